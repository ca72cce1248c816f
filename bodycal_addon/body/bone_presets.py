"""Bone map presets (FORMATS.md §5): a JSON file saying which avatar bone is each body segment,
like Expy Kit's presets or KeeMap's mapping files. The panel exports and imports them and keeps
the user's own in the extension's user folder; `calibrate-avatar` and `retarget` take one with
`--bone-map FILE`, batch jobs with an avatar's `bone_map`. No bpy: the command line checks a
preset before it opens any .blend.

    {"format": "bodycal-bone-map", "version": 1, "name": "Ogre",
     "scheme": "mixamo",                       # optional: a naming scheme maps the rest
     "bones": {"pelvis": "Hips_jnt", "upperarm_l": "L_Arm_jnt", "toe_l": null},
     "chains": {"spine": ["Spine_jnt", "Chest_jnt"], "neck": ["Neck_jnt"]}}

Without `scheme` the file is the whole map (what it does not list stays unmapped); with one, the
scheme maps the armature's bones first and `bones` / `chains` replace its choices (null or ""
unmaps a segment). Checked on reading (the structure, segment and scheme names, a bone named
twice) and again on an armature (every bone must exist): each problem is one line naming the file
and the field.
"""

from __future__ import annotations

import difflib
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..core import outputs
from ..core.errors import BodyCalError, short_repr
from . import naming
from . import skeleton as sk

FORMAT = "bodycal-bone-map"
VERSION = 1
SINGLE_SEGMENTS: tuple[str, ...] = tuple(s for s in sk.SEGMENTS if s not in sk.CHAIN_SEGMENTS)
KEYS = ("format", "version", "name", "scheme", "bones", "chains")
MAX_BYTES = 1 << 20  # a preset is a few kB; anything near this is not one
_CONTROL = re.compile(r"[\x00-\x1f\x7f]")


@dataclass
class BonePreset:
    name: str
    scheme: str | None = None
    bones: dict[str, str | None] = field(default_factory=dict)  # segment -> bone, None: unmapped
    chains: dict[str, list[str]] = field(default_factory=dict)  # "spine" / "neck" -> bones bottom-up
    source: str = "bone map"  # the file (or "built-in: <scheme>") for messages

    def to_dict(self) -> dict:
        out = {"format": FORMAT, "version": VERSION, "name": self.name}
        if self.scheme:
            out["scheme"] = self.scheme
        out["bones"] = dict(self.bones)
        out["chains"] = {k: list(v) for k, v in self.chains.items()}
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1, ensure_ascii=False) + "\n"

    def save(self, path, *, overwrite: bool = True, inputs=(), field: str = "-o") -> Path:
        """Write the preset (never half-written, never over a link, a device or one of `inputs`)."""

        return outputs.write_text(path, self.to_json(), overwrite=overwrite, inputs=inputs, field=field)

    def resolve(self, bone_names) -> naming.BoneMap:
        """The bone map this preset gives an armature with these bones; a bone it names that the
        armature lacks, or one bone for two segments, is an error."""
        names = list(dict.fromkeys(bone_names))
        have = set(names)
        if self.scheme:
            bm = naming.map_with_scheme(names, naming.SCHEME_BY_NAME[self.scheme])
            label = self.scheme + ("+preset" if self.bones or self.chains else "")
            # A bone the preset places itself leaves the place the scheme gave it.
            placed = {b for b in self.bones.values() if b} | {b for bs in self.chains.values() for b in bs}
            bm.bones = {s: b for s, b in bm.bones.items() if b not in placed}
            bm.chains = {c: [b for b in bs if b not in placed] for c, bs in bm.chains.items()}
        else:
            bm = naming.BoneMap("preset", {}, {c: [] for c in sk.CHAIN_SEGMENTS}, [])
            label = "preset"
        for seg, bone in self.bones.items():
            if bone:
                _check_bone(self.source, f"bones.{seg}", bone, have, names)
                bm.bones[seg] = bone
            else:
                bm.bones.pop(seg, None)
        for chain, chain_bones in self.chains.items():
            for i, bone in enumerate(chain_bones):
                _check_bone(self.source, f"chains.{chain}[{i}]", bone, have, names)
            bm.chains[chain] = list(chain_bones)
        _check_once(self.source, bm.bones, bm.chains, "on this armature")
        used = set(bm.bones.values()) | {b for c in bm.chains.values() for b in c}
        return naming.BoneMap(label, bm.bones, {c: list(bm.chains.get(c, [])) for c in sk.CHAIN_SEGMENTS},
                          [n for n in names if n not in used])


