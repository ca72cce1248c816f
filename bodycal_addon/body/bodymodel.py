"""`BodyModel`: the output of the user calibration and of the avatar surface calibration
(FORMATS.md §3, `*.body.json`). One schema for both, so the egocentric mapping is symmetric.

Conventions (this module is their reference):
- `joints[name].world`: position in the internal world frame (Z up, metres) at `reference_time`
  (user) or in the avatar's rest pose (avatar).
- `joints[name].frame` / `.local`: the tracker role (user) or avatar bone name (avatar) the joint
  rides on, and its position in that frame. For an avatar bone the frame is the bone's rest
  matrix (head at the origin, +Y along the bone).
- `bones[name].right`: the bone's local right (flexion axis for hinges) as a world direction at
  the reference time / in the rest pose; `radius_head` / `radius_tail` are capsule radii.
- `surface`: elements of types `capsule` (around a bone), `sphere` (`center` local to `bone`),
  `mesh` (named points, each local to a bone, and triangles over the point names). A capsule may
  carry `axis_head` / `axis_tail` (extension of FORMATS.md §3, kept in `extra`): where its axis
  starts and ends relative to the bone's head and tail joints, in the bone's frame (m); absent,
  the axis runs joint to joint. A thigh's femur runs well behind the middle of the thigh.
- `offsets` (optional, AvatarGo §3.3): per joint, the tracker role and `v0` (tracker
  to joint vector, world), `r0_tracker` and `r0_joint` (world rotations, quaternions w, x, y, z)
  at the T-pose.
- `extra`: anything else a producer wants to keep (readers keep unknown fields round-trip).

What a `kind: "user"` model carries for animation (Delahaye 2023, appendix D; the user calibration
produces it, the synthetic performer's ground truth produces the exact same thing, the retargeting
engine consumes it):
- `joints[name].frames`: {tracker role: local position} for every tracker the joint is known in
  (`frame`/`local` repeat the first): wrist, mcp/pip/dip/tip (extended finger) in `hand_<s>`;
  elbow in `forearm_<s>` (else `hand_<s>`) and `upperarm_<s>`; shoulder in `upperarm_<s>` and the
  root tracker (`chest`, else `pelvis`); knee in `shin_<s>` (else `foot_<s>`) and `thigh_<s>`; hip
  in `thigh_<s>` and `pelvis`; ankle and toe in `foot_<s>`; pelvis and spine_root in `pelvis`;
  skull_base and head in `head`. A joint no tracker carries has only `world`.
- `bones[hinge].extra`: `right_local` (flexion axis) and `right_frame` (the tracker role it is
  expressed in) for forearm_<s> and shin_<s>.
- `extra["tpose"]`: {role: [px, py, pz, qw, qx, qy, qz]} device poses at the reference time;
  `extra["eye_height"]`; `extra["palm_planes"]`: {`hand_<s>`: {"point", "normal"}} in the hand
  frame, normal out of the palm.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import math
import numbers
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..core import outputs
from ..core.errors import BodyCalError

FORMAT = "bodycal-body"
VERSION = 1
KINDS = ("user", "avatar")
ELEMENT_TYPES = ("capsule", "sphere", "mesh")
MAX_COORD_M = 1e4  # a position or offset 10 km or more from its origin is a damaged value
MAX_NESTING = 64  # deeper JSON is not a body model (and would exhaust Python's recursion)
REQUIRED_USER_JOINTS = ("hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r", "shoulder_l", "shoulder_r",
                        "elbow_l", "elbow_r", "wrist_l", "wrist_r", "skull_base", "spine_root")


def _is_number(x) -> bool:
    """A JSON number: not true / false (Python's bool is an int) and not a numeric string."""
    return isinstance(x, numbers.Real) and not isinstance(x, bool | np.bool_)


def _vec(value, source, field_name, n=3) -> np.ndarray:
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, list | tuple) or len(value) != n or not all(_is_number(x) for x in value):
        raise BodyCalError(f"expected a list of {n} numbers, got {value!r:.60}", source=source, field=field_name)
    arr = np.array(value, dtype=float)
    with np.errstate(invalid="ignore"):
        if not (np.abs(arr) < MAX_COORD_M).all():
            raise BodyCalError(f"expected {n} finite numbers below {MAX_COORD_M:g} in size, got {value!r:.60}",
                               source=source, field=field_name)
    return arr


