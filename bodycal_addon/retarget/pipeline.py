"""The bake's entry points (DESIGN.md §1 steps 1-4) for the three methods: the prepared solver
(solver.py) run over the take in chunks of frames, with progress and cancel callbacks for the
modal bake operator.

- `egocentric` (Delahaye 2023, the default): animate the user (step 1), pose the avatar by copying the
  user's bone frames (step 2), map the targets through the two posed surfaces (step 3), then avatar
  IK (step 4).
- `offsets` (AvatarGo): exact tracker-to-joint offsets + IK.
- `rotations`: step 2 only, the baseline.

The result is an `AvatarAnimation` whose `rotations` / `root_location` are pose-bone values for
the armature (`avatar_pose.AvatarRig.solve`) and whose `joints_world` are the canonical joints
those values put in the world (Blender's FK, armature matrix_world included).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..avatar.estimate import ESTIMATED
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..body.skeleton import JOINTS
from ..core.errors import BodyCalError, Cancelled
from ..recording.model import Recording
from .pose_source import PoseSource, RecordingSource
from .solver import PreparedSolver, check_inputs
from .solver_methods import METHOD_CLASSES, METHODS

__all__ = ["METHODS", "METHOD_CLASSES", "retarget", "run_source"]


def retarget(recording: Recording, user_model: BodyModel, avatar_model: BodyModel, method: str = "egocentric", *,
             chunk_frames: int = 2000, progress: Callable[[float], None] | None = None,
             cancel: Callable[[], bool] | None = None, plant_feet: bool = True,
             placement: str = "object", seat_height: float | None = None) -> AvatarAnimation:
    """Retarget `recording` of the user (`user_model`) onto the avatar (`avatar_model`, kind
    "avatar" with `extra["rig"]`). Frames are processed `chunk_frames` at a time; `progress(f)` is
    called with the fraction done after each chunk and `cancel()` before each one (True raises
    `errors.Cancelled`). `plant_feet` holds the feet still and on the floor while the performer
    stands on them (feet.py), in every method. `placement` ("object" or "performer", placement.py)
    says where the performance plays: relative to the armature object's placement, or where the
    performer was in the room. A kit without pelvis or foot trackers gets them estimated
    (lower_body; `seat_height`: the performer sits on a seat that high). Bad inputs raise one
    `BodyCalError`."""
    check_inputs(recording, user_model, avatar_model, method)
    return run_source(RecordingSource(recording, user_model, seat_height=seat_height), avatar_model, method,
                      chunk_frames=chunk_frames,
                      progress=progress, cancel=cancel, plant_feet=plant_feet, placement=placement)


class PreparedTake:
    """A take prepared once for an avatar (`solver.PreparedSolver`: the whole take's feet plan
    included) whose `solve(start, stop)` is the avatar's animation of frames [start, stop), the
    values the bake keys there: the timeline preview solves the frame the user scrubs to."""

    def __init__(self, source: PoseSource, avatar_model: BodyModel, method: str = "egocentric", *,
                 plant_feet: bool = True, placement: str = "object"):
        self.source = source
        self.solver = PreparedSolver(source, avatar_model, method, plant_feet=plant_feet, placement=placement)

    @property
    def frame_count(self) -> int:
        return self.source.frame_count

    def solve(self, start: int, stop: int) -> AvatarAnimation:
        start, stop = max(0, int(start)), min(self.frame_count, int(stop))
        if stop <= start:
            raise BodyCalError(f"frames {start}-{stop} are outside the take (0-{self.frame_count - 1})",
                               source=self.source.name)
        out = self.solver.solve(start, stop)
        rig = self.solver.rig
        return AvatarAnimation(rig.armature, list(rig.names), out.basis, rig.names[rig.root],
                               np.asarray(out.root_location, float), np.asarray(self.source.time[start:stop], float),
                               self.solver.method, {j: out.joints[:, i] for i, j in enumerate(JOINTS)}, out.targets,
                               list(self.solver.notes))


def prepare_recording(recording: Recording, user_model: BodyModel, avatar_model: BodyModel,
                      method: str = "egocentric", *, plant_feet: bool = True, placement: str = "object",
                      seat_height: float | None = None) -> PreparedTake:
    """`retarget`'s take prepared once, to be solved a few frames at a time (PreparedTake)."""
    check_inputs(recording, user_model, avatar_model, method)
    return PreparedTake(RecordingSource(recording, user_model, seat_height=seat_height), avatar_model, method,
                        plant_feet=plant_feet, placement=placement)


def run_source(source: PoseSource, avatar_model: BodyModel, method: str = "egocentric", *, chunk_frames: int = 2000,
               progress: Callable[[float], None] | None = None, cancel: Callable[[], bool] | None = None,
               plant_feet: bool = True, placement: str = "object") -> AvatarAnimation:
    """`retarget` for any pose source (pose_source.py): a recording of a calibrated user, or an
    animated character (`transfer.transfer`). The source's poses are in its play area."""
    solver = PreparedSolver(source, avatar_model, method, plant_feet=plant_feet, placement=placement)
    nf = source.frame_count
    rig = solver.rig
    rotations = np.empty((nf, len(rig.names), 4))
    root_loc = np.empty((nf, 3))
    joints = np.empty((nf, len(JOINTS), 3), np.float32)
    targets: dict[str, np.ndarray] = {}
    chunk_frames = max(1, int(chunk_frames))
    for start in range(0, nf, chunk_frames):
        if cancel is not None and cancel():
            raise Cancelled(f"retargeting cancelled at frame {start} of {nf}")
        stop = min(nf, start + chunk_frames)
        out = solver.solve(start, stop)
        rotations[start:stop] = out.basis
        root_loc[start:stop] = out.root_location
        joints[start:stop] = out.joints
        for n, v in out.targets.items():
            # NaN where a chunk had no target of this name (rotations: an ankle only while planted)
            targets.setdefault(n, np.full((nf, 3), np.nan, np.float32))[start:stop] = v
        if progress is not None:
            progress(stop / nf)
    if not (np.isfinite(rotations).all() and np.isfinite(root_loc).all()):
        raise BodyCalError("the retargeted animation has non-finite values", source=source.name,
                           hint="check the source for broken poses")
    if avatar_model.calibration.get("method") == ESTIMATED:
        solver.notes.append(f"{avatar_model.name} (target): no mesh, body surface estimated from its bone lengths")
    return AvatarAnimation(rig.armature, list(rig.names), rotations, rig.names[rig.root], root_loc,
                           np.asarray(source.time, float), method,
                           {j: joints[:, i] for i, j in enumerate(JOINTS)}, targets, solver.notes)