def _check_bone(source: str, where: str, bone: str, have: set[str], names: list[str]) -> None:
    if bone in have:
        return
    close = difflib.get_close_matches(bone, names, n=1)
    raise BodyCalError(f"the armature has no bone {short_repr(bone)}", source=source, field=where,
                       hint=f"did you mean {close[0]!r}?" if close else "check the bone names in the armature")


def _first_shared(entries: list[tuple[str, str]]) -> tuple[str, str, str] | None:
    """(bone, first place, second place) of the first bone listed twice in (place, bone) entries."""
    seen: dict[str, str] = {}
    for where, bone in entries:
        if bone in seen:
            return bone, seen[bone], where
        seen[bone] = where
    return None


def _check_once(source: str, bones: dict[str, str | None], chains: dict[str, list[str]], how: str = "") -> None:
    """One bone serves one segment: two segments on one bone would pose it twice."""
    entries = [(f"bones.{s}", b) for s, b in bones.items() if b]
    entries += [(f"chains.{c}[{i}]", b) for c, bs in chains.items() for i, b in enumerate(bs)]
    shared = _first_shared(entries)
    if shared:
        bone, first, where = shared
        also = f" {how}" if how else ""
        raise BodyCalError(f"bone {short_repr(bone)} is given to {first} and {where}{also}",
                           source=source, field=where, hint="a bone can serve one segment only")


# --- the map kept on an armature: detection plus the user's overrides --------------------------------
# An armature stores {segment: bone} overrides ("" = unmapped, a chain's bones comma-separated,
# bottom-up); detection maps the segments it does not list (blender/avatar_rig.py keeps them).


def map_with_overrides(bone_names, overrides: dict[str, str], detected: naming.BoneMap | None = None
                       ) -> naming.BoneMap:
    """The armature's map: detection (`detected`, default: by the bones' names), then each
    overridden segment as stored; a bone the armature no longer has is left out. Overriding every
    segment (a preset applied) makes it "custom"."""
    names = list(dict.fromkeys(bone_names))
    have = set(names)
    bm = naming.detect_bone_map(names) if detected is None else detected
    for seg, bone in overrides.items():
        if seg in sk.CHAIN_SEGMENTS:
            bm.chains[seg] = [b for b in (p.strip() for p in bone.split(",")) if b and b in have]
        elif bone and bone in have:
            bm.bones[seg] = bone
        else:
            bm.bones.pop(seg, None)
    if overrides:
        whole = all(seg in overrides for seg in (*SINGLE_SEGMENTS, *sk.CHAIN_SEGMENTS))
        bm.scheme = "custom" if whole else f"{bm.scheme}+custom"
        used = set(bm.bones.values()) | {b for c in bm.chains.values() for b in c}
        bm.unmapped = [n for n in names if n not in used]
    return bm


def segment_value(bm: naming.BoneMap, segment: str) -> str:
    """A segment's bone as the bone map editor shows it: a chain's bones ", "-separated, bottom-up."""
    if segment in sk.CHAIN_SEGMENTS:
        return ", ".join(bm.chains.get(segment, []))
    return bm.bones.get(segment, "")