# Numbers are written to 7 decimals (0.1 µm, 1e-7 rad: far below any measurement); `exact` JSON keeps
# every float64 as it is (repr round-trips exactly), for a model sent to another process that must
# solve what this one would (live/worker.py).
_EXACT = contextvars.ContextVar("bodycal_exact_json", default=False)


@contextlib.contextmanager
def _exactly(exact: bool):
    token = _EXACT.set(exact)
    try:
        yield
    finally:
        _EXACT.reset(token)


def _num(x, digits: int = 7) -> float:
    return float(x) if _EXACT.get() else round(float(x), digits)


def _list(v):
    return None if v is None else [_num(x) for x in np.asarray(v).ravel()]


@dataclass
class Joint:
    world: np.ndarray
    frame: str | None = None
    local: np.ndarray | None = None
    frames: dict[str, np.ndarray] = field(default_factory=dict)  # every tracker the joint is known in

    def __post_init__(self):
        if self.frame is not None and self.local is not None and self.frame not in self.frames:
            self.frames = {self.frame: self.local, **self.frames}

    def to_dict(self):
        d = {"world": _list(self.world)}
        if self.frame is not None:
            d["frame"] = self.frame
        if self.local is not None:
            d["local"] = _list(self.local)
        if set(self.frames) - {self.frame}:
            d["frames"] = {k: _list(v) for k, v in self.frames.items()}
        return d


@dataclass
class BoneInfo:
    head: str
    tail: str
    length: float
    right: np.ndarray | None = None
    radius_head: float | None = None
    radius_tail: float | None = None
    extra: dict = field(default_factory=dict)

    def to_dict(self):
        d = {"head": self.head, "tail": self.tail, "length": _num(self.length)}
        if self.right is not None:
            d["right"] = _list(self.right)
        if self.radius_head is not None:
            d["radius_head"] = _num(self.radius_head)
        if self.radius_tail is not None:
            d["radius_tail"] = _num(self.radius_tail)
        d.update(self.extra)
        return d


@dataclass
class SurfacePoint:
    bone: str
    local: np.ndarray

    def to_dict(self):
        return {"bone": self.bone, "local": _list(self.local)}


@dataclass
class SurfaceElement:
    id: str
    type: str
    bone: str
    center: np.ndarray | None = None  # sphere: local to `bone`
    radius: float | None = None  # sphere
    points: dict[str, SurfacePoint] = field(default_factory=dict)  # mesh
    triangles: list[tuple[str, str, str]] = field(default_factory=list)  # mesh
    extra: dict = field(default_factory=dict)

    def to_dict(self):
        d = {"id": self.id, "type": self.type, "bone": self.bone}
        if self.center is not None:
            d["center"] = _list(self.center)
        if self.radius is not None:
            d["radius"] = _num(self.radius)
        if self.points:
            d["points"] = {k: p.to_dict() for k, p in self.points.items()}
        if self.triangles:
            d["triangles"] = [list(t) for t in self.triangles]
        d.update(self.extra)
        return d

    def axis_offsets(self) -> np.ndarray:
        """(2, 3) capsule axis offsets at the head and tail joints, in the bone's frame (zeros when
        the axis runs joint to joint)."""
        return np.array([self.extra.get("axis_head", (0.0, 0.0, 0.0)), self.extra.get("axis_tail", (0.0, 0.0, 0.0))],
                        float)

    def set_axis_offsets(self, head, tail) -> None:
        self.extra["axis_head"] = _list(np.asarray(head, float))
        self.extra["axis_tail"] = _list(np.asarray(tail, float))


@dataclass
class Offset:
    """AvatarGo exact offset of one joint from its tracker (AvatarGo, eq. 2-3)."""

    tracker: str
    v0: np.ndarray  # p0(J) - p0(T), world
    r0_tracker: np.ndarray  # R0(T), quaternion
    r0_joint: np.ndarray  # R0(J), quaternion

    def to_dict(self):
        return {"tracker": self.tracker, "v0": _list(self.v0), "r0_tracker": _list(self.r0_tracker),
                "r0_joint": _list(self.r0_joint)}


