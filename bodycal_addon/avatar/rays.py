"""The avatar surface calibration's ray plan (DESIGN.md §4; Delahaye 2023, appendix C: "surface
measurements are performed using ray cast hit points on the collider mesh of the avatar"), numpy
only. `surface_from_rays(rig, caster, name)` casts every ray below through any `RayCaster` (in
Blender: `blender.avatar_calibration`'s BVH trees on the evaluated meshes; in the tests: analytic
capsules, spheres and boxes) and returns a `kind: "avatar"` BodyModel with exactly the elements of
`surface_layout.element_ids()`.

Every ray is documented below. Directions are in the avatar's body frame from `avatar_rig`:
F = forward, L = towards the avatar's left, U = up. "az" turns F towards L (+) or away from it
(-) in degrees (180 = straight back), "el" raises (+) or lowers (-) the direction. `h` is a
height above the pelvis (midpoint of the hips) as a fraction of the shoulders' height above it;
"spine@h" is the point of the spine curve (pelvis, spine_root .. skull_base) at that height.

| element / point         | origin                                   | direction                       |
|-------------------------|------------------------------------------|---------------------------------|
| capsule:<bone>          | axis at 5 stations clear of the joints   | 12 rays around, ⟂ the bone      |
| head top (sizes head)   | skull_base + U * spine length            | -U (first hit from outside)     |
| head centre c           | skull_base + U * (head height / 2)       | -                               |
| sphere:skull            | c                                        | back (az 180 ± 30, 60) x el 0..60, and U |
| torso sternum           | spine@0.80                               | F                               |
| torso chest_l / _r      | spine@0.72                               | az +35 / -35                    |
| torso belly_ul / _ur    | spine@0.45                               | az +30 / -30                    |
| torso belly_ll / _lr    | spine@0.15                               | az +30 / -30                    |
| torso belly_c1..c4      | spine@ height of the bilinear default    | horizontally towards it (*)     |
| torso back_ul / _ur     | spine@0.72                               | az +145 / -145                  |
| torso back_low          | spine@0.30                               | az 180                          |
| jaw ear_l / ear_r       | c + D * 2 head heights, D = az +90 / -90 | -D (towards c, from outside)    |
| jaw upper_lip / chin    | same, D = az 0, el -35 / el -60          | -D                              |
| jaw jaw_l / jaw_r       | same, D = az +40 / -40, el -45           | -D                              |
| palm_1..4_<s>           | wrist + 0.85 / 0.85 / 0.3 / 0.3 of the   | middle_2 axis x hand dir (**)   |
|                         | way to mcp index / pinky / pinky / index |                                 |
| sole floor              | ankle, toe joint - U * (leg length + 0.1)| U (first hit from below)        |
| sole_1..6_<s>           | ankle / 15 % to toe / toe / toe / toe /  | -f / +lat / +lat / +f / -lat /  |
|                         | 15 %, at 20 % of the ankle's height (***)| -lat                            |
| sole contact (168 rays) | a grid under the floor over the foot's   | U (foot_contact.py)             |
|                         | footprint                                |                                 |

(*) the bilinear default of surface_layout.belly_centre_points from the four measured corners.
(**) out of the palm: the side the fingers flex to (a positive rotation about a finger's +X).
(***) f = ankle -> toe on the floor, lat = the avatar's left made orthogonal to f; hits are
projected onto the floor plane (the lowest of the two floor hits).

Capsule radii (DESIGN.md §4): per station, a circle is fitted to the ring's hits in the plane
across the bone (hits beyond 3 scaled MADs of the radius rejected, but never one within
`surface_fit.SKIN_WITHIN` of the radius: that is the limb's own skin; `surface_fit.cross_sections`);
the station radius is the mean distance of the rest to its centre; head/tail radii and the axis
offsets (`axis_head` / `axis_tail`: the centres' line, in the bone's frame) come from lines
through the stations (limbs: extrapolated to the joints within bounds, `surface_fit.linear_radii`;
phalanges: clamped to the stations' range).
Stations stay away from the joints, where the neighbouring part (torso, the next phalanx) would be
hit first. No angular radius profile is kept: most rings are round within ±2.5 % once centred, but
a thigh's front (the quadriceps) stands up to 13 % of the radius beyond the circle through the rest
of its ring, and the circle through all of it still leaves that front 4-6 mm under the skin on the
shared avatars (a palm laid there sinks as deep; DESIGN.md §4).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..body import skeleton as sk
from ..body import surface_layout as sl
from ..body.bodymodel import BodyModel, BoneInfo, Joint, SurfaceElement, SurfacePoint
from ..core.errors import BodyCalError
from . import foot_contact
from .armature import ArmatureReading, canonical_bones
from .surface_fit import cross_sections, linear_offsets, linear_radii, robust_keep, sphere_fit
from .template import TEMPLATE

CAPSULE_STATIONS = np.linspace(0.25, 0.75, 5)  # count; the span adapts (see below)
CAPSULE_RAYS = 12
LIMB_EXTRAPOLATION = 1.0  # a limb capsule's radius/axis line may reach this many station ranges beyond them
MIN_CAPSULE_HITS = 0.5  # fraction of a capsule's rays that must hit
CAPSULE_MAX = 1.0  # a fitted radius above this many bone lengths (or an axis offset above one) is no limb's

# (height fraction, azimuth degrees): see the table in the module docstring.
TORSO_RAYS = {
    "sternum": (0.80, 0.0),
    "chest_l": (0.72, 35.0), "chest_r": (0.72, -35.0),
    "belly_ul": (0.45, 30.0), "belly_ur": (0.45, -30.0),
    "belly_ll": (0.15, 30.0), "belly_lr": (0.15, -30.0),
    "back_ul": (0.72, 145.0), "back_ur": (0.72, -145.0),
    "back_low": (0.30, 180.0),
}
# (azimuth, elevation) degrees from the head centre.
JAW_RAYS = {
    "ear_l": (90.0, 0.0), "ear_r": (-90.0, 0.0),
    "upper_lip": (0.0, -35.0), "chin": (0.0, -60.0),
    "jaw_l": (40.0, -45.0), "jaw_r": (-40.0, -45.0),
}
SKULL_RAYS = [(180.0 + a, e) for e in (0.0, 20.0, 40.0, 60.0) for a in (-60.0, -30.0, 0.0, 30.0, 60.0)] + [(0.0, 90.0)]
# Palm ray origins: fraction of the way from the wrist to the index (I) or pinky (P) mcp.
PALM_RAYS = (("I", 0.85), ("P", 0.85), ("P", 0.30), ("I", 0.30))
SOLE_HEIGHT = 0.2  # of the ankle's height above the floor
SOLE_RAYS = 6  # the sole's outline: heel, both sides of the heel and of the toe, the toe


class RayCaster(Protocol):
    """What the ray plan needs of a scene: the first hit of a world-space ray, and a count of rays."""

    rays: int

    def cast(self, origin: np.ndarray, direction: np.ndarray, max_dist: float = 1e4
             ) -> tuple[np.ndarray, float] | None:
        """(hit point, distance) of the first surface hit along `direction` from `origin`, or None."""


def _dir(F, L, U, az: float, el: float = 0.0) -> np.ndarray:
    a, e = np.radians(az), np.radians(el)
    return np.cos(e) * (np.cos(a) * F + np.sin(a) * L) + np.sin(e) * U


def skeleton_model(rig: ArmatureReading, name: str, method: str = "raycast") -> tuple[BodyModel, dict]:
    """The avatar model of `rig` without its surface: joints, bones (with `right`), the calibration
    record (`method`, defaults, missing parts) and the canonical rest frames {bone: (3, 3)}."""
    model = BodyModel("avatar", name)
    quality: dict = {}
    defaulted: dict = {}
    for miss in rig.missing:
        if miss.startswith("toe_"):
            defaulted[miss.split()[0]] = "the foot bone's tail (the rig has no toe bone)"
    for joint in rig.estimated:
        defaulted[joint] = "placed by proportion (the bone's tail is an importer's guess)"
    for bone in rig.derived_hinges:
        defaulted[f"hinge:{bone}"] = "flexion axis from the chain's bend or the anatomy (the bone's local X is not it)"
    model.calibration = {"method": method, "steps_used": [method], "defaulted": defaulted,
                         "missing": [m for m in rig.missing if m.startswith("fingers")], "quality": quality}
    # Joints: exact rest positions, and where they ride on the avatar's own bones.
    for j in sk.JOINTS:
        if j in rig.joints:
            frame = rig.joint_frames[j]
            model.joints[j] = Joint(rig.joints[j].copy(), frame, rig.to_local(frame, rig.joints[j]))
    frames: dict[str, np.ndarray] = {}
    for b in canonical_bones(rig):
        h, t = rig.joints[b.head], rig.joints[b.tail]
        extra = {}
        if b.name in rig.bone_map.bones:
            extra["avatar_bone"] = rig.bone_map.bones[b.name]
        model.bones[b.name] = BoneInfo(b.head, b.tail, float(np.linalg.norm(t - h)), rig.rights[b.name].copy(),
                                       extra=extra)
        frames[b.name] = sl.bone_frame(h, t, rig.rights[b.name])
    model.extra["rig"] = rig.rig_dict()
    return model, frames


@dataclass
class _Survey:
    """What every pass of `surface_from_rays` shares: the rig read, the caster, the model being
    filled (its `calibration["quality"]` gets one entry per element) and the bones' rest frames."""
    rig: ArmatureReading
    caster: RayCaster
    model: BodyModel
    frames: dict[str, np.ndarray]

    def __post_init__(self):
        self.quality = self.model.calibration["quality"]
        self.F, self.L, self.U = self.rig.forward, self.rig.lateral, self.rig.up
        self.J = self.rig.joints

    def local(self, bone: str, p: np.ndarray) -> np.ndarray:
        """A world point in `bone`'s rest frame, about its head."""
        return self.frames[bone].T @ (p - self.J[sk.BONE_BY_NAME[bone].head])

    def hit(self, point: str, bone_for_message: str, origin, direction, max_dist=1e4):
        """The caster's (hit, distance) for a ray that must hit; a miss is one error naming `point`."""
        r = self.caster.cast(origin, direction / np.linalg.norm(direction), max_dist)
        if r is None:
            raise BodyCalError(f"the ray for {point} (from near bone {bone_for_message}) missed the mesh",
                               source=self.rig.armature,
                               hint="check that the mesh covers this part, or edit the point by hand")
        return r


