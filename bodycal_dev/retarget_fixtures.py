"""Avatar body models built in numpy, for tests and benchmarks that run without the Blender avatar
calibration: (a) the user's own body as an avatar, (b) the same uniformly scaled (and placed by any
rigid + uniform-scale `matrix_world`), (c) the procedural avatar of `sample_rigs/procedural.py`
with rest matrices computed the way Blender's `EditBone.align_roll` does (+Y along the bone, +Z
toward the spec's `z_axis`). The models follow the avatar calibration's contract: canonical
joints (world rest + frame = avatar bone + local), canonical bones, surface elements, and
`extra["rig"]`.
"""

from __future__ import annotations

import copy

import numpy as np

from bodycal_addon.body import naming
from bodycal_addon.body import skeleton as sk
from bodycal_addon.body import surface_layout as sl
from bodycal_addon.body.bodymodel import BodyModel, BoneInfo, Joint, SurfaceElement, SurfacePoint
from bodycal_addon.body.rest_frames import complete_joints, model_rest_frames
from bodycal_addon.body.skeleton import BONE_INDEX as BI
from bodycal_addon.body.skeleton import BONES, JOINTS, SPINE_JOINTS
from bodycal_addon.body.skeleton import HINGE_BONES as HINGES
from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.core.transforms import normalize
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import user_animation as ua
from bodycal_dev import synthetic


def _rig_dict(name, bones, matrix_world, bone_map, rest_pose="T"):
    return {"armature": name, "matrix_world": np.asarray(matrix_world, float).tolist(), "scheme": bone_map.scheme,
            "bone_map": bone_map.to_dict(), "bones": bones, "rest_pose": rest_pose}


def _inv_world(matrix_world, p):
    w = np.asarray(matrix_world, float)
    return np.linalg.solve(w[:3, :3], (np.asarray(p, float) - w[:3, 3]).T).T


def avatar_from_user(user: BodyModel, scale: float = 1.0, matrix_world=None, name: str = "user_avatar") -> BodyModel:
    """The user's body at the reference time as an avatar (uniformly scaled by `scale` about the
    world origin). Rig bones are the canonical bones themselves (12 vertebrae as the spine chain);
    `matrix_world` (rigid + uniform scale) places the armature: joints stay where they are in the
    world, the armature-space data move."""
    w = np.eye(4) if matrix_world is None else np.asarray(matrix_world, float)
    wr = w[:3, :3] / np.linalg.norm(w[:3, :3], axis=0).mean()
    pos = {j: scale * p for j, p in complete_joints(user).items()}
    frames0 = model_rest_frames(user, {j: pos[j] / scale for j in JOINTS})
    rig_bones = {}
    segs = {}
    for b in BONES:
        if b.shortcut:
            continue
        parent = b.parent if b.parent is None or not sk.BONE_BY_NAME[b.parent].shortcut else "sacrum"
        seg = "pelvis" if b.name == "sacrum" else (None if b.name in avatar_spine() else b.name)
        rig_bones[b.name] = {"parent": parent, "head": _inv_world(w, pos[b.head]).tolist(),
                             "tail": _inv_world(w, pos[b.tail]).tolist(),
                             "matrix": (wr.T @ frames0[BI[b.name]]).tolist(), "segment": seg or "spine"}
        if seg:
            segs[seg] = b.name
    bm = naming.BoneMap("canonical", segs, {"spine": avatar_spine(), "neck": []}, [])
    joints = {}
    for j in JOINTS:
        bone = next((b.name for b in BONES if b.head == j and b.name in rig_bones), None)
        bone = bone or next((b.name for b in BONES if b.tail == j and b.name in rig_bones), "sacrum")
        arm = _inv_world(w, pos[j])
        local = np.asarray(rig_bones[bone]["matrix"]).T @ (arm - np.asarray(rig_bones[bone]["head"]))
        joints[j] = Joint(pos[j], bone, local)
    bones = {}
    for b in BONES:
        ub = user.bones.get(b.name)
        # Keep the user's own rights: the copied surface points are local to frames built with them.
        right = ub.right if ub is not None and ub.right is not None else frames0[BI[b.name]][:, 0]
        bones[b.name] = BoneInfo(b.head, b.tail, float(np.linalg.norm(pos[b.tail] - pos[b.head])), right,
                                 None if ub is None or ub.radius_head is None else ub.radius_head * scale,
                                 None if ub is None or ub.radius_tail is None else ub.radius_tail * scale)
    surface = []
    for e in user.surface:
        e2 = copy.deepcopy(e)
        if e2.center is not None:
            e2.center = e2.center * scale
        if e2.radius is not None:
            e2.radius = e2.radius * scale
        for p in e2.points.values():
            p.local = p.local * scale
        surface.append(e2)
    return BodyModel("avatar", name, joints, bones, surface, None, {}, extra={
        "rig": _rig_dict(name, rig_bones, w, bm)})


