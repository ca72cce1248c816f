"""Read an avatar's armature into canonical terms (DESIGN.md §2, §4; Delahaye 2023, appendix C:
"the calibration of skeleton bones is direct through the skeleton's rig of the avatar; only the
local right directions for knees, elbows, and fingers must be specified").

`read_rig(arm)` returns an `ArmatureReading`: the bone map (auto-detected, plus the user's overrides
stored on the armature object), the rest pose of every avatar bone (armature space, exact), and
every canonical joint the rig allows in world space with the avatar bone it rides on.

Joint rules (rest pose):
- `pelvis` = midpoint of the hips, on the pelvis bone; `spine_root` = head of the first spine
  bone; `spine_01..spine_12` resampled at equal arc length along the polyline through the heads
  of the spine and neck chain bones up to the head bone's head (= `skull_base` = `spine_12`),
  each on the chain bone whose stretch of the polyline holds it (`spine_12` on the head bone);
- `head` = the head bone's tail (top of the head bone), on the head bone;
- `clavicle_<s>` = clavicle head; shoulder/elbow/wrist = heads of upperarm/forearm/hand;
  mcp/pip/dip = heads of finger bones 1..3, tip = tail of bone 3;
- hip/knee/ankle = heads of thigh/shin/foot; toe = head of the toe bone, else the foot's tail.
`local` is the joint in its bone's rest frame in ARMATURE space (bone head at the origin, axes
= the columns of bone.matrix_local): world = matrix_world @ (head + R @ local).

Canonical bone `right` (a world direction, orthogonal to the canonical bone): hinges (forearm,
shin, finger bones 2 and 3) take the avatar bone's local +X (its flexion axis, FORMATS.md §1) or
the per-bone override stored on the armature (`bodycal_hinge_axes`, in the avatar bone's frame);
every other bone follows `retarget.avatar_pose.canonical_rest_frames`, the one rule shared with
the user model (upper limb bones take their child hinge's axis, hand and metacarpals the palm's
lateral line, trunk and head the hip line, clavicles and hips the trunk's forward direction).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from .. import skeleton as sk
from ..errors import BodyCalError

BONE_MAP_PROP = "bodycal_bone_map"  # JSON {segment: avatar bone ("" = unmapped)}: user overrides
HINGE_AXES_PROP = "bodycal_hinge_axes"  # JSON {canonical bone: [x, y, z] in the avatar bone's frame}
HINGE_BONES = tuple(b.name for b in sk.BONES if b.hinge)
A_POSE_DEG = 20.0  # an upper arm further than this below horizontal makes the rest pose an A-pose


@dataclass
class ArmatureReading:
    armature: str
    matrix_world: np.ndarray  # (4, 4)
    bone_map: sk.BoneMap
    bones: dict[str, dict]  # avatar bone -> parent, head, tail (armature space), matrix (3x3), segment
    joints: dict[str, np.ndarray] = field(default_factory=dict)  # canonical joint -> world
    joint_frames: dict[str, str] = field(default_factory=dict)  # canonical joint -> avatar bone
    rights: dict[str, np.ndarray] = field(default_factory=dict)  # canonical bone -> world right
    hinges: dict[str, np.ndarray] = field(default_factory=dict)  # hinge bone -> world flexion axis
    rest_pose: str = "T"
    missing: list[str] = field(default_factory=list)  # optional segments the rig lacks (fingers, toes)

    # -- frames ---------------------------------------------------------------------------------
    def bone_world_matrix(self, bone: str) -> np.ndarray:
        """(4, 4) rest matrix of an avatar bone in world space."""
        b = self.bones[bone]
        m = np.eye(4)
        m[:3, :3] = b["matrix"]
        m[:3, 3] = b["head"]
        return self.matrix_world @ m

    def to_local(self, bone: str, world: np.ndarray) -> np.ndarray:
        """A world point in the avatar bone's rest frame (armature units)."""
        b = self.bones[bone]
        p_arm = np.linalg.solve(self.matrix_world, np.append(world, 1.0))[:3]
        return b["matrix"].T @ (p_arm - b["head"])

    def to_world(self, point_arm: np.ndarray) -> np.ndarray:
        return (self.matrix_world @ np.append(point_arm, 1.0))[:3]

    def axis_world(self, bone: str, local_axis) -> np.ndarray:
        v = self.matrix_world[:3, :3] @ (self.bones[bone]["matrix"] @ np.asarray(local_axis, float))
        return v / np.linalg.norm(v)

    @property
    def up(self) -> np.ndarray:
        """The avatar's up: the armature-space axis (+-X, +-Y, +-Z) closest to its spine, in world.
        Blender rigs stand along +Z; FBX-style rigs keep Y-up bones under an object rotated 90
        degrees. Either way it turns exactly with the armature object."""
        lin = self.matrix_world[:3, :3]
        spine = np.linalg.solve(lin, self.joints["skull_base"] - self.joints["pelvis"])
        k = int(np.argmax(np.abs(spine)))
        v = lin[:, k] * np.sign(spine[k])
        return v / np.linalg.norm(v)

    @property
    def lateral(self) -> np.ndarray:
        """Towards the avatar's left (hip_r -> hip_l), orthogonal to up."""
        v = self.joints["hip_l"] - self.joints["hip_r"]
        v = v - np.dot(v, self.up) * self.up
        return v / np.linalg.norm(v)

    @property
    def forward(self) -> np.ndarray:
        """Where the avatar faces (-Y for a Blender rig facing the front view): left x up."""
        return np.cross(self.lateral, self.up)

    def rig_dict(self) -> dict:
        """extra["rig"] of the avatar body model: everything the retargeting engine needs for FK."""
        return {
            "armature": self.armature,
            "matrix_world": [[round(float(x), 9) for x in row] for row in self.matrix_world],
            "scheme": self.bone_map.scheme,
            "bone_map": self.bone_map.to_dict(),
            "bones": {n: {"parent": b["parent"], "head": [round(float(x), 9) for x in b["head"]],
                          "tail": [round(float(x), 9) for x in b["tail"]],
                          "matrix": [[round(float(x), 9) for x in row] for row in b["matrix"]],
                          "segment": b["segment"],
                          **({"chain_index": b["chain_index"]} if b["chain_index"] is not None else {})}
                      for n, b in self.bones.items()},
            "rest_pose": self.rest_pose,
        }


