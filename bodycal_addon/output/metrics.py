"""Quality metrics shared by tests and benchmarks (DESIGN.md §7), numpy only.

Every function returns metres (or radians); `stats_mm` turns an array of metres into the figures
benchmarks print (median, 95th percentile, max, in millimetres). NaN marks "not measured" (e.g. a
frame where the foot is not planted) and is ignored by `stats_mm`.

The contact gap here is measured against the analytic surface elements of a posed body model
(`retarget.egocentric.PosedSurface`: capsules, spheres, crude-mesh triangles); the gap against
the avatar's evaluated Blender mesh lives with the Blender code.

The benches' targets are here too (the limits below): the review of a bake (output/review.py,
DESIGN.md §7 "Review") flags a figure past the same limit a benchmark holds it to, computed by
the same function.
"""

from __future__ import annotations

import numpy as np

from ..body import skeleton as sk
from ..body.rest_frames import complete_joints
from ..core.errors import BodyCalError
from ..retarget.avatar_pose import AvatarRig
from ..retarget.egocentric import own_chain_elements, pose_surface, project
from ..retarget.rig import RigPose
from ..retarget.solver_methods import surface_bones, surface_correction

# The benches' targets, which the review's flags use as their limits (one place for both).
CONTACT_GAP_P95_MM = 10.0  # bench_retarget_quality: p95 of |contact gap| in the contact frames
FOOT_SKIN_LOWEST_MM = -10.0  # bench_real_motion: the lowest foot skin on the evaluated mesh
SLIDE_P95_MM = 2.0  # bench_real_motion: p95 of a planted foot's slide, mm per 90 Hz frame
SLIDE_RATIO = 1.5  # bench_real_motion: heel / ball slide p95 over the source's, scaled like the legs
ACCEL_RATIO = 1.3  # bench_real_motion: wrist / ankle acceleration p95 over the source's, scaled


def stats_mm(values) -> dict:
    """{"median", "p95", "max", "mean", "count"} of |values| in mm, NaN ignored (None if empty)."""
    v = np.abs(np.asarray(values, float)).ravel()
    v = v[np.isfinite(v)] * 1000.0
    if v.size == 0:
        return {"median": None, "p95": None, "max": None, "mean": None, "count": 0}
    return {"median": round(float(np.median(v)), 3), "p95": round(float(np.percentile(v, 95)), 3),
            "max": round(float(v.max()), 3), "mean": round(float(v.mean()), 3), "count": int(v.size)}


def joint_centre_error(estimated: dict, truth: dict) -> dict[str, float]:
    """Distance (m) between estimated and true joint centres, per joint present in both (arrays of
    any matching shape (..., 3); frames are averaged)."""
    out = {}
    for name, p in estimated.items():
        if name in truth:
            d = np.linalg.norm(np.asarray(p, float) - np.asarray(truth[name], float), axis=-1)
            out[name] = float(np.mean(d))
    return out


def signed_distances(points, surface, mesh_depth: float = 0.15) -> np.ndarray:
    """Signed distance (m, negative inside) of (F, P, 3) points to every element of a PosedSurface:
    (F, P, E). Capsules: distance to the axis segment minus the radius interpolated at the closest
    axis point; spheres: to the centre minus the radius; meshes: distance to the closest triangle,
    negative only behind its outward face, inside its outline (the closest point is not on an
    edge) and less than `mesh_depth` deep: a crude mesh is an open surface, so a point far behind
    it (above a sole, beside the torso) is not inside the body."""
    p = np.asarray(points, float)
    proj = project(p, surface, penetration_tolerance=0.0)
    C, S, M = surface.counts
    pe = p[:, :, None, :]
    a = surface.caps_head[:, None]
    ab = surface.caps_tail[:, None] - a
    t = proj.cap_t
    r = surface.caps_radius[:, 0] + t * (surface.caps_radius[:, 1] - surface.caps_radius[:, 0])
    caps = np.linalg.norm(pe - (a + t[..., None] * ab), axis=-1) - r
    sph = np.linalg.norm(pe - surface.sph_center[:, None], axis=-1) - surface.sph_radius
    if M:
        fi = np.arange(p.shape[0])[:, None, None]
        normal = surface.tri_normal[fi, proj.tri_index]
        v = proj.v[:, :, C + S:]
        interior = np.all(proj.tri_bary > 1e-9, axis=-1)
        dist = proj.dist[:, :, C + S:]
        behind = (np.einsum("...i,...i->...", v, normal) < 0) & interior & (dist < mesh_depth)
        mesh = np.where(behind, -dist, dist)
    else:
        mesh = np.zeros(p.shape[:2] + (0,))
    return np.concatenate([caps, sph, mesh], axis=2)


