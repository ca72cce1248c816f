"""Everything in BodyCal that touches `bpy`: scene I/O, raycasting, baking, the CLI bridge; and the
one door through which the sidebar (`operators/`, `panels/`) reaches the engine.

Its modules by job: the scene's recording and performer (`recording_scene`, `device_roles`,
`scene_objects`, `calibration_scene`), the avatar (`blendfile`, `avatar_rig`, `avatar_storage`,
`avatar_calibration`, `surface_helpers`, `bone_map_presets`), a bake (`session`, `bake`, `fcurves`,
`rig_output`, `bake_check`, `export`, `character_source`), what the user sees (`preview`, `live`,
`review`, `review_plots`, `pose_state`, `mesh_metrics`), and the process (`process`, `demo`,
`extension_build`).

The package re-exports the engine's error types and its one line for an OS error, so the UI's
reporting needs no engine import; its modules are imported one by one (each loads bpy)."""

from ..core.errors import BodyCalError as BodyCalError
from ..core.errors import Cancelled as Cancelled
from ..core.outputs import describe_os_error as describe_os_error
