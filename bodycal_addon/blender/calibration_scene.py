"""The user body model in the Blender scene: stored as JSON in a scene custom property (survives
save / reload and undo), and shown as helper objects in a collection: one empty per fitted joint,
sphere empties for the skull and the anchor-joint spheres, circle empties for the hinge axes,
and the crude meshes (torso, jaw, palms, soles) as mesh objects, all at the reference time."""

from __future__ import annotations

import bpy
import numpy as np

from ..body import surface_layout as sl
from ..body.bodymodel import BodyModel
from ..calibration import CALIBRATION_STEPS as CALIBRATION_STEPS  # re-exported (`X as X`): the panel's
from ..calibration import calibrate_user, check_usable
from ..calibration import coverage as coverage  # re-exported: the panel's
from ..calibration.coverage import BODY_JOINTS as BODY_JOINTS  # re-exported: the panel's
from ..calibration.coverage import Coverage
from ..core.errors import BodyCalError
from ..core.transforms import matrix_to_quat
from .avatar_storage import has_json_model, load_json_model, store_json_model
from .recording_scene import recording_from_scene

MODEL_PROP = "bodycal_user_model"
HELPER_PROP = "bodycal_helper"  # on a helper object: the joint or element it shows
COLLECTION = "BodyCal User Calibration"


# (The sidebar reaches the engine through blender/ only: the names the calibration panel shows are
# re-exported above.)


def store_user_model(scene, model: BodyModel) -> None:
    store_json_model(scene, MODEL_PROP, model)


def has_user_model(scene) -> bool:
    return has_json_model(scene, MODEL_PROP)


def load_user_model(scene) -> BodyModel:
    return load_json_model(scene, MODEL_PROP, what="user body model", redo="run Calibrate User first")


# {scene name: the last refusal's line}: what the calibration panel shows until the next calibration
# of that scene.
REFUSED: dict[str, str] = {}


def calibrate_scene(scene, show: bool = True) -> tuple[BodyModel, Coverage]:
    """Calibrate the performer from the scene's recording, store the model on the scene and (with
    `show`) its helpers; a model too guessed to use is refused (BodyCalError), its line kept in
    REFUSED for the panel."""
    model = calibrate_user(recording_from_scene(scene))
    REFUSED.pop(scene.name, None)
    try:
        cov = check_usable(model)
    except BodyCalError as exc:
        REFUSED[scene.name] = exc.line()
        raise
    store_user_model(scene, model)
    if show:
        show_helpers(scene, model)
    return model, cov


def calibration_report(model: BodyModel, cov: Coverage) -> tuple[str, list[str]]:
    """(summary line, warnings) of a calibration: what the operator reports."""
    cal = model.calibration
    summary = (f"Calibrated from {len(cal['steps_used'])} steps: {cov.line()}; {len(cal['missing'])} steps missing"
               + (f", {len(cal['warnings'])} not usable (see the panel)" if cal.get("warnings") else ""))
    return summary, cal.get("warnings", []) + cov.warnings()


def read_user_model(path, wrong_kind: str = "this is an {kind} body model, not a user one",
                    source=None) -> BodyModel:
    """A user body model from its `.body.json`; another kind of model is refused with `wrong_kind`."""
    model = BodyModel.load(path)
    if model.kind != "user":
        raise BodyCalError(wrong_kind.format(kind=model.kind), source=path if source is None else source)
    return model


def load_user_model_file(scene, path) -> BodyModel:
    """Read a user body model file and store it on the scene."""
    model = read_user_model(path)
    store_user_model(scene, model)
    return model


def performer_model(scene, user_file: str | None) -> BodyModel:
    """The performer's model: the file `user_file` when given ("" = the file setting left empty),
    else the scene's calibrated one."""
    if user_file is not None:
        if not user_file:
            raise BodyCalError("no body model file picked", field="Body Model",
                               hint="pick the performer's .body.json, or use the scene's performer")
        return read_user_model(bpy.path.abspath(user_file), "expected a user body model, got kind '{kind}'",
                               source=user_file)
    if not has_user_model(scene):
        raise BodyCalError("no performer calibrated in this scene", field="Performer",
                           hint="Calibrate User on a take first, or pick a .body.json file")
    return load_user_model(scene)