def contact_gap(points, surface, target_names: list[str] | None = None, exclude_ids=()) -> np.ndarray:
    """Gap (m) between each target and the posed body surface: the smallest signed distance over
    the elements (negative: inside). With `target_names`, each target's own-chain elements are left
    out (egocentric.own_chain_elements: a wrist is always "touching" its own forearm); `exclude_ids`
    leaves more out for every target. Returns (F, P)."""
    return nearest_contact(points, surface, target_names, exclude_ids)[0]


def nearest_contact(points, surface, target_names: list[str] | None = None, exclude_ids=()
                    ) -> tuple[np.ndarray, np.ndarray]:
    """`contact_gap` (F, P) and the element each target is nearest to: its index in
    `surface.element_ids` (F, P), -1 where none is left."""
    d = signed_distances(points, surface)
    ids = surface.element_ids
    mask = np.zeros(d.shape[1:], bool)
    for e, eid in enumerate(ids):
        if eid in exclude_ids:
            mask[:, e] = True
    if target_names is not None:
        for p, name in enumerate(target_names):
            own = own_chain_elements(name)
            mask[p] |= np.array([eid in own for eid in ids], bool)
    d = np.where(mask, np.inf, d)
    if not d.shape[-1]:
        return np.full(d.shape[:2], np.nan), np.full(d.shape[:2], -1)
    nearest = d.argmin(axis=-1)
    out = np.take_along_axis(d, nearest[..., None], axis=-1)[..., 0]
    found = np.isfinite(out)
    return np.where(found, out, np.nan), np.where(found, nearest, -1)


def floor_error(foot_points, planted) -> np.ndarray:
    """Height (m) of the lowest foot point above the floor (z = 0) in the frames where the foot is
    planted, NaN elsewhere. foot_points: (F, K, 3) points of one foot (sole corners, ankle, toe);
    planted: (F,) bool."""
    low = np.asarray(foot_points, float)[..., 2].min(axis=-1)
    return np.where(np.asarray(planted, bool), low, np.nan)


def foot_sliding(point, planted) -> np.ndarray:
    """Horizontal displacement (m) of a foot point between consecutive frames that are both
    planted, NaN elsewhere; (F - 1,). Its mean is the sliding in m per planted frame."""
    p = np.asarray(point, float)
    pl = np.asarray(planted, bool)
    step = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=-1)
    return np.where(pl[1:] & pl[:-1], step, np.nan)


ON_FLOOR = 0.003  # m: a skin point within this of its own lowest height stands on the floor (`floor_travel_mm`)


def floor_travel_mm(point) -> float:
    """The longest horizontal path (mm) a skin point (F, 3) travels over the floor in one stay on
    it: consecutive frames within ON_FLOOR of its own lowest height, whatever any stance detection
    says (a foot held on the floor while it moves skates; a planted one travels ~0)."""
    p = np.asarray(point, float)
    if len(p) < 2 or not np.isfinite(p).all():
        return 0.0
    on = p[:, 2] <= p[:, 2].min() + ON_FLOOR
    both = on[1:] & on[:-1]
    if not both.any():
        return 0.0
    step = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=-1)
    stay = np.cumsum(np.r_[True, both[1:] != both[:-1]])  # a label per run of `both`
    return round(float(np.bincount(stay[both], step[both]).max()) * 1000.0, 1)


def planted_frames(point, speed_threshold: float = 0.05, height_threshold: float = 0.12,
                   dt: float = 1 / 90) -> np.ndarray:
    """Frames where a foot point (F, 3) is planted: low (z below `height_threshold`) and slow
    (horizontal speed below `speed_threshold` m/s). (F,) bool."""
    p = np.asarray(point, float)
    v = np.zeros(len(p))
    if len(p) > 1:
        sp = np.linalg.norm(np.diff(p[:, :2], axis=0), axis=-1) / dt
        v[1:] = sp
        v[0] = sp[0]
    return (p[:, 2] < height_threshold) & (v < speed_threshold)


def acceleration(point, fps: float) -> np.ndarray:
    """(F,) magnitude (m/s^2) of a point's acceleration (F, 3), the central second difference;
    NaN at the first and last frame."""
    p = np.asarray(point, float)
    out = np.full(len(p), np.nan)
    if len(p) > 2:
        out[1:-1] = np.linalg.norm(p[2:] - 2 * p[1:-1] + p[:-2], axis=-1) * fps * fps
    return out