def surface_from_rays(rig: ArmatureReading, caster: RayCaster, name: str) -> BodyModel:
    """The avatar model of `rig` measured with `caster`: every element of `surface_layout.element_ids()`
    (or a default and a note in `calibration["defaulted"]`), the rig for FK in `extra["rig"]`."""
    model, frames = skeleton_model(rig, name)
    survey = _Survey(rig, caster, model, frames)
    _measure_capsules(survey)
    try:
        centre, head_h = _head_centre(survey)
        _measure_skull(survey, centre, head_h)
        _measure_jaw(survey, centre, head_h)
    except BodyCalError as exc:  # a helmet, hair or a mask around the head: its proportions stand in
        model.surface[:] = [e for e in model.surface if e.id not in ("sphere:skull", "mesh:jaw")]
        _estimate_head(survey, exc.message)
    _measure_torso(survey)
    for s in sk.SIDES:  # palm then sole, side by side: the order the rays are cast and reported in
        _measure_palm(survey, s)
        try:
            _measure_sole(survey, s)
        except BodyCalError as exc:  # a stylised foot (a robot's disc the outline rays miss)
            _estimate_sole(survey, s, exc.message)
    model.surface.sort(key=lambda e: _ORDER.get(e.id, len(_ORDER)))
    model.extra["rig"] = rig.rig_dict()
    model.extra["rays_cast"] = caster.rays
    return model