def check_bone_map(bm: naming.BoneMap, source: str = "armature", segment: str | None = None) -> None:
    """Each bone of the map serves one segment, else one line naming the bone and both segments.
    With `segment` (the one just edited) only a clash of its own bones counts: one elsewhere was
    there before the edit, and is the map's own problem (`check_overrides`)."""
    places = [(s, b) for s, b in bm.bones.items() if b]
    places += [(f"{c}[{i}]" if len(bs) > 1 else c, b) for c, bs in bm.chains.items() for i, b in enumerate(bs)]
    if segment is None:
        shared = _first_shared(places)
    else:
        mine = [p for p in places if p[0] == segment or p[0].startswith(segment + "[")]
        others: dict[str, str] = {}
        for where, bone in places:
            if (where, bone) not in mine:
                others.setdefault(bone, where)
        shared = next(((b, others[b], w) for w, b in mine if b in others), None) or _first_shared(mine)
    if shared:
        bone, first, second = shared
        raise BodyCalError(f"bone {short_repr(bone)} is given to {first} and {second}", source=source,
                           hint=f"a bone can serve one segment only: clear {first} first, or pick another bone")


def check_overrides(bone_names, overrides: dict[str, str], source: str = "armature") -> None:
    """A stored map the armature can use as it is: every bone it names still there (a renamed or
    deleted bone, with the nearest name), each bone on one segment; the first problem is one line."""
    names = list(dict.fromkeys(bone_names))
    have = set(names)
    for seg, value in overrides.items():
        bones = [p.strip() for p in value.split(",")] if seg in sk.CHAIN_SEGMENTS else [value]
        for bone in bones:
            if bone:
                _check_bone(source, seg, bone, have, names)
    check_bone_map(map_with_overrides(names, overrides), source)


def edit_overrides(bone_names, overrides: dict[str, str], segment: str, value: str | None,
                   source: str = "armature") -> dict[str, str]:
    """The overrides after one edit: `segment` set to `value` (a bone name; a chain's bones
    comma-separated, bottom-up; "" unmaps it) or given back to detection (None). Refused with one
    line: an unknown segment, a bone the armature lacks (with the nearest name), a bone that would
    serve two segments."""
    names = list(dict.fromkeys(bone_names))
    if segment not in sk.SEGMENTS:
        raise BodyCalError(_unknown(str(segment), sk.SEGMENTS, "segment"), source=source,
                           hint="segments are named as in docs/FORMATS.md §5")
    out = dict(overrides)
    if value is None:
        out.pop(segment, None)
    else:
        # A single segment takes the name as it is (a bone name may hold a comma); a chain a list.
        bones = [p.strip() for p in value.split(",") if p.strip()] if segment in sk.CHAIN_SEGMENTS else \
            [value] if value else []
        have = set(names)
        for bone in bones:
            _check_bone(source, segment, bone, have, names)
        out[segment] = ",".join(bones)
    check_bone_map(map_with_overrides(names, out), source, segment)
    return out


def _text(value, source: str, where: str, what: str) -> str:
    if not isinstance(value, str) or not value.strip():
        raise BodyCalError(f"must be {what} (a non-empty string), got {short_repr(value)}", source=source, field=where)
    if _CONTROL.search(value):
        raise BodyCalError("contains a control character (such as a newline)", source=source, field=where)
    return value


def _unknown(value: str, known, what: str) -> str:
    close = difflib.get_close_matches(value, list(known), n=1)
    return f"unknown {what} {short_repr(value)}" + (f" (did you mean {close[0]!r}?)" if close else "")