@dataclass
class BodyModel:
    kind: str
    name: str
    joints: dict[str, Joint] = field(default_factory=dict)
    bones: dict[str, BoneInfo] = field(default_factory=dict)
    surface: list[SurfaceElement] = field(default_factory=list)
    reference_time: float | None = None
    offsets: dict[str, Offset] = field(default_factory=dict)
    calibration: dict = field(default_factory=lambda: {"steps_used": [], "defaulted": {}, "missing": [],
                                                       "quality": {}})
    extra: dict = field(default_factory=dict)

    def world(self, joint: str) -> np.ndarray:
        try:
            return self.joints[joint].world
        except KeyError:
            raise BodyCalError(f"joint '{joint}' is not in the body model", source=self.name) from None

    def element(self, element_id: str) -> SurfaceElement:
        for e in self.surface:
            if e.id == element_id:
                return e
        raise BodyCalError(f"surface element '{element_id}' is not in the body model", source=self.name)

    # --- JSON ------------------------------------------------------------------------------

    def to_dict(self, exact: bool = False) -> dict:
        """The model as FORMATS.md §3's JSON object; `exact`: every number as it is (not to 7 decimals)."""
        with _exactly(exact):
            return self._to_dict()

    def _to_dict(self) -> dict:
        d = {"format": FORMAT, "version": VERSION, "kind": self.kind, "name": self.name}
        if self.reference_time is not None:
            d["reference_time"] = _num(self.reference_time, 6)
        d["joints"] = {k: j.to_dict() for k, j in self.joints.items()}
        d["bones"] = {k: b.to_dict() for k, b in self.bones.items()}
        d["surface"] = [e.to_dict() for e in self.surface]
        if self.offsets:
            d["offsets"] = {k: o.to_dict() for k, o in self.offsets.items()}
        d["calibration"] = self.calibration
        d.update(self.extra)
        return d

    def to_json(self, exact: bool = False) -> str:
        if exact:  # for another process, not a file: compact
            return json.dumps(self.to_dict(exact=True), allow_nan=False)
        return json.dumps(self.to_dict(), indent=1, allow_nan=False)

    def save(self, path, *, overwrite: bool = True, inputs=(), field: str = "-o") -> Path:
        """Write the model to `path` (folders created). Never half-written, never over a symlink,
        a device or one of `inputs` ((what, path) pairs); an existing file is replaced only with
        `overwrite` (the file browser has already asked; the command line asks for --overwrite)."""

        text = self.to_json()  # a model that cannot be written (NaN) fails before the target is touched
        return outputs.write_text(path, text, overwrite=overwrite, inputs=inputs, field=field)

    @classmethod
    def load(cls, path) -> BodyModel:
        """Read a *.body.json. Whatever the bytes (binary, a .blend, not UTF-8, JSON nested beyond
        Python's recursion), the outcome is a model or a one-line BodyCalError naming the file."""
        path = Path(path)
        source = str(path)
        hint = "give the *.body.json written by calibrate-user or calibrate-avatar"
        try:
            raw = path.read_bytes()
        except OSError as exc:
            raise BodyCalError(f"cannot read: {exc.strerror}", source=source) from None
        if raw.startswith(b"BLENDER") or raw[:4] in (b"\x28\xb5\x2f\xfd", b"\x1f\x8b\x08\x00"):
            raise BodyCalError("is a .blend file, not a body model", source=source, hint=hint)
        try:
            text = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise BodyCalError(f"not UTF-8 text (byte {exc.start}): not a body model", source=source,
                               hint=hint) from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise BodyCalError(f"not valid JSON ({exc.msg})", source=source,
                               where=f"line {exc.lineno} column {exc.colno}", hint=hint) from None
        except RecursionError:
            raise BodyCalError("not valid JSON (nested too deeply)", source=source, hint=hint) from None
        return cls.from_dict(data, source=source)

    @classmethod
    def from_dict(cls, data: dict, source: str = "body model", exact: bool = False) -> BodyModel:
        """A model from its JSON object, checked field by field (one BodyCalError naming the field);
        `exact`: the numbers kept as they are (`to_dict(exact=True)`'s), none rounded on the way."""
        with _exactly(exact):
            return cls._from_dict(data, source)

    @classmethod
    def _from_dict(cls, data: dict, source: str) -> BodyModel:
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise BodyCalError(f"not a body model (format must be '{FORMAT}')", source=source, field="format")
        _check_tree(data, source)
        if data.get("version") != VERSION:
            raise BodyCalError(f"unsupported version {data.get('version')!r}, this BodyCal reads {VERSION}",
                               source=source, field="version")
        kind = data.get("kind")
        if kind not in KINDS:
            raise BodyCalError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}", source=source, field="kind")
        joints = {}
        for name, j in _dict(data.get("joints", {}), source, "joints").items():
            j = _dict(j, source, f"joints.{name}")
            if "world" not in j:
                raise BodyCalError("missing 'world'", source=source, field=f"joints.{name}")
            local = j.get("local")
            if j.get("frame") is not None and not isinstance(j.get("frame"), str):
                raise BodyCalError(f"expected a tracker or bone name, got {j.get('frame')!r:.40}", source=source,
                                   field=f"joints.{name}.frame")
            frames = {k: _vec(v, source, f"joints.{name}.frames.{k}")
                      for k, v in _dict(j.get("frames", {}), source, f"joints.{name}.frames").items()}
            joints[name] = Joint(_vec(j["world"], source, f"joints.{name}.world"), j.get("frame"),
                                 None if local is None else _vec(local, source, f"joints.{name}.local"), frames)
        bones = {}
        for name, b in _dict(data.get("bones", {}), source, "bones").items():
            b = _dict(b, source, f"bones.{name}")
            known = {"head", "tail", "length", "right", "radius_head", "radius_tail"}
            try:
                bones[name] = BoneInfo(
                    str(b["head"]), str(b["tail"]), _positive(b["length"], source, f"bones.{name}.length"),
                    None if b.get("right") is None else _vec(b["right"], source, f"bones.{name}.right"),
                    _opt_radius(b.get("radius_head"), source, f"bones.{name}.radius_head"),
                    _opt_radius(b.get("radius_tail"), source, f"bones.{name}.radius_tail"),
                    {k: v for k, v in b.items() if k not in known})
            except KeyError as exc:
                raise BodyCalError(f"missing '{exc.args[0]}'", source=source, field=f"bones.{name}") from None
            if b.get("right_local") is not None:  # used by the retargeting: checked here, not mid-bake
                _vec(b["right_local"], source, f"bones.{name}.right_local")
        surface = []
        if not isinstance(data.get("surface", []), list):
            raise BodyCalError("expected a list", source=source, field="surface")
        for i, e in enumerate(data.get("surface", [])):
            e = _dict(e, source, f"surface[{i}]")
            etype = e.get("type")
            if etype not in ELEMENT_TYPES:
                raise BodyCalError(f"type must be one of {', '.join(ELEMENT_TYPES)}, got {etype!r}", source=source,
                                   field=f"surface[{i}].type")
            pts = {k: SurfacePoint(str(_dict(p, source, f"surface[{i}].points.{k}").get("bone", e.get("bone"))),
                                   _vec(p.get("local"), source, f"surface[{i}].points.{k}.local"))
                   for k, p in _dict(e.get("points", {}), source, f"surface[{i}].points").items()}
            tris = []
            for t in e.get("triangles", []):
                if not (isinstance(t, list) and len(t) == 3 and all(v in pts for v in t)):
                    raise BodyCalError(f"triangle {t!r:.60} must name three of its points", source=source,
                                       field=f"surface[{i}].triangles")
                tris.append(tuple(t))
            known = {"id", "type", "bone", "center", "radius", "points", "triangles"}
            for end in ("axis_head", "axis_tail"):
                if end in e:  # checked here so a bad offset fails on load, not mid-retarget
                    e[end] = _list(_vec(e[end], source, f"surface[{i}].{end}"))
            surface.append(SurfaceElement(
                str(e.get("id", f"{etype}:{i}")), etype, str(e.get("bone", "")),
                None if e.get("center") is None else _vec(e["center"], source, f"surface[{i}].center"),
                _opt_radius(e.get("radius"), source, f"surface[{i}].radius"), pts, tris,
                {k: v for k, v in e.items() if k not in known}))
        offsets = {}
        for name, o in _dict(data.get("offsets", {}), source, "offsets").items():
            o = _dict(o, source, f"offsets.{name}")
            offsets[name] = Offset(str(o.get("tracker")), _vec(o.get("v0"), source, f"offsets.{name}.v0"),
                                   _vec(o.get("r0_tracker"), source, f"offsets.{name}.r0_tracker", 4),
                                   _vec(o.get("r0_joint"), source, f"offsets.{name}.r0_joint", 4))
        _check_known_extras(data, source)
        calibration = data.get("calibration", {"steps_used": [], "defaulted": {}, "missing": [], "quality": {}})
        _dict(calibration, source, "calibration")
        known_top = {"format", "version", "kind", "name", "reference_time", "joints", "bones", "surface", "offsets",
                     "calibration"}
        return cls(kind, str(data.get("name", "")), joints, bones, surface,
                   _opt_number(data.get("reference_time"), source, "reference_time"), offsets,
                   calibration, {k: v for k, v in data.items() if k not in known_top})