def avatar_spine() -> list[str]:
    return [f"spine_{k:02d}" for k in range(1, sk.SPINE_COUNT + 1)]


def align_roll_matrix(head, tail, z_axis) -> np.ndarray:
    """Blender's rest matrix after `EditBone.align_roll(z_axis)`: +Y along the bone, +Z as close
    to z_axis as possible."""
    y = normalize(np.asarray(tail, float) - head)
    z = normalize(z_axis - np.dot(z_axis, y) * y)
    return np.stack([np.cross(y, z), y, z], axis=1)


_PROC_SEG_JOINTS = {  # canonical joint -> (procedural bone, "head" | "tail")
    "pelvis": ("pelvis", "head"), "spine_root": ("spine_01", "head"), "skull_base": ("head", "head"),
    "head": ("head", "tail"),
}


def procedural_avatar(spec=None, matrix_world=None, name: str | None = None, **spec_kwargs) -> BodyModel:
    """Avatar body model of `sample_rigs.procedural.build_spec(**spec_kwargs)` (or `spec`), as the
    avatar calibration would measure it on the exact surface."""
    from sample_rigs import procedural

    spec = spec or procedural.build_spec(**spec_kwargs)
    name = name or spec.name
    w = np.eye(4) if matrix_world is None else np.asarray(matrix_world, float)
    wl = w[:3, :3]
    ws = np.linalg.norm(wl, axis=0).mean()

    def to_world(p):
        return wl @ np.asarray(p, float) + w[:3, 3]

    rig_bones = {}
    for bn, b in spec.bones.items():
        rig_bones[bn] = {"parent": b.parent or "", "head": b.head.tolist(), "tail": b.tail.tolist(),
                         "matrix": align_roll_matrix(b.head, b.tail, b.z_axis).tolist()}
    bm = naming.detect_bone_map(list(spec.bones))
    for seg, bn in bm.bones.items():
        rig_bones[bn]["segment"] = seg
    for c, lst in bm.chains.items():
        for bn in lst:
            rig_bones[bn]["segment"] = c
    sb = spec.bones
    pos_arm: dict[str, tuple[np.ndarray, str]] = {}
    for j, (bn, end) in _PROC_SEG_JOINTS.items():
        pos_arm[j] = (getattr(sb[bn], end), bn)
    chain = [*bm.chains["spine"], *bm.chains["neck"]]
    curve = np.stack([sb[c].head for c in chain] + [sb["head"].head])
    res = sk.resample_polyline(curve, sk.SPINE_COUNT)
    seg_len = np.linalg.norm(np.diff(curve, axis=0), axis=1)
    cum = np.concatenate([[0], np.cumsum(seg_len)])
    for k in range(1, sk.SPINE_COUNT):
        arc = cum[-1] * k / sk.SPINE_COUNT
        ci = int(np.clip(np.searchsorted(cum, arc, side="right") - 1, 0, len(chain) - 1))
        pos_arm[SPINE_JOINTS[k]] = (res[k], chain[ci])
    pos_arm["spine_12"] = (sb["head"].head, "head")
    for s in sk.SIDES:
        pos_arm[f"clavicle_{s}"] = (pos_arm["spine_05"][0], pos_arm["spine_05"][1])
        for j, bn, end in (("shoulder", "upperarm", "head"), ("elbow", "lowerarm", "head"),
                           ("wrist", "hand", "head"), ("hip", "thigh", "head"), ("knee", "calf", "head"),
                           ("ankle", "foot", "head"), ("toe", "ball", "head")):
            pos_arm[f"{j}_{s}"] = (getattr(sb[f"{bn}_{s}"], end), f"{bn}_{s}")
        for f in sk.FINGERS:
            for j, bn, end in (("mcp", 1, "head"), ("pip", 2, "head"), ("dip", 3, "head"), ("tip", 3, "tail")):
                pos_arm[f"{j}_{f}_{s}"] = (getattr(sb[f"{f}_{bn:02d}_{s}"], end), f"{f}_{bn:02d}_{s}")
    joints = {}
    for j, (p, bn) in pos_arm.items():
        m = np.asarray(rig_bones[bn]["matrix"])
        joints[j] = Joint(to_world(p), bn, m.T @ (p - sb[bn].head))
    pos = {j: jt.world for j, jt in joints.items()}
    canon_to_proc = {f"forearm_{s}": f"lowerarm_{s}" for s in sk.SIDES}
    canon_to_proc |= {f"shin_{s}": f"calf_{s}" for s in sk.SIDES}
    canon_to_proc |= {f"{f}_{i}_{s}": f"{f}_{i:02d}_{s}" for s in sk.SIDES for f in sk.FINGERS for i in (1, 2, 3)}
    canon_to_proc |= {f"{b}_{s}": f"{b}_{s}" for s in sk.SIDES for b in ("upperarm", "thigh")}
    bones = {}
    truth = spec.truth
    for b in BONES:
        right = None
        if b.name in HINGES:
            right = wl @ np.asarray(rig_bones[canon_to_proc[b.name]]["matrix"])[:, 0] / ws
        rh = rt = None
        pb = canon_to_proc.get(b.name)
        if pb in truth["capsules"]:
            rh = rt = truth["capsules"][pb]["radius"] * ws
        bones[b.name] = BoneInfo(b.head, b.tail, float(np.linalg.norm(pos[b.tail] - pos[b.head])) if
                                 b.head in pos and b.tail in pos else 0.0, right, rh, rt)
    model = BodyModel("avatar", name, joints, bones, [], None, {},
                      extra={"rig": _rig_dict(name, rig_bones, w, bm, "A" if spec_kwargs.get("arm_drop_deg") else "T")})
    model.surface = _procedural_surface(model, spec, to_world, ws)
    return model


