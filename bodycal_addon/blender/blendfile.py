"""Opening a user's avatar file from the command line (a .blend, or an .fbx, .glb / .gltf or .vrm
through Blender's own importers into an empty scene), finding the avatar's armature in it, and
saving the result without risking any file the user has."""

from __future__ import annotations

import base64
import contextlib
import json
import struct
from pathlib import Path

import bpy
import numpy as np
from mathutils import Vector

from ..core import outputs
from ..core.errors import BodyCalError
from ..core.paths import AVATAR_SUFFIXES
from .process import stderr_to_stdout

# suffix -> (the format's name, its import_scene operator, the add-on that provides it; None: not
# Blender's own, the user installs one)
IMPORTERS = {
    ".fbx": ("FBX", "fbx", "io_scene_fbx"),
    ".glb": ("glTF", "gltf", "io_scene_gltf2"),
    ".gltf": ("glTF", "gltf", "io_scene_gltf2"),
    ".vrm": ("VRM", "vrm", None),
}


# Decision: a glTF avatar whose skins were bound in another pose than its nodes' rest keeps the
# nodes' rest (the importer's Guess Original Bind Pose off, `bound_elsewhere`). With the guess (the
# importer's default), such a file gets the bind pose as the armature's rest and the nodes' rest
# as a pose on every bone, locations included; the bake keys rotations, the locations stayed, and
# RobotExpressive's right wrist landed 2.4 m from the retargeted pose (the bake's check refused
# it). Off, the bones rest where the nodes do and the skinned meshes are bound there. Files bound
# in their nodes' rest (every Blender export) are imported as before: off, the importer re-skins
# their vertices and moves them by float round-off, enough to move a sole's contact points.
GLTF_REST = {"guess_original_bind_pose": False}


def open_blend(path) -> None:
    path = Path(path)
    if not path.is_file():
        raise BodyCalError("no such file", source=str(path))
    try:
        # A user's file may hold scripts (drivers, registered text blocks): none of them runs here.
        bpy.ops.wm.open_mainfile(filepath=str(path.resolve()), load_ui=False, use_scripts=False)
    except RuntimeError as exc:
        raise BodyCalError(f"Blender cannot open it ({str(exc).strip().splitlines()[-1][:120]})",
                           source=str(path)) from None


def find_armature(name: str | None, source: str):
    """The armature object named `name`, else the only armature in the file."""
    armatures = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    if name:
        arm = bpy.data.objects.get(name)
        if arm is None or arm.type != "ARMATURE":
            have = ", ".join(sorted(o.name for o in armatures)) or "none"
            raise BodyCalError(f"no armature named '{name}' (armatures in the file: {have})", source=source,
                               field="--armature")
        return arm
    if not armatures:
        raise BodyCalError("the file has no armature", source=source)
    # An armature no mesh is skinned to is a helper (an importer's bone-shape rig, a prop's), not
    # an avatar: it is a candidate only when nothing else is.
    skinned = [a for a in armatures if deformed_meshes(a)] or armatures
    if len(skinned) > 1:
        raise BodyCalError(f"several armatures ({', '.join(sorted(o.name for o in skinned))}): pick one",
                           source=source, hint="use --armature NAME")
    return skinned[0]


def deformed_meshes(arm) -> list:
    """Mesh objects with an Armature modifier driven by `arm`."""
    return [o for o in bpy.data.objects if o.type == "MESH" and any(
        m.type == "ARMATURE" and m.object == arm for m in o.modifiers)]