# --- bone map ------------------------------------------------------------------------------------

def load_overrides(arm) -> dict[str, str]:
    raw = arm.get(BONE_MAP_PROP)
    if not raw:
        return {}
    try:
        data = json.loads(raw)
    except (TypeError, ValueError):
        raise BodyCalError("the stored bone map is not valid JSON", source=arm.name, field=BONE_MAP_PROP,
                           hint="clear it with Detect Bone Map") from None
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


def set_override(arm, segment: str, bone: str | None) -> None:
    """Map `segment` to avatar bone `bone` (None/"" marks it unmapped; the spine and neck chains
    take a comma-separated list, bottom-up); saved with the armature."""
    if segment not in sk.SEGMENTS and segment not in sk.CHAIN_SEGMENTS:
        raise BodyCalError(f"'{segment}' is not a body segment", source=arm.name)
    names = [b.strip() for b in (bone or "").split(",") if b.strip()]
    if len(names) > 1 and segment not in sk.CHAIN_SEGMENTS:
        raise BodyCalError("only the spine and neck take several bones", source=arm.name, field=segment)
    for b in names:
        if b not in arm.data.bones:
            raise BodyCalError(f"armature has no bone '{b}'", source=arm.name, field=segment)
    bone = ",".join(names)
    ov = load_overrides(arm)
    ov[segment] = bone or ""
    arm[BONE_MAP_PROP] = json.dumps(ov)


def clear_overrides(arm) -> None:
    if BONE_MAP_PROP in arm:
        del arm[BONE_MAP_PROP]


def bone_map_for(arm) -> sk.BoneMap:
    """Auto-detected map with the user's overrides applied (chains: comma-separated bone lists)."""
    names = [b.name for b in arm.data.bones]
    bm = sk.detect_bone_map(names)
    ov = load_overrides(arm)
    for seg, bone in ov.items():
        if seg in sk.CHAIN_SEGMENTS:
            bm.chains[seg] = [b for b in bone.split(",") if b and b in arm.data.bones]
            continue
        if bone and bone in arm.data.bones:
            bm.bones[seg] = bone
        else:
            bm.bones.pop(seg, None)
    if ov:
        bm.scheme = f"{bm.scheme}+custom"
        used = set(bm.bones.values()) | {b for c in bm.chains.values() for b in c}
        bm.unmapped = [n for n in names if n not in used]
    return bm