def acceleration_p95(point, fps: float) -> float:
    """The 95th percentile of `acceleration` over the frames that have one (NaN: fewer than 3)."""
    a = acceleration(point, fps)
    return float(np.nanpercentile(a, 95)) if np.isfinite(a).any() else float("nan")


def ground_contact(point, fps: float, speed: float = 0.15, height: float = 0.03) -> np.ndarray:
    """(F,) bool: a source's point (a heel's ankle, a ball's toe joint) on the ground: slower than
    `speed` (m/s, horizontal, central difference) and within `height` of its lowest 5 % over the take."""
    p = np.asarray(point, float)
    if len(p) < 2:
        return np.zeros(len(p), bool)
    v = np.gradient(p, axis=0) * fps
    slow = np.linalg.norm(v[:, :2], axis=-1) < speed
    low = p[:, 2] < np.percentile(p[:, 2], 5) + height
    return slow & low


def slide_steps_mm(point, on, fps: float) -> np.ndarray:
    """(F - 1,) a point's horizontal step between consecutive frames both `on`, in mm per 90 Hz
    frame (so takes at any rate compare), NaN elsewhere: `foot_sliding` at 90 Hz."""
    return foot_sliding(point, on) * 1000.0 * fps / 90.0


def slide_p95_mm(point, on, fps: float) -> float | None:
    """p95 of `slide_steps_mm` (mm per 90 Hz frame, two decimals); None when no two consecutive
    frames are `on`."""
    steps = slide_steps_mm(point, on, fps)
    steps = steps[np.isfinite(steps)]
    return None if steps.size == 0 else round(float(np.percentile(steps, 95)), 2)


def limb_ratios(rig: AvatarRig, source_joints: dict) -> dict[str, float]:
    """How much longer the avatar's limbs are than the source's (a rotation copy moves a longer
    limb's end proportionally faster): "ankle", the avatar's leg (`AvatarRig.leg_length`) over
    the source's hip to knee to ankle plus its ankle height; "wrist", shoulder to elbow to wrist.
    `source_joints`: canonical joint -> (3,) world, the source standing."""
    a = rig.joint_world

    def chain(get, names):
        return float(np.mean([sum(np.linalg.norm(np.subtract(get(f"{y}_{s}"), get(f"{x}_{s}")))
                                  for x, y in zip(names, names[1:])) for s in sk.SIDES]))

    p = source_joints
    leg = chain(lambda n: p[n], ("hip", "knee", "ankle")) + float(np.mean([p[f"ankle_{s}"][2] for s in sk.SIDES]))
    arm = chain(lambda n: p[n], ("shoulder", "elbow", "wrist"))
    arm_avatar = chain(lambda n: a[sk.JOINT_INDEX[n]], ("shoulder", "elbow", "wrist"))
    return {"ankle": rig.leg_length() / max(leg, 1e-9), "wrist": arm_avatar / max(arm, 1e-9)}


def motion_scale(method: str, limb: dict[str, float], eye_ratio: float) -> dict[str, float]:
    """How the method scales the source's wrist and ankle motion: AvatarGo (`offsets`) every
    position by the one eye-height ratio (its eq. 2), the others by the limb ratios."""
    return {"ankle": eye_ratio, "wrist": eye_ratio} if method == "offsets" else dict(limb)


def reach_error(effector, target) -> np.ndarray:
    """Distance (m) between the avatar's effectors after IK and their retargeted targets."""
    return np.linalg.norm(np.asarray(effector, float) - np.asarray(target, float), axis=-1)