def _procedural_surface(model: BodyModel, spec, to_world, ws) -> list[SurfaceElement]:
    """Surface elements measured on the procedural avatar's exact shapes (numpy raycasts against
    the torso ellipsoid, the skull sphere, the palm and sole boxes)."""
    pos = complete_joints(model)
    frames = model_rest_frames(model, pos)
    truth = spec.truth

    def local(bone, p):
        b = sk.BONE_BY_NAME[bone]
        return frames[BI[bone]].T @ (p - pos[b.head])

    out = [SurfaceElement(f"capsule:{b}", "capsule", b) for b in sl.CAPSULE_BONES]
    c_sk = to_world(truth["skull"]["center"])
    out.append(SurfaceElement("sphere:skull", "sphere", "head", local("head", c_sk), truth["skull"]["radius"] * ws))
    # Torso: rays from the spine axis at each point's height, toward a documented direction.
    tc, ta = truth["torso"]["center"], truth["torso"]["semi_axes"]
    z0, z1 = tc[2] - 0.6 * ta[2], tc[2] + 0.7 * ta[2]
    dirs = {  # (height fraction 0 = low .. 1 = high, azimuth deg from forward toward the performer's left)
        "sternum": (1.0, 0), "chest_l": (0.9, 35), "chest_r": (0.9, -35), "belly_ul": (0.55, 35),
        "belly_ur": (0.55, -35), "belly_ll": (0.05, 35), "belly_lr": (0.05, -35),
        "back_ul": (0.9, 150), "back_ur": (0.9, -150), "back_low": (0.2, 180)}
    spine = np.stack([pos[j] for j in SPINE_JOINTS])
    pts_world = {}
    for n, (h, az) in dirs.items():
        z = z0 + h * (z1 - z0)
        a = np.radians(az)
        d = np.array([np.sin(a), -np.cos(a), 0.0])  # forward = -Y, left = +X
        o = np.array([tc[0], tc[1], z])
        q, v = (o - tc) / ta, d / ta
        A, B, C = v @ v, 2 * q @ v, q @ q - 1
        t = (-B + np.sqrt(B * B - 4 * A * C)) / (2 * A)
        pts_world[n] = to_world(o + t * d)
    pts_world |= sl.belly_centre_points(pts_world["belly_ul"], pts_world["belly_ur"], pts_world["belly_ll"],
                                        pts_world["belly_lr"])
    tpoints = {}
    for n, p in pts_world.items():
        vb = sl.nearest_vertebra(p, spine)
        tpoints[n] = SurfacePoint(vb, local(vb, p))
    out.append(SurfaceElement("mesh:torso", "mesh", "spine_*", points=tpoints, triangles=list(sl.TORSO_TRIANGLES)))
    # Jaw on the skull sphere, below and in front.
    r = truth["skull"]["radius"]
    jaw = {"ear_l": (90, -10), "ear_r": (-90, -10), "upper_lip": (0, -25), "chin": (0, -55), "jaw_l": (40, -45),
           "jaw_r": (-40, -45)}
    jpts = {}
    for n, (az, el) in jaw.items():
        a, e = np.radians(az), np.radians(el)
        d = np.array([np.sin(a) * np.cos(e), -np.cos(a) * np.cos(e), np.sin(e)])
        jpts[n] = SurfacePoint("head", local("head", to_world(truth["skull"]["center"] + r * d)))
    out.append(SurfaceElement("mesh:jaw", "mesh", "head", points=jpts, triangles=list(sl.JAW_TRIANGLES)))
    for s in sk.SIDES:
        palm = truth["palms"][s]
        hb = spec.bones[f"hand_{s}"]
        x = normalize(hb.tail - hb.head)
        down = palm["normal_down"]
        yv = np.cross(-down, x)
        centre = hb.head + down * palm["half_thickness"]
        outline = [(0.01, -0.04), (0.01, 0.04), (0.085, 0.04), (0.085, -0.04)]
        names = sl.palm_points(len(outline), s)
        pp = {n: centre + a * x + b * yv for n, (a, b) in zip(names, outline)}
        tris = sl.fan_triangles(names)
        n0 = np.cross(pp[names[1]] - pp[names[0]], pp[names[2]] - pp[names[0]])
        if np.dot(n0, down) < 0:
            names = [names[0], *names[1:][::-1]]
            tris = sl.fan_triangles(names)
        out.append(SurfaceElement(f"mesh:palm_{s}", "mesh", f"hand_{s}",
                                  points={n: SurfacePoint(f"hand_{s}", local(f"hand_{s}", to_world(p)))
                                          for n, p in pp.items()}, triangles=tris))
        so = truth["soles"][s]
        x0, x1 = sorted((so["x"], so["x2"]))
        y0, y1 = so["y"]
        corners = [(x0, y0), (x0, y1), (x1, y1), (x1, y0)]
        names = sl.sole_points(4, s)
        sp = {n: np.array([a, b, so["z"]]) for n, (a, b) in zip(names, corners)}
        n0 = np.cross(sp[names[1]] - sp[names[0]], sp[names[2]] - sp[names[0]])
        if n0[2] > 0:
            names = [names[0], *names[1:][::-1]]
        out.append(SurfaceElement(f"mesh:sole_{s}", "mesh", f"foot_{s}",
                                  points={n: SurfacePoint(f"foot_{s}", local(f"foot_{s}", to_world(p)))
                                          for n, p in sp.items()}, triangles=sl.fan_triangles(names)))
    return out