def hinge_overrides(arm) -> dict[str, np.ndarray]:
    raw = arm.get(HINGE_AXES_PROP)
    if not raw:
        return {}
    try:
        return {k: np.asarray(v, float) for k, v in json.loads(raw).items()}
    except (TypeError, ValueError):
        raise BodyCalError("stored hinge axes are not valid JSON", source=arm.name, field=HINGE_AXES_PROP) from None


def set_hinge_axis(arm, canonical_bone: str, local_axis) -> None:
    """Override a hinge's flexion axis, given in the mapped avatar bone's local frame."""
    if canonical_bone not in HINGE_BONES:
        raise BodyCalError(f"'{canonical_bone}' is not a hinge bone ({', '.join(HINGE_BONES[:3])}, ...)",
                           source=arm.name)
    axes = {k: v.tolist() for k, v in hinge_overrides(arm).items()}
    axes[canonical_bone] = [float(x) for x in local_axis]
    arm[HINGE_AXES_PROP] = json.dumps(axes)


# --- reading the rig -----------------------------------------------------------------------------

def _segment_of(bm: sk.BoneMap) -> dict[str, str]:
    seg = {bone: s for s, bone in bm.bones.items()}
    for chain, names in bm.chains.items():
        for n in names:
            seg[n] = chain
    return seg


def check_humanoid(arm, bm: sk.BoneMap) -> None:
    missing = bm.missing(with_fingers=False)
    if missing:
        raise BodyCalError(
            f"not a humanoid rig this version can map: missing {', '.join(missing)}", source=arm.name,
            hint="map these segments in the BodyCal panel (Avatar > Bone Map) or pick another armature")


def read_rig(arm, bone_map: sk.BoneMap | None = None) -> ArmatureReading:
    """Canonical joints and bone rights of an armature in its rest pose."""
    if arm is None or getattr(arm, "type", None) != "ARMATURE":
        raise BodyCalError("not an armature object", source=getattr(arm, "name", "object"))
    bm = bone_map or bone_map_for(arm)
    check_humanoid(arm, bm)
    seg_of = _segment_of(bm)
    chain_index = {n: i for names in bm.chains.values() for i, n in enumerate(names)}
    bones = {}
    for b in arm.data.bones:
        m = b.matrix_local
        bones[b.name] = {"parent": b.parent.name if b.parent else None, "head": np.array(b.head_local[:]),
                         "tail": np.array(b.tail_local[:]),
                         "matrix": np.array([m[i][:3] for i in range(3)], dtype=float),
                         "segment": seg_of.get(b.name),
                         "chain_index": chain_index.get(b.name)}
    rig = ArmatureReading(arm.name, np.array([row[:] for row in arm.matrix_world], dtype=float), bm, bones)
    _canonical_joints(rig)
    _rights(rig, hinge_overrides(arm))
    up_arm = rig.joints["elbow_l"] - rig.joints["shoulder_l"]
    drop = np.degrees(np.arcsin(np.clip(-np.dot(up_arm, rig.up) / np.linalg.norm(up_arm), -1, 1)))
    rig.rest_pose = "A" if drop > A_POSE_DEG else "T"
    return rig