def _dict(v, source, field_name) -> dict:
    if not isinstance(v, dict):
        raise BodyCalError("expected an object", source=source, field=field_name)
    return v


def _number(v, source, field_name) -> float:
    if not _is_number(v) or not math.isfinite(v):
        raise BodyCalError(f"expected a finite number, got {v!r:.40}", source=source, field=field_name)
    return float(v)


def _opt_number(v, source, field_name):
    return None if v is None else _number(v, source, field_name)


def _positive(v, source, field_name) -> float:
    x = _number(v, source, field_name)
    if not 0 < x < MAX_COORD_M:
        raise BodyCalError(f"must be a positive length in metres, got {v!r:.40}", source=source, field=field_name,
                           hint="recalibrate: a bone's head and tail joints coincide or are swapped")
    return x


def _opt_radius(v, source, field_name):
    x = _opt_number(v, source, field_name)
    if x is not None and not 0 <= x < MAX_COORD_M:
        raise BodyCalError(f"must be a radius in metres (0 or more), got {v!r:.40}", source=source, field=field_name)
    return x


def _check_tree(data, source) -> None:
    """Walk the whole document (iteratively: depth is what is being checked) once: refuse nesting
    deeper than MAX_NESTING and any NaN / Infinity (JSON extensions Python reads) or overflowing
    number like 1e999, naming its field, so that a non-finite value anywhere, extras included, is
    blamed on the body file rather than on the recording it is later used with."""
    stack = [(data, "", 0)]
    while stack:
        value, where, depth = stack.pop()
        if depth > MAX_NESTING:
            raise BodyCalError(f"nested more than {MAX_NESTING} levels deep", source=source, field=where or None,
                               hint="not a body model")
        if isinstance(value, dict):
            stack.extend((v, f"{where}.{k}" if where else str(k), depth + 1) for k, v in value.items())
        elif isinstance(value, list | tuple):
            stack.extend((v, f"{where}[{k}]", depth + 1) for k, v in enumerate(value))
        elif isinstance(value, float) and not math.isfinite(value):
            raise BodyCalError(f"{value} is not a finite number", source=source, field=where or None,
                               hint="write finite numbers (JSON has no NaN or Infinity)")


def _check_known_extras(data, source) -> None:
    """The extras the retargeting reads (module docstring), checked on load like the schema."""
    tpose = data.get("tpose")
    if tpose is not None:
        for role, pose in _dict(tpose, source, "tpose").items():
            _vec(pose, source, f"tpose.{role}", 7)
    for key in ("eye_height", "sacrum_width"):
        if data.get(key) is not None:
            _positive(data[key], source, key)
    planes = data.get("palm_planes")
    if planes is not None:
        for hand, plane in _dict(planes, source, "palm_planes").items():
            plane = _dict(plane, source, f"palm_planes.{hand}")
            for k in ("point", "normal"):
                if k in plane:
                    _vec(plane[k], source, f"palm_planes.{hand}.{k}")