def rigid_matrix_world(angle_deg: float = 30.0, scale: float = 1.0, offset=(0.3, -0.2, 0.1)) -> np.ndarray:
    """A rotated (about Z then X a little), uniformly scaled, translated armature matrix_world."""
    a, b = np.radians(angle_deg), np.radians(angle_deg / 3)
    rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    rx = np.array([[1, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    m = np.eye(4)
    m[:3, :3] = scale * rz @ rx
    m[:3, 3] = offset
    return m


def plain_and_turned_avatars() -> tuple[BodyModel, BodyModel]:
    """The procedural avatar as built, and turned, scaled 1.2 with its arms dropped 30 degrees: the
    pair a rig-posing test checks a result on (a rig whose armature is not the world's)."""
    return procedural_avatar(), procedural_avatar(matrix_world=rigid_matrix_world(30.0, 1.2), arm_drop_deg=30.0)



def synthetic_take(seed: int, motions: tuple = ("clap", "hand_on_head"), seconds: float = 1.0):
    """(the recording, the performer's body model) of a synthetic take of `motions`, without
    calibration (the performer's truth stands for it)."""
    perf = synthetic.make_performer(seed=seed)
    rec, truth = synthetic.record_session(perf, motions=motions, calibration=False, motion_seconds=seconds)
    return rec, truth.body_model()


def rigs_on_a_take(seed: int, motions: tuple, seconds: float):
    """For each of `plain_and_turned_avatars`: (its rig, the bone frames a synthetic take of
    `motions` gives it, the user's pelvis (F, 3)); the take made once, without calibration."""
    rec, user = synthetic_take(seed, motions, seconds)
    up = ua.animate_user(rec, user)
    for avatar in plain_and_turned_avatars():
        rig = ap.AvatarRig.from_model(avatar)
        yield rig, ap.copy_frames(up.frames, model_rest_frames(user), rig.frames0), up.joints[:, JI["pelvis"]]

# One frame's solve in mathutils (float32, bodycal_addon/core/one_frame.py) against the numpy path's
# float64 values (DESIGN.md "Prepared solver"). Measured: on the pinned tracker takes
# (tests/engine/test_live_push_pin.py, test_solver_speedup_pin.py, test_prepared_solver.py) at most
# 4.0e-5 on a pose-bone quaternion component and 4.4e-6 m on a joint, root or target; on the
# animation transfer to a 1.3x avatar (test_transfer.py) 6.0e-4 on a forearm's component (p99 9.5e-5)
# and 0.21 mm at its elbow: float32's rounding of the IK's inputs (1e-7) magnified by a nearly
# straight limb's bend, h = sqrt(l1^2 - a^2), whose slope grows without bound as the limb straightens
# (a finger's flexion from its tip distance likewise). The pins hold the mathutils path to these
# (positions to 1e-5 m where they are read), the numpy path to 1e-9 as before.
ONE_FRAME_ATOL = {"basis": 1e-3, "position": 1e-5}


def one_frame_atol(key: str) -> float:
    """ONE_FRAME_ATOL for a pinned array named `key` (its kind in the name: basis, else a position)."""
    return ONE_FRAME_ATOL["basis" if "basis" in key else "position"]