def _bone_matrix(model: BodyModel, bone: str) -> tuple[np.ndarray, np.ndarray]:
    b = model.bones[bone]
    head, tail = model.world(b.head), model.world(b.tail)
    right = b.right if b.right is not None else np.array([1.0, 0, 0])
    return head, sl.bone_frame(head, tail, right)


def surface_points_world(model: BodyModel, element) -> dict[str, np.ndarray]:
    out = {}
    for k, p in element.points.items():
        head, rot = _bone_matrix(model, p.bone)
        out[k] = head + rot @ p.local
    return out


def _clear(coll):
    for obj in list(coll.objects):
        data = obj.data
        bpy.data.objects.remove(obj, do_unlink=True)
        if data is not None and data.users == 0 and isinstance(data, bpy.types.Mesh):
            bpy.data.meshes.remove(data)


def _empty(coll, name, loc, display="SPHERE", size=0.01, rot=None):
    obj = bpy.data.objects.new(name, None)
    obj.empty_display_type = display
    obj.empty_display_size = size
    obj.location = [float(x) for x in loc]
    if rot is not None:
        obj.rotation_mode = "QUATERNION"

        obj.rotation_quaternion = [float(x) for x in matrix_to_quat(rot)]
    coll.objects.link(obj)
    obj[HELPER_PROP] = name
    return obj


def show_helpers(scene, model: BodyModel) -> bpy.types.Collection:
    """(Re)build the helper collection for `model`; returns it."""
    coll = bpy.data.collections.get(COLLECTION)
    if coll is None:
        coll = bpy.data.collections.new(COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    _clear(coll)
    fitted = set(model.joints) - {k for k in model.calibration.get("defaulted", {}) if k in model.joints}
    for name, j in model.joints.items():
        _empty(coll, f"joint:{name}", j.world, "SPHERE" if name in fitted else "PLAIN_AXES", 0.012)
    for e in model.surface:
        if e.type == "sphere":
            head, rot = _bone_matrix(model, e.bone)
            _empty(coll, e.id, head + rot @ e.center, "SPHERE", e.radius)
        elif e.type == "mesh":
            pts = surface_points_world(model, e)
            names = list(pts)
            me = bpy.data.meshes.new(e.id)
            me.from_pydata([tuple(map(float, pts[n])) for n in names], [],
                           [tuple(names.index(v) for v in tri) for tri in e.triangles])
            me.update()
            obj = bpy.data.objects.new(e.id, me)
            obj.display_type = "WIRE"
            obj[HELPER_PROP] = e.id
            coll.objects.link(obj)
    radii = model.extra.get("joint_radii", {}) if isinstance(model.extra, dict) else {}
    for joint in ("shoulder_l", "shoulder_r", "hip_l", "hip_r"):  # the anchor joints' spheres
        if joint in model.joints and radii.get(joint):
            _empty(coll, f"anchor:{joint}", model.world(joint), "SPHERE", float(radii[joint]))
    for bone in ("forearm_l", "forearm_r", "shin_l", "shin_r"):
        if bone in model.bones:
            head, rot = _bone_matrix(model, bone)
            # the hinge circle lies in the plane normal to the axis: a CIRCLE empty draws in its local XY
            circle_rot = np.stack([rot[:, 1], rot[:, 2], rot[:, 0]], axis=1)
            r = model.bones[bone].radius_head or 0.04
            _empty(coll, f"hinge:{bone}", head, "CIRCLE", 1.5 * r, circle_rot)
            _empty(coll, f"axis:{bone}", head, "SINGLE_ARROW", 0.1, np.stack([rot[:, 1], rot[:, 2], rot[:, 0]],
                                                                                 axis=1))
    return coll