def planned_rays(rig: ArmatureReading) -> int:
    """How many rays `surface_from_rays` casts on `rig` (a progress bar's end): each capsule's probe
    ring and its station rings, the head top, the skull, the jaw, the torso and its belly centre,
    and per side the palm, the two floor rays, the sole's outline and its contact grid."""
    capsules = sum(1 for b in canonical_bones(rig) if b.name in sl.CAPSULE_BONES)
    head = 1 + len(SKULL_RAYS) + len(JAW_RAYS)
    torso = len(TORSO_RAYS) + len(sl.BELLY_CENTRE_UV)
    per_side = len(PALM_RAYS) + 2 + SOLE_RAYS + foot_contact.RAYS + foot_contact.BACK_RAYS
    return capsules * (1 + len(CAPSULE_STATIONS)) * CAPSULE_RAYS + head + torso + len(sk.SIDES) * per_side


def _measure_capsules(survey: _Survey) -> None:
    """Capsules pass: for every `CAPSULE_BONES` bone the model has, in that order, measures its
    cross-sections (`_capsule_sections`) and sets the bone's `radius_head` / `radius_tail`, appends
    `capsule:<bone>` with its axis offsets and records its quality. Raises when too few rays hit."""
    angles = np.linspace(0.0, 2 * np.pi, CAPSULE_RAYS, endpoint=False)
    ring_2d = np.stack([np.cos(angles), np.sin(angles)], axis=-1)  # (rays, 2): bone x, z
    limbs = [b for b in sl.CAPSULE_BONES if b in survey.model.bones and b.split("_")[0] not in sk.FINGERS]
    missed = []
    for bone in sl.CAPSULE_BONES:
        if bone in survey.model.bones:
            why = _measure_capsule(survey, bone, ring_2d)
            if why is not None and bone in limbs:
                missed.append(why)
    # A stylised part (a robot's bare rod of an upper arm) is one thing; most of the body missed
    # is a mesh that is not around these bones.
    if 2 * len(missed) > len(limbs):
        raise BodyCalError(missed[0], source=survey.rig.armature,
                           hint="is the mesh skinned to this armature and around the bone?")