def _canonical_joints(rig: ArmatureReading) -> None:
    bm, bones = rig.bone_map, rig.bones

    def head(bone):
        return rig.to_world(bones[bone]["head"])

    def tail(bone):
        return rig.to_world(bones[bone]["tail"])

    def put(joint, world, frame):
        rig.joints[joint] = np.asarray(world, float)
        rig.joint_frames[joint] = frame

    seg = bm.bones
    for s in sk.SIDES:
        put(f"hip_{s}", head(seg[f"thigh_{s}"]), seg[f"thigh_{s}"])
    put("pelvis", 0.5 * (rig.joints["hip_l"] + rig.joints["hip_r"]), seg["pelvis"])
    chain = list(bm.chains.get("spine", [])) + list(bm.chains.get("neck", []))
    if not chain:
        raise BodyCalError("no spine bones mapped", source=rig.armature, hint="map the spine chain in the panel")
    poly = np.array([head(b) for b in chain] + [head(seg["head"])])
    put("spine_root", poly[0], chain[0])
    spine = sk.resample_polyline(poly, sk.SPINE_COUNT)
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(poly, axis=0), axis=1))])
    targets = np.linspace(0.0, 1.0, sk.SPINE_COUNT + 1) * cum[-1]
    for k in range(1, sk.SPINE_COUNT):
        i = int(np.clip(np.searchsorted(cum, targets[k], side="right") - 1, 0, len(chain) - 1))
        put(sk.spine_joint(k), spine[k], chain[i])
    put(sk.spine_joint(sk.SPINE_COUNT), head(seg["head"]), seg["head"])  # the top of the spine
    put("skull_base", head(seg["head"]), seg["head"])
    put("head", tail(seg["head"]), seg["head"])
    for s in sk.SIDES:
        for joint, segment in (("clavicle", "clavicle"), ("shoulder", "upperarm"), ("elbow", "forearm"),
                               ("wrist", "hand")):
            put(f"{joint}_{s}", head(seg[f"{segment}_{s}"]), seg[f"{segment}_{s}"])
        for f in sk.FINGERS:
            names = [seg.get(f"{f}_{i}_{s}") for i in (1, 2, 3)]
            if not all(names):
                rig.missing.append(f"fingers: {f}_{s}")
                continue
            for joint, b in zip(("mcp", "pip", "dip"), names):
                put(f"{joint}_{f}_{s}", head(b), b)
            put(f"tip_{f}_{s}", tail(names[2]), names[2])
        put(f"knee_{s}", head(seg[f"shin_{s}"]), seg[f"shin_{s}"])
        put(f"ankle_{s}", head(seg[f"foot_{s}"]), seg[f"foot_{s}"])
        if seg.get(f"toe_{s}"):
            put(f"toe_{s}", head(seg[f"toe_{s}"]), seg[f"toe_{s}"])
        else:
            put(f"toe_{s}", tail(seg[f"foot_{s}"]), seg[f"foot_{s}"])
            rig.missing.append(f"toe_{s} (foot tail used)")


def canonical_bones(rig: ArmatureReading) -> list[sk.Bone]:
    return [b for b in sk.BONES if b.head in rig.joints and b.tail in rig.joints]


def _rights(rig: ArmatureReading, overrides: dict[str, np.ndarray]) -> None:
    """Hinge rights from the avatar bones; every other right from the ONE rule the retargeting
    engine uses for the user and the avatar alike (`retarget.avatar_pose.canonical_rest_frames`),
    so surface points expressed in these frames mean the same thing on both sides."""
    from ..bodymodel import BodyModel, Joint
    from ..retarget.avatar_pose import canonical_rest_frames, complete_joints

    seg = rig.bone_map.bones
    hinge_world: dict[str, np.ndarray] = {}
    for name in HINGE_BONES:
        avatar_bone = seg.get(name)
        if avatar_bone is None or sk.BONE_BY_NAME[name].tail not in rig.joints:
            continue
        hinge_world[name] = rig.axis_world(avatar_bone, overrides.get(name, (1.0, 0.0, 0.0)))
    pos = complete_joints(BodyModel("avatar", rig.armature, {j: Joint(p) for j, p in rig.joints.items()}))
    rig.hinges = hinge_world
    frames = canonical_rest_frames(pos, hinge_world)
    for b in canonical_bones(rig):
        d = rig.joints[b.tail] - rig.joints[b.head]
        if np.linalg.norm(d) < 1e-9:
            raise BodyCalError(f"canonical bone {b.name} has zero length", source=rig.armature,
                               hint="check the bone map")
        r = frames[b.name][:, 0]
        if not np.all(np.isfinite(r)) or np.linalg.norm(r) < 0.5:
            raise BodyCalError(f"the right axis of {b.name} runs along the bone", source=rig.armature,
                               hint="override its hinge axis")
        rig.rights[b.name] = r