def parse_preset(data, source: str = "bone map", default_name: str = "bone map") -> BonePreset:
    """A preset from parsed JSON, every field checked (module docstring)."""
    if not isinstance(data, dict):
        raise BodyCalError(f"a bone map preset is a JSON object, got {type(data).__name__}", source=source)
    for key in data:
        if key not in KEYS:
            raise BodyCalError(_unknown(str(key), KEYS, "key") + f"; allowed: {', '.join(KEYS)}", source=source,
                               field=str(key))
    if data.get("format") != FORMAT:
        raise BodyCalError(f"must be \"{FORMAT}\", got {short_repr(data.get('format'))}", source=source,
                           field="format", hint="not a BodyCal bone map preset")
    version = data.get("version")
    if isinstance(version, bool) or version != VERSION:
        raise BodyCalError(f"version {short_repr(version)} is not supported (this BodyCal reads version {VERSION})",
                           source=source, field="version")
    name = _text(data["name"], source, "name", "a name") if data.get("name") is not None else default_name
    scheme = data.get("scheme")
    if scheme is not None:
        scheme = _text(scheme, source, "scheme", "a naming scheme")
        if scheme not in naming.SCHEME_BY_NAME:
            raise BodyCalError(_unknown(scheme, naming.SCHEME_BY_NAME, "naming scheme") +
                               f"; known: {', '.join(naming.SCHEME_BY_NAME)}", source=source, field="scheme")
    raw_bones = data.get("bones", {})
    if not isinstance(raw_bones, dict):
        raise BodyCalError(f"must be an object {{segment: bone}}, got {short_repr(raw_bones)}", source=source,
                           field="bones")
    bones: dict[str, str | None] = {}
    for seg, bone in raw_bones.items():
        where = f"bones.{seg}"
        if seg in sk.CHAIN_SEGMENTS:
            raise BodyCalError(f"'{seg}' is a chain of bones: list them bottom-up under \"chains\"", source=source,
                               field=where)
        if seg not in SINGLE_SEGMENTS:
            raise BodyCalError(_unknown(str(seg), SINGLE_SEGMENTS, "segment"), source=source, field=where,
                               hint="segments are named as in docs/FORMATS.md §5")
        bones[seg] = None if bone is None or bone == "" else _text(bone, source, where, "a bone name or null")
    raw_chains = data.get("chains", {})
    if not isinstance(raw_chains, dict):
        raise BodyCalError(f"must be an object {{\"spine\": [...], \"neck\": [...]}}, got {short_repr(raw_chains)}",
                           source=source, field="chains")
    chains: dict[str, list[str]] = {}
    for chain, chain_bones in raw_chains.items():
        where = f"chains.{chain}"
        if chain not in sk.CHAIN_SEGMENTS:
            raise BodyCalError(_unknown(str(chain), sk.CHAIN_SEGMENTS, "chain") + "; chains are spine and neck",
                               source=source, field=where)
        if not isinstance(chain_bones, list):
            raise BodyCalError(f"must be a list of bone names, bottom-up, got {short_repr(chain_bones)}",
                               source=source, field=where)
        chains[chain] = [_text(b, source, f"{where}[{i}]", "a bone name") for i, b in enumerate(chain_bones)]
    if scheme is None and not any(bones.values()) and not any(chains.values()):
        raise BodyCalError("maps no bone: give a \"scheme\" or list \"bones\"", source=source)
    _check_once(source, bones, chains)
    return BonePreset(name, scheme, bones, chains, source)


def load_preset(path) -> BonePreset:
    """Read a preset file: whatever the bytes, a preset or one line naming the file."""
    path = Path(path)
    source = str(path)
    try:
        if path.is_dir():
            raise BodyCalError("is a folder, not a bone map preset", source=source)
        with open(path, "rb") as fh:
            raw = fh.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise BodyCalError("no such file", source=source) from None
    except OSError as exc:
        raise BodyCalError(f"cannot read it: {exc.strerror or exc}", source=source) from None
    if len(raw) > MAX_BYTES:
        raise BodyCalError(f"is larger than {MAX_BYTES // 1024} kB: not a bone map preset", source=source)
    try:
        data = json.loads(raw.decode("utf-8-sig"))
    except UnicodeDecodeError:
        raise BodyCalError("not valid JSON (not UTF-8 text)", source=source) from None
    except json.JSONDecodeError as exc:
        raise BodyCalError(f"not valid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})", source=source) \
            from None
    except RecursionError:
        raise BodyCalError("not valid JSON (nested too deeply)", source=source) from None
    return parse_preset(data, source, default_name=path.name.split(".")[0] or "bone map")


def builtin_presets() -> list[BonePreset]:
    """One preset per naming scheme: apply it to force that scheme on a rig."""
    return [BonePreset(s.title, s.name, source=f"built-in: {s.name}") for s in naming.SCHEMES]


def preset_from_bone_map(bm: naming.BoneMap, name: str) -> BonePreset:
    """The whole map as a preset without a scheme: applied to the same armature it gives the
    same map, whatever detection would say."""
    return BonePreset(name, None, dict(bm.bones), {c: list(v) for c, v in bm.chains.items() if v})