def _capsule_sections(survey: _Survey, bone: str, ring_2d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Casts `bone`'s rings: (stations as fractions along the bone, (stations, CAPSULE_RAYS, 2) hit
    points in the bone's (x, z) plane, NaN where a ray missed). Reads the joints and the frame."""
    J = survey.J
    h, t = J[sk.BONE_BY_NAME[bone].head], J[sk.BONE_BY_NAME[bone].tail]
    R = survey.frames[bone]
    length = np.linalg.norm(t - h)

    dirs = ring_2d @ np.stack([R[:, 0], R[:, 2]])  # (rays, 3) world directions

    def section(st):
        """(CAPSULE_RAYS, 2) hit points of a station's ring in the bone's (x, z) plane, NaN
        where a ray missed."""
        o = h + st * (t - h)
        dist = np.full(len(dirs), np.nan)
        for k, d in enumerate(dirs):
            r = survey.caster.cast(o, d, max_dist=length)
            if r is not None:
                dist[k] = r[1]
        return ring_2d * dist[:, None]

    # Stations keep clear of the joints by 1.6 probe radii: the neighbouring part's surface
    # (a thicker parent's rounded end, the next phalanx, the torso at the hip) reaches about
    # that far. A fingertip has no neighbour beyond its tail.
    probe = np.linalg.norm(section(0.5), axis=1)
    probe = probe[np.isfinite(probe)]
    margin = 0.25
    if len(probe) >= 3:
        margin = float(np.clip(1.6 * probe[robust_keep(probe)].mean() / length, 0.1, 0.45))
    tail_margin = min(margin, 0.25) if bone.split("_")[1:2] == ["3"] else margin
    stations = np.linspace(margin, 1.0 - tail_margin, len(CAPSULE_STATIONS))
    return stations, np.stack([section(st) for st in stations])


def _measure_capsule(survey: _Survey, bone: str, ring_2d: np.ndarray) -> str | None:
    """One bone of the capsules pass (see `_measure_capsules`); returns why its capsule was
    estimated from the body's proportions (too few of its rays hit the mesh), else None."""
    rig, model = survey.rig, survey.model
    stations, pts = _capsule_sections(survey, bone, ring_2d)
    hits = np.isfinite(pts).all(axis=-1)
    # Decision (beyond Delahaye 2023's bone-centred capsules): the capsule's axis goes through
    # the middle of the cross-section, not along the bone; a femur runs ~25 mm behind the
    # middle of an adult thigh, and a hand resting on the thigh sank that far into it.
    centres, radii, keep = cross_sections(pts)
    used = np.isfinite(radii)
    n_hit, n_rej = int(hits.sum()), int((hits & ~keep)[used].sum())
    station_t, station_r, station_c = stations[used], radii[used], centres[used]
    spreads = [np.linalg.norm(pts[i][keep[i]] - centres[i], axis=1) - radii[i] for i in np.flatnonzero(used)]
    rays = CAPSULE_RAYS * len(CAPSULE_STATIONS)
    avatar_bone = rig.bone_map.bones.get(bone, bone)
    if n_hit < MIN_CAPSULE_HITS * rays or len(station_r) < 2:
        # A finger the mesh does not model (a mitten hand), too thin for the rings, or a limb a
        # stylised character leaves bare (RobotExpressive's upper arms: a shoulder ball and the
        # forearm, 35 % of the rays hit): its proportions to its bone stand in, and the calibration
        # says so (most of the limbs missed: refused, `_measure_capsules`).
        why = f"capsule:{bone}: only {n_hit} of {rays} rays from bone {avatar_bone} hit the mesh"
        _estimate_capsule(survey, bone, why.split(": ", 1)[1])
        return why
    extend = LIMB_EXTRAPOLATION if bone in sl.LIMB_CAPSULE_BONES else 0.0
    rh, rt = linear_radii(station_t, station_r, extend)
    ch, ct = linear_offsets(station_t, station_c, extend)
    length = model.bones[bone].length
    fitted = np.array([rh, rt, *ch, *ct], float)
    if not np.all(np.isfinite(fitted)) or max(rh, rt) > CAPSULE_MAX * length or np.abs(fitted[2:]).max() > length:
        # A few rays grazing a stylised or low-poly part can fit a line that runs off (a base
        # mesh's fingertip came out 96 m thick): the bone's proportions stand in.
        _estimate_capsule(survey, bone, f"its rings fit a radius of {max(rh, rt):.3g} m on a {length:.3g} m bone")
        return None
    model.bones[bone].radius_head, model.bones[bone].radius_tail = rh, rt
    element = SurfaceElement(f"capsule:{bone}", "capsule", bone)
    element.set_axis_offsets((ch[0], 0.0, ch[1]), (ct[0], 0.0, ct[1]))  # bone frame: x, (y along), z
    model.surface.append(element)
    survey.quality[f"capsule:{bone}"] = {"rays": rays, "hit": n_hit, "rejected": n_rej,
                                         "spread_mm": round(float(np.concatenate(spreads).std() * 1000), 3)}
    return None


# --- what the rays could not measure: the shared avatars' proportions (avatar/template.py) ------------

def _note_estimated(survey: _Survey, element: str, why: str) -> None:
    survey.model.calibration["defaulted"][element] = f"estimated from the body's proportions ({why})"
    survey.quality[element] = {"estimated": True}


def _estimate_capsule(survey: _Survey, bone: str, why: str) -> None:
    """`capsule:<bone>` from the template's radii and axis offsets over the bone's length."""
    info = survey.model.bones[bone]
    v = np.asarray(TEMPLATE[f"capsule:{bone}"], float) * info.length
    info.radius_head, info.radius_tail = float(v[0]), float(v[1])
    element = SurfaceElement(f"capsule:{bone}", "capsule", bone)
    element.set_axis_offsets(v[2:5], v[5:8])
    survey.model.surface.append(element)
    _note_estimated(survey, f"capsule:{bone}", why)


def _estimate_head(survey: _Survey, why: str) -> None:
    """The skull sphere and the jaw from the template, scaled by the head size the trunk implies
    (the template's head over trunk: a rig's head bone may end anywhere from the skull's middle
    to its top)."""
    J = survey.J
    size = TEMPLATE["scale:head"][0] * float(np.linalg.norm(J["skull_base"] - J["pelvis"]))
    v = np.asarray(TEMPLATE["sphere:skull"], float) * size
    survey.model.surface.append(SurfaceElement("sphere:skull", "sphere", "head", center=v[:3], radius=float(v[3])))
    survey.model.surface.append(SurfaceElement(
        "mesh:jaw", "mesh", "head", triangles=list(sl.JAW_TRIANGLES),
        points={p: SurfacePoint("head", np.asarray(TEMPLATE[f"mesh:jaw/{p}"], float) * size) for p in sl.JAW_POINTS}))
    for element in ("sphere:skull", "mesh:jaw"):
        _note_estimated(survey, element, why)


def _estimate_sole(survey: _Survey, s: str, why: str) -> None:
    """`mesh:sole_<s>` from the template, scaled by the foot (ankle to toe joint) as a bare
    skeleton's (avatar/estimate.py); no skin contact points."""
    names = sl.sole_points(6, s)
    size = float(np.linalg.norm(survey.J[f"toe_{s}"] - survey.J[f"ankle_{s}"]))  # as estimate.scales sizes it
    survey.model.surface[:] = [e for e in survey.model.surface if e.id != f"mesh:sole_{s}"]
    survey.model.surface.append(SurfaceElement(
        f"mesh:sole_{s}", "mesh", f"foot_{s}", triangles=sl.fan_triangles(names),
        points={p: SurfacePoint(f"foot_{s}", np.asarray(TEMPLATE[f"mesh:sole_{s}/{p}"], float) * size) for p in names}))
    _note_estimated(survey, f"mesh:sole_{s}", why)


def _head_centre(survey: _Survey) -> tuple[np.ndarray, float]:
    """Head size pass: casts down onto the top of the head; returns the head centre c and the head
    height above the skull base (the table's "head top" and "head centre c"). Adds no element."""
    J, U = survey.J, survey.U
    sb = J["skull_base"]
    spine_len = float(np.linalg.norm(sb - J["pelvis"]))
    top, _ = survey.hit("head top", survey.rig.bone_map.bones["head"], sb + U * spine_len, -U)
    head_h = float(np.dot(top - sb, U))
    if head_h <= 0:
        raise BodyCalError("the top of the head is below the skull base", source=survey.rig.armature)
    return sb + U * head_h / 2, head_h


def _measure_skull(survey: _Survey, c: np.ndarray, head_h: float) -> None:
    """Skull pass: casts `SKULL_RAYS` from the head centre `c`, fits a sphere, appends
    `sphere:skull` (in the head bone's frame) and its quality. Raises below 8 hits."""
    rig, F, L, U = survey.rig, survey.F, survey.L, survey.U
    pts = []
    for az, el in SKULL_RAYS:
        r = survey.caster.cast(c, _dir(F, L, U, az, el), max_dist=head_h)
        if r is not None:
            pts.append(r[0])
    if len(pts) < 8:
        raise BodyCalError(f"sphere:skull: only {len(pts)} of {len(SKULL_RAYS)} rays from the head centre "
                           f"(bone {rig.bone_map.bones['head']}) hit the mesh", source=rig.armature)
    pts = np.array(pts)
    centre, radius, keep = sphere_fit(pts)
    if not (np.all(np.isfinite(centre)) and radius <= head_h and np.linalg.norm(centre - c) <= head_h):
        # hits on a nearly flat back of the head (a stylised, low-poly one) fit any sphere
        raise BodyCalError(f"sphere:skull: the rays' hits fit a sphere of {radius:.3g} m, not a skull",
                           source=rig.armature)
    survey.model.surface.append(SurfaceElement("sphere:skull", "sphere", "head", center=survey.local("head", centre),
                                               radius=radius))
    res = np.linalg.norm(pts[keep] - centre, axis=1) - radius
    survey.quality["sphere:skull"] = {"rays": len(SKULL_RAYS), "hit": len(pts), "rejected": int((~keep).sum()),
                                      "spread_mm": round(float(res.std() * 1000), 3)}


def _measure_jaw(survey: _Survey, c: np.ndarray, head_h: float) -> None:
    """Jaw pass: casts `JAW_RAYS` from outside the head towards its centre `c`; appends `mesh:jaw`
    (points in the head bone's frame) and its quality."""
    F, L, U = survey.F, survey.L, survey.U
    jaw = {}
    for p, (az, el) in JAW_RAYS.items():
        # From outside towards the head centre: the first hit is the skin, never the mouth's
        # inside or teeth that a ray from the centre would meet first.
        d = _dir(F, L, U, az, el)
        jaw[p] = survey.hit(f"mesh:jaw {p}", survey.rig.bone_map.bones["head"], c + d * 2 * head_h, -d)[0]
    survey.model.surface.append(SurfaceElement(
        "mesh:jaw", "mesh", "head", points={p: SurfacePoint("head", survey.local("head", w)) for p, w in jaw.items()},
        triangles=list(sl.JAW_TRIANGLES)))
    survey.quality["mesh:jaw"] = {"rays": len(jaw), "hit": len(jaw), "rejected": 0, "spread_mm": 0.0}


def _measure_torso(survey: _Survey) -> None:
    """Torso pass: casts `TORSO_RAYS` from the spine curve, then the belly centre points towards
    their bilinear default; appends `mesh:torso` (each point in its nearest vertebra's frame) and
    its quality."""
    J, F, L, U = survey.J, survey.F, survey.L, survey.U
    spine = np.array([J["pelvis"], J["spine_root"]] + [J[sk.spine_joint(k)] for k in range(1, sk.SPINE_COUNT + 1)])
    spine_joints = spine[1:]
    heights = (spine - J["pelvis"]) @ U
    order = np.maximum.accumulate(heights)  # a spine that dips never makes interp non-monotonic
    shoulder_h = float(np.mean([(J[f"shoulder_{s}"] - J["pelvis"]) @ U for s in sk.SIDES]))

    def spine_at(h):
        return np.array([np.interp(h, order, spine[:, i]) for i in range(3)])

    torso = {}
    for p, (frac, az) in TORSO_RAYS.items():
        o = spine_at(frac * shoulder_h)
        torso[p] = survey.hit(f"mesh:torso {p}", sl.nearest_vertebra(o, spine_joints), o, _dir(F, L, U, az))[0]
    for p, guess in sl.belly_centre_points(torso["belly_ul"], torso["belly_ur"], torso["belly_ll"],
                                           torso["belly_lr"]).items():
        o = spine_at(float((guess - J["pelvis"]) @ U))
        d = guess - o
        d = d - np.dot(d, U) * U
        torso[p] = survey.hit(f"mesh:torso {p}", sl.nearest_vertebra(o, spine_joints), o, d)[0]
    points = {}
    for p in sl.TORSO_POINTS:
        v = sl.nearest_vertebra(torso[p], spine_joints)
        points[p] = SurfacePoint(v, survey.local(v, torso[p]))
    survey.model.surface.append(SurfaceElement("mesh:torso", "mesh", "spine_*", points=points,
                                               triangles=list(sl.TORSO_TRIANGLES)))
    survey.quality["mesh:torso"] = {"rays": len(torso), "hit": len(torso), "rejected": 0, "spread_mm": 0.0}


def _measure_palm(survey: _Survey, s: str) -> None:
    """Palm pass for side `s`: casts `PALM_RAYS` out of the palm; appends `mesh:palm_<s>` (in the
    hand bone's frame) and its quality, or, without the finger bones, a line in
    `calibration["missing"]`."""
    J, model = survey.J, survey.model
    hand = f"hand_{s}"
    if not (hand in model.bones and f"mcp_index_{s}" in J and f"mcp_pinky_{s}" in J):
        model.calibration["missing"].append(f"mesh:palm_{s} (no finger bones to place it)")
        return
    w = J[f"wrist_{s}"]
    ends = {"I": J[f"mcp_index_{s}"], "P": J[f"mcp_pinky_{s}"]}
    hand_dir = J[f"mcp_middle_{s}"] - w
    n = np.cross(survey.rig.hinges.get(f"middle_2_{s}", survey.frames[hand][:, 0]), hand_dir)
    n /= np.linalg.norm(n)
    names = sl.palm_points(len(PALM_RAYS), s)
    hits = [survey.hit(f"mesh:palm_{s} {p}", survey.rig.bone_map.bones[hand], w + f * (ends[k] - w), n)[0]
            for p, (k, f) in zip(names, PALM_RAYS)]
    hits = _wind(hits, n)
    model.surface.append(SurfaceElement(
        f"mesh:palm_{s}", "mesh", hand,
        points={p: SurfacePoint(hand, survey.local(hand, x)) for p, x in zip(names, hits)},
        triangles=sl.fan_triangles(names)))
    survey.quality[f"mesh:palm_{s}"] = {"rays": len(names), "hit": len(names), "rejected": 0, "spread_mm": 0.0}


def _measure_sole(survey: _Survey, s: str) -> None:
    """Sole pass for side `s`: finds the floor under the ankle and the toe, casts the six outline
    rays at `SOLE_HEIGHT` and puts the hits on the floor plane; appends `mesh:sole_<s>` (in the
    foot bone's frame) and its quality."""
    J, L, U = survey.J, survey.L, survey.U
    foot = f"foot_{s}"
    a, toe = J[f"ankle_{s}"], J[f"toe_{s}"]
    leg = float(np.linalg.norm(J[f"hip_{s}"] - a)) + 0.1
    floor_hits = [survey.hit(f"mesh:sole_{s} floor", survey.rig.bone_map.bones[foot], p - U * leg, U)[0]
                  for p in (a, toe)]
    floor = min(float(x @ U) for x in floor_hits)
    f = toe - a
    f = f - np.dot(f, U) * U
    f /= np.linalg.norm(f)
    lat = L - np.dot(L, f) * f
    lat /= np.linalg.norm(lat)
    low = floor + SOLE_HEIGHT * (float(a @ U) - floor)

    def at_low(p):
        return p + U * (low - float(p @ U))

    heel_st = at_low(a + 0.15 * (toe - a))
    rays = [(at_low(a), -f), (heel_st, lat), (at_low(toe), lat), (at_low(toe), f), (at_low(toe), -lat),
            (heel_st, -lat)]
    names = sl.sole_points(len(rays), s)
    outline = [survey.hit(f"mesh:sole_{s} {p}", survey.rig.bone_map.bones[foot], o, d)[0]
               for p, (o, d) in zip(names, rays)]
    outline = [x + U * (floor - float(x @ U)) for x in outline]  # on the floor plane
    outline = _wind(outline, -U)
    element = SurfaceElement(
        f"mesh:sole_{s}", "mesh", foot,
        points={p: SurfacePoint(foot, survey.local(foot, x)) for p, x in zip(names, outline)},
        triangles=sl.fan_triangles(names))
    # The skin's contact points (foot_contact.py): a grid of rays from under the floor, and rays at
    # the heel's back.
    grid = []
    for o in foot_contact.grid_origins(a, toe, floor, f, lat, U):
        r = survey.caster.cast(o, U, float(a @ U) - floor + foot_contact.BELOW)
        grid.append(r[0] if r is not None else np.full(3, np.nan))
    origins, reach = foot_contact.back_origins(a, toe, floor, f, lat, U)  # the heel's back, cast forward
    back = []
    for o in origins:
        r = survey.caster.cast(o, f, reach)
        back.append(r[0] if r is not None else np.full(3, np.nan))
    contact = foot_contact.contact_points(np.array(grid), a, toe, floor, f, lat, U, back=np.array(back))
    if contact is not None:
        element.extra["contact"] = {
            "heel": _list3(survey.local(foot, contact["heel"])), "ball": _list3(survey.local(foot, contact["ball"])),
            "support": [_list3(survey.local(foot, x)) for x in contact["support"]]}
    survey.model.surface.append(element)
    hit = int(np.isfinite(np.array(grid + back)).all(axis=1).sum())
    survey.quality[f"mesh:sole_{s}"] = {"rays": len(rays) + 2 + len(grid) + len(back), "hit": len(rays) + 2 + hit,
                                        "rejected": 0,
                                        "spread_mm": round(float(np.ptp([x @ U for x in floor_hits]) * 1000), 3),
                                        "contact_points": 0 if contact is None else len(contact["support"])}


def _list3(x) -> list[float]:
    return [round(float(v), 7) for v in x]


_ORDER = {eid: i for i, eid in enumerate(sl.element_ids())}


def _wind(points: list[np.ndarray], outward: np.ndarray) -> list[np.ndarray]:
    """Keep the outline's first point and reverse the rest if the fan's normal is not `outward`."""
    p = np.array(points)
    n = np.zeros(3)
    for i in range(1, len(p) - 1):
        n += np.cross(p[i] - p[0], p[i + 1] - p[0])
    if np.dot(n, outward) < 0:
        return [points[0]] + points[1:][::-1]
    return points