def effector_points(avatar, rig: AvatarRig, pose, effector: str, joints: dict | None = None):
    """(F, 3) world points of the avatar's effector in `pose` (`rig.fk`'s) and its skin offset (m):
    "palm_<s>" is the centre of the avatar's palm surface (on the skin, offset 0); a joint (wrist,
    fingertip) lies inside its limb, offset = that limb's radius at the joint. `joints` (name ->
    (F, 3)) gives the joints where the caller has them (a baked animation's `joints_world`), else
    the pose's."""
    if effector.startswith("palm_"):
        side = effector[-1]
        el = avatar.element(f"mesh:palm_{side}")
        # Palm points are local to the model's own hand frame (its `right`): correct the engine's.
        corr = surface_correction(avatar, rig.frames0, complete_joints(avatar))[sk.BONE_INDEX[f"hand_{side}"]]
        frame = pose.frames[:, sk.BONE_INDEX[f"hand_{side}"]] @ corr
        wrist = pose.joints[:, sk.JOINT_INDEX[f"wrist_{side}"]]
        local = np.mean([p.local for p in el.points.values()], axis=0)
        return wrist + frame @ local, 0.0
    if effector not in (joints if joints is not None else sk.JOINT_INDEX):
        raise BodyCalError(f"unknown effector '{effector}'", field="effector")
    radius = next((avatar.bones[b.name].radius_tail or 0.0 for b in sk.BONES
                   if b.tail == effector and b.name in avatar.bones and not b.shortcut), 0.0)
    point = joints[effector] if joints is not None else pose.joints[:, sk.JOINT_INDEX[effector]]
    return np.asarray(point, float), float(radius)


def foot_points(avatar, rig: AvatarRig, pose: RigPose, side: str) -> dict[str, np.ndarray]:
    """World points of the avatar's foot in `pose` (`rig.fk`'s): "outline" (F, N, 3) its sole's
    outline (`mesh:sole_<side>`: the floor-error measurement, DESIGN.md §7), "heel" and "ball"
    (F, 3) and "support" (F, K, 3) its sole's contact points (the element's `contact`, measured on
    its skin, FORMATS.md §3; the outline stands in, heel and ball its middle, on a model without)."""
    corr = surface_correction(avatar, rig.frames0, complete_joints(avatar))[sk.BONE_INDEX[f"foot_{side}"]]
    frame = pose.frames[:, sk.BONE_INDEX[f"foot_{side}"]] @ corr
    ankle = pose.joints[:, sk.JOINT_INDEX[f"ankle_{side}"]]
    el = avatar.element(f"mesh:sole_{side}")
    outline = np.stack([p.local for p in el.points.values()])
    c = el.extra.get("contact")
    if not isinstance(c, dict):
        c = {"heel": outline.mean(0), "ball": outline.mean(0), "support": outline}
    out = {"outline": ankle[:, None] + np.einsum("fij,kj->fki", frame, outline)}
    out |= {k: ankle + frame @ np.asarray(c[k], float) for k in ("heel", "ball")}
    out["support"] = ankle[:, None] + np.einsum("fij,kj->fki", frame, np.asarray(c["support"], float))
    return out


def model_contact_gaps(avatar, rotations, root_location, contacts: list[dict], joints: dict | None = None
                       ) -> list[np.ndarray]:
    """Signed gap (m) per contact of a ground truth (`{"effector", "target", "frames" (F,) bool}`) on
    the avatar's calibrated surface model (capsules, skull sphere, crude meshes) posed by the pose-bone
    `rotations` and `root_location`, in the contact's frames: separates the retargeting's accuracy from
    how well the calibrated model fits the skin (the evaluated mesh's gap is Blender's,
    blender/mesh_metrics.contact_gaps). Contacts on an element the model lacks are left out."""
    rig = AvatarRig.from_model(avatar)
    pose = rig.fk(rotations, root_location)
    out = []
    for c in contacts:
        idx = np.flatnonzero(np.asarray(c["frames"], bool))
        eid = c["target"].split("/", 1)[0]
        if len(idx) == 0 or eid not in {e.id for e in avatar.surface}:
            continue
        out.append(posed_contact_gaps(avatar, rig, pose, c["effector"], eid, idx, joints)[0])
    return out


def posed_contact_gaps(avatar, rig: AvatarRig, pose: RigPose, effector: str, target: str, frames,
                       joints: dict | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """`model_contact_gaps` of one contact at `frames` (indices into `pose`'s frames): the gaps
    (n,) (m), the effector's points there (n, 3) and its skin offset."""
    idx = np.asarray(frames, int)
    eid = target.split("/", 1)[0]
    model = surface_bones(avatar)
    corr = surface_correction(avatar, rig.frames0, complete_joints(avatar))
    posed_joints = {j: pose.joints[idx, i] for i, j in enumerate(sk.JOINTS)}
    frames_at = {b.name: pose.frames[idx, i] @ corr[i] for i, b in enumerate(sk.BONES)}
    pts, off = effector_points(avatar, rig, pose, effector, joints)
    pts = np.asarray(pts, float)[idx]
    surf = pose_surface(model, posed_joints, frames_at, [eid])
    return signed_distances(pts[:, None], surf)[:, 0, 0] - off, pts, off