def open_avatar(path) -> list[str]:
    """Make the avatar file `path` the open file: a .blend is opened (scripts off, `open_blend`);
    an .fbx, .glb, .gltf or .vrm is imported into an empty scene by Blender's own importer
    (`import_avatar_file`). Returns notes on what the import had to mend, one line each."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in AVATAR_SUFFIXES:
        raise BodyCalError(f"not an avatar file this version reads (it reads {', '.join(AVATAR_SUFFIXES)})",
                           source=str(path))
    if suffix == ".blend":
        open_blend(path)
        return []
    if not path.is_file():
        raise BodyCalError("no such file", source=str(path))
    importer_operator(suffix, str(path))  # a missing importer is said before the session is emptied
    bpy.ops.wm.read_homefile(use_empty=True)
    notes = []
    import_avatar_file(path, notes)
    return notes


def import_avatar_file(path, notes: list | None = None) -> list:
    """Import an .fbx, .glb, .gltf or .vrm into the current scene with Blender's importer; returns
    the objects it added. What the importer prints stays off stderr (its tracebacks would break
    the command line's one error line): it goes to stdout, with Blender's own log. A file the
    importer cannot read is one BodyCalError. Skins Blender's FBX importer lost are bound again
    (`bind_lost_skins`), a line each in `notes`."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in IMPORTERS:
        raise BodyCalError(f"not a file Blender imports as an avatar ({', '.join(IMPORTERS)})", source=str(path))
    if not path.is_file():
        raise BodyCalError("no such file", source=str(path))
    fmt = IMPORTERS[suffix][0]
    options = GLTF_REST if suffix in (".glb", ".gltf") and bound_elsewhere(path) else {}
    before = set(bpy.data.objects)
    with _importer_enabled(suffix, str(path)) as operator, stderr_to_stdout():
        try:
            result = operator(filepath=str(path.resolve()), **options)
        except RuntimeError as exc:
            raise BodyCalError(f"Blender's {fmt} importer cannot read it ({_last_line(exc, path)})",
                               source=str(path)) from None
    if "FINISHED" not in result:
        raise BodyCalError(f"Blender's {fmt} importer gave up on it", source=str(path))
    added = [o for o in bpy.data.objects if o not in before]
    if suffix == ".fbx":
        said = bind_lost_skins(added)
        if notes is not None:
            notes.extend(said)
    return added


def import_avatars(path, notes: list | None = None) -> tuple[list, list]:
    """Import an avatar file (`import_avatar_file`) and pick its avatars: (every new object, the
    armatures a mesh is skinned to, or every armature when none is). A file without an armature
    leaves the scene as it was and is refused."""
    new = import_avatar_file(path, notes)
    armatures = [o for o in new if o.type == "ARMATURE"]
    # As on the command line: an armature no mesh is skinned to is a helper, not the avatar.
    avatars = [a for a in armatures if deformed_meshes(a)] or armatures
    if not avatars:
        for obj in new:  # nothing to animate: leave the scene as it was
            bpy.data.objects.remove(obj)
        raise BodyCalError("the file has no armature", source=path)
    return new, avatars


def bound_elsewhere(path) -> bool:
    """Whether a glTF file's skins were bound in another pose than its nodes' rest: for a skin
    bound at rest, every joint's world matrix (the nodes' rest) times its inverse bind matrix is
    the same matrix (where the mesh stood when bound). False when that cannot be read here (the
    importer then reads the file as it does by default, or says what is wrong)."""
    try:
        doc, binary = _gltf_parts(Path(path))
        nodes = doc.get("nodes", [])
        world = _node_worlds(nodes, doc)
        for skin in doc.get("skins", []):
            if "inverseBindMatrices" not in skin:
                continue
            ibm = _accessor_floats(doc, binary, skin["inverseBindMatrices"], 16).reshape(-1, 4, 4).transpose(0, 2, 1)
            products = np.stack([world[j] @ m for j, m in zip(skin["joints"], ibm)])
            scale = max(1.0, float(np.abs(products[:, :3, 3]).max()))
            if np.abs(products - products[0]).max() > 1e-3 * scale:
                return True
        return False
    except (OSError, ValueError, TypeError, KeyError, IndexError, struct.error, np.linalg.LinAlgError):
        return False


def _gltf_parts(path: Path) -> tuple[dict, bytes]:
    """The JSON and the binary chunk of a .glb (glTF 2.0 §4.4), or a .gltf's JSON and its first
    buffer (a data URI or a file beside it)."""
    if path.suffix.lower() == ".gltf":
        doc = json.loads(path.read_text(encoding="utf-8"))
        uri = doc["buffers"][0]["uri"]
        if uri.startswith("data:"):
            return doc, base64.b64decode(uri.split(",", 1)[1])
        return doc, (path.parent / uri).read_bytes()
    data = path.read_bytes()
    magic, _version, _length = struct.unpack_from("<4sII", data, 0)
    if magic != b"glTF":
        raise ValueError("not a binary glTF")
    offset, doc, binary = 12, None, b""
    while offset + 8 <= len(data):
        size, kind = struct.unpack_from("<II", data, offset)
        chunk = data[offset + 8:offset + 8 + size]
        if kind == 0x4E4F534A:  # JSON
            doc = json.loads(chunk.decode("utf-8"))
        elif kind == 0x004E4942:  # BIN
            binary = chunk
        offset += 8 + size
    if doc is None:
        raise ValueError("no JSON chunk")
    return doc, binary


def _accessor_floats(doc: dict, binary: bytes, index: int, width: int) -> np.ndarray:
    """A float accessor's values, (count, width), from the file's first buffer."""
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    if acc.get("componentType") != 5126 or view.get("buffer", 0) != 0 or view.get("byteStride", 4 * width) != 4 * width:
        raise ValueError("an accessor this check does not read")
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(binary, "<f4", acc["count"] * width, start).reshape(-1, width).astype(float)


def _node_worlds(nodes: list, doc: dict) -> dict[int, np.ndarray]:
    """Every node's world matrix (4, 4) at the nodes' rest (their `matrix`, or translation,
    rotation (x, y, z, w) and scale)."""
    parent = {c: i for i, n in enumerate(nodes) for c in n.get("children", [])}
    out: dict[int, np.ndarray] = {}

    def local(n: dict) -> np.ndarray:
        if "matrix" in n:
            return np.array(n["matrix"], float).reshape(4, 4).T
        x, y, z, w = n.get("rotation", (0.0, 0.0, 0.0, 1.0))
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        m = np.eye(4)
        m[:3, :3] = r * np.asarray(n.get("scale", (1.0, 1.0, 1.0)), float)
        m[:3, 3] = n.get("translation", (0.0, 0.0, 0.0))
        return m

    def world(i: int, depth: int = 0) -> np.ndarray:
        if i not in out:
            if depth > len(nodes):
                raise ValueError("a cycle in the node hierarchy")
            out[i] = local(nodes[i]) if i not in parent else world(parent[i], depth + 1) @ local(nodes[i])
        return out[i]

    for i in range(len(nodes)):
        world(i)
    return out


def bind_lost_skins(objects) -> list[str]:
    """Bind again the meshes among `objects` whose skin Blender's FBX importer lost; returns a note
    for each. The importer (4.2 to 5.0, `collect_armature_meshes`) reparents an armature's meshes
    while it walks the list that holds them: the node after that armature is skipped, so when it is
    a second character's armature, that character's meshes keep their vertex weights but get no
    Armature modifier and no parent (two characters in one file, or the same one twice). Such a
    mesh (vertex groups, no Armature modifier, no armature parent) goes to the armature among
    `objects` that has a bone for every vertex group and whose bones stand inside the mesh's
    bounds; of several alike, the one with no mesh of its own; none or a tie: left as it is."""
    bpy.context.view_layer.update()  # the world matrices the bounds are read in
    armatures = [o for o in objects if o.type == "ARMATURE"]
    lost = [o for o in objects if o.type == "MESH" and o.vertex_groups
            and not any(m.type == "ARMATURE" for m in o.modifiers)
            and not (o.parent is not None and o.parent.type == "ARMATURE")]
    notes = []
    for mesh in lost:
        groups = {g.name for g in mesh.vertex_groups}
        scored = [(_bones_inside(arm, mesh), not deformed_meshes(arm), arm) for arm in armatures
                  if groups <= set(arm.data.bones.keys())]
        scored = [c for c in scored if c[0] > 0.5]
        if not scored:
            continue
        best = max(c[:2] for c in scored)
        chosen = [arm for inside, alone, arm in scored if (inside, alone) == best]
        if len(chosen) != 1:
            continue
        arm = chosen[0]
        world = mesh.matrix_world.copy()
        mesh.parent = arm
        mesh.matrix_parent_inverse = arm.matrix_world.inverted()
        mesh.matrix_world = world
        mesh.modifiers.new(arm.name, "ARMATURE").object = arm
        notes.append(f"{mesh.name}: Blender's FBX importer left it unbound (its skin to '{arm.name}' lost); bound "
                     f"to '{arm.name}' again, whose bones its vertex groups name")
    return notes


def _bones_inside(arm, mesh) -> float:
    """The share of the armature's bone heads (at rest, in the world) inside the mesh's bounds, the
    bounds grown by a tenth of their size."""
    corners = np.array([mesh.matrix_world @ Vector(c) for c in mesh.bound_box])
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    pad = 0.1 * (hi - lo) + 1e-6
    heads = np.array([arm.matrix_world @ b.head_local for b in arm.data.bones])
    return float(np.mean(np.all((heads >= lo - pad) & (heads <= hi + pad), axis=1))) if len(heads) else 0.0


def importer_operator(suffix: str, source: str):
    """The import_scene operator for `suffix`, or a BodyCalError saying what to install."""
    fmt, op_name, addon = IMPORTERS[suffix]
    if op_name in dir(bpy.ops.import_scene):
        return getattr(bpy.ops.import_scene, op_name)
    if addon is None:
        raise BodyCalError(f"reading {suffix} needs a {fmt} importer add-on, and none is enabled", source=source,
                           hint="install and enable one (such as \"VRM format\" in Preferences > Get Extensions), "
                                "then run again")
    return None  # Blender's own: enabled on demand (_importer_enabled)


@contextlib.contextmanager
def _importer_enabled(suffix: str, source: str):
    """The importer operator, with its add-on enabled for the import when it was not (Blender's
    own FBX and glTF importers are add-ons a user may have turned off), and turned off again."""
    import addon_utils  # here: on sys.path only once bpy is imported, which isort would put after it

    fmt, op_name, addon = IMPORTERS[suffix]
    operator = importer_operator(suffix, source)
    enabled_here = False
    if operator is None:
        addon_utils.enable(addon, default_set=False, handle_error=lambda _exc: None)
        enabled_here = op_name in dir(bpy.ops.import_scene)
        if not enabled_here:
            raise BodyCalError(f"Blender's {fmt} importer ({addon}) cannot be enabled", source=source,
                               hint="check the Blender installation")
        operator = getattr(bpy.ops.import_scene, op_name)
    try:
        yield operator
    finally:
        if enabled_here:
            addon_utils.disable(addon, default_set=False, handle_error=lambda _exc: None)


def _last_line(exc: BaseException, path: Path) -> str:
    """The reason an operator's RuntimeError gives, on one short line: its last line (a traceback's
    is the exception; Blender may add the operator's "Location:" after it), without Blender's
    "Error:" prefix and with the file's path shortened."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip() and not ln.strip().startswith("Location:")]
    text = lines[-1] if lines else type(exc).__name__
    text = text.removeprefix("Error:").strip().replace(str(path.resolve()), path.name).replace(str(path), path.name)
    return text if len(text) <= 160 else text[:157] + "..."


def _call_operator(idname: str, **properties) -> set[str]:
    """Run the operator `idname` ("wm.save_as_mainfile") without `bpy.ops`' view-layer update.
    Decision: `bpy.ops.<op>()` updates the view layer before and after the call, and that
    evaluation copies every action in the scene into the depsgraph: a 10-minute bake's action
    doubled the command's memory (+650 MB) for a save that writes only the original data (BLENDER_NOTES.md).
    `_bpy.ops.call` is what `bpy.ops` itself calls (the same on 4.2, 4.5 and 5.0)."""
    from _bpy import ops as _ops  # here: on sys.path only once bpy is imported

    return _ops.call(idname, properties)


def save_blend(path, *, overwrite: bool = True, inputs=(), field: str = "-o") -> Path:
    """Save the open file as `path` through `outputs.replacing`: Blender writes a temporary file
    beside it, renamed over `path` only once complete; a symlink, a device or one of `inputs` is
    refused. The session keeps its own file path (`copy=True`), so nothing points at the temp."""
    with outputs.replacing(path, inputs=inputs, overwrite=overwrite, field=field) as tmp:
        tmp.unlink()  # else Blender keeps the empty placeholder as a `.blend1` backup
        try:
            _call_operator("wm.save_as_mainfile", filepath=str(tmp), copy=True, compress=True)
        except RuntimeError as exc:
            raise BodyCalError(f"Blender cannot save it ({str(exc).strip().splitlines()[-1][:120]})",
                               source=str(path), field=field, hint="check the disk space and the folder") from None
    return Path(path)
