"""Exporting a baked avatar for game engines and other tools (FORMATS.md §4.2, "Files"): FBX,
glTF (.glb binary, .gltf with its buffers embedded) and BVH, through Blender's own exporters,
with the options a game engine expects: the armature and its skinned meshes, the baked (active)
action only, no leaf bones, Y up where the format wants it, and the clip (the FBX take, the glTF
animation) named after the action.

Every export goes through `outputs.replacing` (a temporary file beside the target, renamed only
once complete), so a failed export never leaves half a file or costs an existing one.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import bpy

from ..core import outputs
from ..core.errors import BodyCalError

EXPORT_SUFFIXES = (".fbx", ".glb", ".gltf", ".bvh")
OUTPUT_SUFFIXES = (".blend", *EXPORT_SUFFIXES)


def output_kind(path) -> str:
    """'blend', 'fbx', 'glb', 'gltf' or 'bvh' from the output's suffix; one line when unknown."""
    suffix = Path(path).suffix.lower()
    if suffix not in OUTPUT_SUFFIXES:
        raise BodyCalError(f"cannot write a '{suffix or 'suffix-less'}' file", source=str(path), field="-o",
                           hint="end the output with .blend, .fbx, .glb, .gltf or .bvh")
    return suffix[1:]


def _skinned_meshes(arm) -> list:
    return [o for o in bpy.data.objects if o.type == "MESH" and (
        o.parent == arm or any(m.type == "ARMATURE" and m.object == arm for m in o.modifiers))]


@contextlib.contextmanager
def _selected(arm, objects):
    """Only `objects` selected and `arm` active, in the scene's view layer, for the exporters'
    `use_selection`; the selection and active object are restored afterwards."""
    view_layer = bpy.context.view_layer
    before = [o for o in view_layer.objects if o.select_get()]
    active = view_layer.objects.active
    try:
        for o in before:
            o.select_set(False)
        for o in objects:
            if o.name in view_layer.objects:
                o.select_set(True)
        view_layer.objects.active = arm
        yield
    finally:
        for o in view_layer.objects:
            o.select_set(o in before)
        view_layer.objects.active = active


@contextlib.contextmanager
def _gltf_embedded_allowed():
    """The glTF exporter offers 'GLTF_EMBEDDED' (one self-contained .gltf) only when its add-on
    preference allows it; allowed for the export, then put back as it was."""
    addon = bpy.context.preferences.addons.get("io_scene_gltf2")
    prefs = getattr(addon, "preferences", None)
    had = getattr(prefs, "allow_embedded_format", None)
    if prefs is not None and had is not None:
        prefs.allow_embedded_format = True
    try:
        yield
    finally:
        if prefs is not None and had is not None:
            prefs.allow_embedded_format = had


@contextlib.contextmanager
def _scene_named(name: str):
    """The scene named `name` for the FBX export (its exporter names the take, the clip a game
    engine shows, after the scene when it exports the active action alone); a scene that already
    has the name gives it up meanwhile. Both names are put back."""
    scene = bpy.context.scene
    own = scene.name
    other = bpy.data.scenes.get(name)
    if other is not None and other != scene:
        other.name = name + ".bodycal-export"
    scene.name = name
    try:
        yield
    finally:
        scene.name = own
        if other is not None and other != scene:
            other.name = name


def _export_to(kind: str, tmp: Path, action_name: str) -> None:
    scene = bpy.context.scene
    if kind == "fbx":
        with _scene_named(action_name):
            _export_fbx(tmp)
    elif kind in ("glb", "gltf"):
        with _gltf_embedded_allowed():
            bpy.ops.export_scene.gltf(
                filepath=str(tmp), export_format="GLB" if kind == "glb" else "GLTF_EMBEDDED", use_selection=True,
                export_yup=True, export_animations=True, export_animation_mode="ACTIVE_ACTIONS",
                export_nla_strips_merged_animation_name=action_name,
                export_frame_range=True, export_force_sampling=True, export_skins=True, export_leaf_bone=False,
                export_anim_slide_to_zero=False)
    elif kind == "bvh":  # the armature alone (BVH has no mesh); rotations in each bone's own order
        bpy.ops.export_anim.bvh(filepath=str(tmp), frame_start=scene.frame_start, frame_end=scene.frame_end,
                                rotate_mode="NATIVE", root_transform_only=False)
    else:
        raise ValueError(kind)


def _export_fbx(tmp: Path) -> None:
    bpy.ops.export_scene.fbx(
        filepath=str(tmp), use_selection=True, object_types={"ARMATURE", "MESH"}, add_leaf_bones=False,
        bake_anim=True, bake_anim_use_all_bones=True, bake_anim_use_nla_strips=False,
        bake_anim_use_all_actions=False, bake_anim_force_startend_keying=True, bake_anim_simplify_factor=0.0,
        axis_forward="-Z", axis_up="Y", apply_scale_options="FBX_SCALE_ALL", path_mode="AUTO")


def export_avatar(arm, path, *, inputs=(), overwrite: bool = False, field: str = "-o") -> Path:
    """Write armature `arm` (with its skinned meshes and its active action, over the scene's frame
    range) to `path` in the format its suffix names."""
    kind = output_kind(path)
    if kind == "blend":
        raise ValueError("a .blend is saved with blendfile.save_blend")
    if arm is None or arm.type != "ARMATURE":
        raise BodyCalError("pick an armature to export", source=getattr(arm, "name", "no object"))
    if arm.animation_data is None or arm.animation_data.action is None:
        raise BodyCalError("the armature has no action to export", source=arm.name,
                           hint="retarget and bake first (the export takes the active action)")
    with outputs.replacing(path, inputs=inputs, overwrite=overwrite, field=field) as tmp:
        tmp.unlink()
        chatter = io.StringIO()  # the exporters print progress; the command line keeps one line per result
        try:
            with _selected(arm, [arm, *_skinned_meshes(arm)]), contextlib.redirect_stdout(chatter):
                _export_to(kind, tmp, arm.animation_data.action.name)
        except RuntimeError as exc:
            raise BodyCalError(f"Blender's {kind.upper()} exporter failed ({str(exc).strip().splitlines()[-1][:120]})",
                               source=str(path), field=field) from None
    return Path(path)
