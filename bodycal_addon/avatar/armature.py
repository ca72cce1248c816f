"""An armature in canonical terms, numpy only: the rest pose of every bone (armature space, as
Blender's `bone.matrix_local` gives it), the bone map, and every canonical joint the rig allows in
world space with the bone it rides on. `read_armature` builds it from plain arrays;
`blender.avatar_rig.read_rig` reads those arrays from a Blender armature object.

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
every other bone follows `body.rest_frames.canonical_rest_frames`, the one rule shared with
the user model (upper limb bones take their child hinge's axis, hand and metacarpals the palm's
lateral line, trunk and head the hip line, clavicles and hips the trunk's forward direction).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..body import naming
from ..body import skeleton as sk
from ..body.bodymodel import BodyModel, Joint
from ..body.rest_frames import canonical_rest_frames, complete_joints
from ..core.errors import BodyCalError
from ..core.transforms import normalize
from .template import TEMPLATE

HINGE_BONES = tuple(b.name for b in sk.BONES if b.hinge)
A_POSE_DEG = 20.0  # an upper arm further than this below horizontal makes the rest pose an A-pose


@dataclass
class ArmatureReading:
    armature: str
    matrix_world: np.ndarray  # (4, 4)
    bone_map: naming.BoneMap
    bones: dict[str, dict]  # avatar bone -> parent, head, tail (armature space), matrix (3x3), segment
    joints: dict[str, np.ndarray] = field(default_factory=dict)  # canonical joint -> world
    joint_frames: dict[str, str] = field(default_factory=dict)  # canonical joint -> avatar bone
    rights: dict[str, np.ndarray] = field(default_factory=dict)  # canonical bone -> world right
    hinges: dict[str, np.ndarray] = field(default_factory=dict)  # hinge bone -> world flexion axis
    rest_pose: str = "T"
    missing: list[str] = field(default_factory=list)  # optional segments the rig lacks (fingers, toes)
    estimated: list[str] = field(default_factory=list)  # end joints placed by proportion (chain_end)
    derived_hinges: list[str] = field(default_factory=list)  # hinges whose axis came from bend_axis
    # limb bones posed as hanging from the limb bone before them though the file hangs them from
    # another (loose_limb_bones): bone -> its parent in the file; the bake keys them in armature space
    armature_space: dict[str, str | None] = field(default_factory=dict)

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
            **({"armature_space": dict(self.armature_space)} if self.armature_space else {}),
        }


def _segment_of(bm: naming.BoneMap) -> dict[str, str]:
    seg = {bone: s for s, bone in bm.bones.items()}
    for chain, names in bm.chains.items():
        for n in names:
            seg[n] = chain
    return seg


def check_humanoid(name: str, bm: naming.BoneMap, bone_count: int | None = None) -> None:
    """Every required segment mapped; one line otherwise. A rig with fewer bones than the segments
    (Kenney's mini characters: root, torso, head and one bone per arm and leg) is told so: no map
    can give it an elbow or a knee."""
    missing = bm.missing(with_fingers=False)
    if not missing:
        return
    needed = len(sk.required_segments())
    if bone_count is not None and bone_count < needed:
        raise BodyCalError(
            f"not a humanoid rig this version can animate: {bone_count} bones, fewer than the {needed} segments "
            f"it poses (missing {', '.join(missing)})", source=name,
            hint="each arm and leg needs an upper bone, a lower bone and a hand or foot (a limb of one bone "
                 "cannot bend at the elbow or knee); pick another armature")
    raise BodyCalError(
        f"not a humanoid rig this version can map: missing {', '.join(missing)}", source=name,
        hint="map these segments in the BodyCal panel (Avatar > Bone Map) or pick another armature")


def _ancestors(bone: str, parent: dict[str, str | None]) -> list[str]:
    out, seen = [], {bone}
    while (bone := parent.get(bone)) is not None and bone not in seen:
        out.append(bone)
        seen.add(bone)
    return out


def check_pelvis_is_root(name: str, bm: naming.BoneMap, parent: dict[str, str | None]) -> None:
    """The pelvis bone carries the root motion, so both thighs and the spine must hang from it.
    A rig whose bone called "pelvis" is a child of the hips root (Daz, Character Creator: hip ->
    pelvis -> thighs, hip -> abdomen) mapped by that name would leave the spine behind."""
    pelvis = bm.bones["pelvis"]
    spine = (list(bm.chains.get("spine", [])) + list(bm.chains.get("neck", [])))[:1]
    hanging = [bm.bones["thigh_l"], bm.bones["thigh_r"], *spine]
    stray = [b for b in hanging if pelvis not in _ancestors(b, parent)]
    if not stray:
        return
    common = [a for a in _ancestors(hanging[0], parent) if all(a in _ancestors(b, parent) for b in hanging[1:])]
    hint = (f"map pelvis to '{common[0]}', the bone the spine and both thighs hang from" if common
            else "parent the thighs and the spine to the hips bone")
    raise BodyCalError(f"the pelvis bone '{pelvis}' is not a parent of {', '.join(stray)}: the root motion "
                       "would leave them behind", source=name, field="pelvis", hint=hint)


LIMB_LINKS = tuple((f"{child}_{s}", f"{parent}_{s}") for s in sk.SIDES
                   for child, parent in (("forearm", "upperarm"), ("hand", "forearm"), ("shin", "thigh"),
                                         ("foot", "shin")))


def loose_limb_bones(name: str, bm: naming.BoneMap, parent: dict[str, str | None]) -> dict[str, str]:
    """The limb bones that do not hang from the one before them (at any depth), each with that bone:
    a game rig's IK controls beside the limb (RobotExpressive's and Quaternius' knight's feet under
    the root, the leg reaching them through a constraint a glTF file does not keep). The engine
    poses such a bone as if it hung from that bone, and the bake keys its location and rotation in
    the armature's space (output/armature_space.py), as game exporters key IK feet. One line when
    it cannot: the bone before it hangs from it."""
    parent = dict(parent)
    loose = {}
    for child, above in LIMB_LINKS:
        bone, limb = bm.bones[child], bm.bones[above]
        if limb in _ancestors(bone, parent):
            continue
        if bone in _ancestors(limb, parent):
            raise BodyCalError(
                f"the {child.split('_')[0]} bone '{bone}' does not hang from the {above.split('_')[0]} bone '{limb}', "
                "which hangs from it", source=name, field=child,
                hint=f"map {child} and {above} to bones in the limb's order, from the shoulder or hip down")
        loose[bone] = limb
        parent[bone] = limb
    return loose


def settle_pelvis(bm: naming.BoneMap, parent: dict[str, str | None]) -> str | None:
    """A detected map whose pelvis bone is not the one the thighs and the spine hang from takes
    that bone instead (Quaternius: Root or Body -> Hips -> Abdomen, Body -> UpperLeg), as a rig
    would be mapped by hand; a `root` segment that was that bone is dropped (nothing above the
    pelvis carries the travel then). Changes `bm` in place and returns a note, or None when the map
    needed nothing or no such bone exists (`check_pelvis_is_root` then says so)."""
    pelvis = bm.bones.get("pelvis")
    spine = (list(bm.chains.get("spine", [])) + list(bm.chains.get("neck", [])))[:1]
    thighs = [bm.bones.get("thigh_l"), bm.bones.get("thigh_r")]
    if pelvis is None or not spine or not all(thighs):
        return None
    hanging = [*thighs, *spine]
    if all(pelvis in _ancestors(b, parent) for b in hanging):
        return None
    common = [a for a in _ancestors(hanging[0], parent) if all(a in _ancestors(b, parent) for b in hanging[1:])]
    if not common or common[0] in bm.bones.values() and common[0] != bm.bones.get("root"):
        return None
    if bm.bones.get("root") == common[0]:
        del bm.bones["root"]
    bm.bones["pelvis"] = common[0]
    bm.unmapped = [n for n in bm.unmapped if n != common[0]] + [pelvis]
    return f"pelvis: '{common[0]}', the bone the spine and both thighs hang from ('{pelvis}' follows it)"


def read_armature(name: str, matrix_world: np.ndarray, rest_bones: dict[str, dict], bone_map: naming.BoneMap,
                  hinge_overrides: dict[str, np.ndarray] | None = None) -> ArmatureReading:
    """Canonical joints and bone rights of an armature in its rest pose. `rest_bones`: per bone
    {"parent", "head", "tail" (armature space), "matrix" (3x3, the bone's rest axes as columns)}."""
    check_humanoid(name, bone_map, len(rest_bones))
    check_pelvis_is_root(name, bone_map, {n: b["parent"] for n, b in rest_bones.items()})
    loose = loose_limb_bones(name, bone_map, {n: b["parent"] for n, b in rest_bones.items()})
    seg_of = _segment_of(bone_map)
    chain_index = {n: i for names in bone_map.chains.values() for i, n in enumerate(names)}
    bones = {n: {"parent": loose.get(n, b["parent"]), "head": np.asarray(b["head"], float),
                 "tail": np.asarray(b["tail"], float), "matrix": np.asarray(b["matrix"], float),
                 "segment": seg_of.get(n), "chain_index": chain_index.get(n)}
             for n, b in rest_bones.items()}
    rig = ArmatureReading(name, np.asarray(matrix_world, float), bone_map, bones)
    rig.armature_space = {n: rest_bones[n]["parent"] for n in loose}
    _canonical_joints(rig)
    _rights(rig, hinge_overrides or {})
    up_arm = rig.joints["elbow_l"] - rig.joints["shoulder_l"]
    drop = np.degrees(np.arcsin(np.clip(-np.dot(up_arm, rig.up) / np.linalg.norm(up_arm), -1, 1)))
    rig.rest_pose = "A" if drop > A_POSE_DEG else "T"
    return rig


# Where a chain's last bone ends (a fingertip, the top of the head, the toes without a toe bone) is
# its tail only when the tail is a plausible length: an importer sets the tails of glTF and FBX
# bones by a guess (glTF nodes have no length), so a 0.01-scaled Mixamo thumb tip came out 2 m
# away and a Quaternius head 9 mm tall. (shortest, longest, fallback) as fractions of the
# reference length: the previous phalanx, the expected head (HEAD_OF_TRUNK x the trunk), the shin.
END_RANGES = {"tip": (0.4, 2.0, 0.85), "head": (0.5, 3.0, 1.0), "toe": (0.2, 1.0, 0.3)}
TOE_DROP_DEG = 10.0  # an estimated ball of the foot: this far below the horizontal from the ankle
HEAD_OF_TRUNK = TEMPLATE["scale:head"][0]  # skull base to the top of the head, over pelvis to skull base
IN_LINE_DEG = 35.0  # an end bone's child this close to its direction marks where it ends (HeadTop_End)


def chain_end(rig: ArmatureReading, bone: str, reference: float, kind: str,
              direction: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """World point where `bone` ends, and how it was found ("tail", "child", "estimated"): the head
    of a child bone in line with it (a Mixamo `*_End` or `Thumb4` leaf) within the plausible
    range of `kind` (END_RANGES, times `reference` m), else its tail when that is in range, else
    its head plus `direction` (default: the bone's own +Y) times the fallback length."""
    lo, hi, fallback = (reference * f for f in END_RANGES[kind])
    head = rig.to_world(rig.bones[bone]["head"])
    axis = rig.axis_world(bone, (0.0, 1.0, 0.0)) if direction is None else normalize(direction)
    best = None
    for b in rig.bones.values():
        if b["parent"] != bone:
            continue
        d = rig.to_world(b["head"]) - head
        n = float(np.linalg.norm(d))
        if lo <= n <= hi and np.dot(d, axis) >= n * np.cos(np.radians(IN_LINE_DEG)) and (best is None or n > best[0]):
            best = (n, head + d)
    if best is not None:
        return best[1], "child"
    tail = rig.to_world(rig.bones[bone]["tail"])
    if lo <= np.linalg.norm(tail - head) <= hi:
        return tail, "tail"
    return head + axis * fallback, "estimated"


def _canonical_joints(rig: ArmatureReading) -> None:
    bm, bones = rig.bone_map, rig.bones

    def head(bone):
        return rig.to_world(bones[bone]["head"])

    def end(joint, bone, reference, kind, direction=None):
        point, how = chain_end(rig, bone, reference, kind, direction)
        if how == "estimated":
            rig.estimated.append(joint)
        put(joint, point, bone)

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
    trunk = float(np.linalg.norm(rig.joints["skull_base"] - rig.joints["pelvis"]))
    end("head", seg["head"], HEAD_OF_TRUNK * trunk, "head", rig.joints["skull_base"] - rig.joints["pelvis"])
    for s in sk.SIDES:
        if seg.get(f"clavicle_{s}"):
            put(f"clavicle_{s}", head(seg[f"clavicle_{s}"]), seg[f"clavicle_{s}"])
        else:
            rig.missing.append(f"clavicle_{s} (the arm hangs from the spine)")
        for joint, segment in (("shoulder", "upperarm"), ("elbow", "forearm"), ("wrist", "hand")):
            put(f"{joint}_{s}", head(seg[f"{segment}_{s}"]), seg[f"{segment}_{s}"])
        for f in sk.FINGERS:
            names = [seg.get(f"{f}_{i}_{s}") for i in (1, 2, 3)]
            if not all(names):
                rig.missing.append(f"fingers: {f}_{s}")
                continue
            for joint, b in zip(("mcp", "pip", "dip"), names):
                put(f"{joint}_{f}_{s}", head(b), b)
            phalanx = rig.joints[f"dip_{f}_{s}"] - rig.joints[f"pip_{f}_{s}"]
            end(f"tip_{f}_{s}", names[2], float(np.linalg.norm(phalanx)), "tip", phalanx)
        put(f"knee_{s}", head(seg[f"shin_{s}"]), seg[f"shin_{s}"])
        put(f"ankle_{s}", head(seg[f"foot_{s}"]), seg[f"foot_{s}"])
        if seg.get(f"toe_{s}"):
            put(f"toe_{s}", head(seg[f"toe_{s}"]), seg[f"toe_{s}"])
        else:
            shin = float(np.linalg.norm(rig.joints[f"ankle_{s}"] - rig.joints[f"knee_{s}"]))
            # the foot's own +Y is an importer's guess too: forward and down to the ball
            down = np.radians(TOE_DROP_DEG)
            end(f"toe_{s}", seg[f"foot_{s}"], shin, "toe", np.cos(down) * rig.forward - np.sin(down) * rig.up)
            rig.missing.append(f"toe_{s} (foot tail used)")


def canonical_bones(rig: ArmatureReading) -> list[sk.Bone]:
    return [b for b in sk.BONES if b.head in rig.joints and b.tail in rig.joints]


BENT_DEG = 8.0  # a rest chain bent less than this says nothing of its hinge's axis
# A bone's local X is its hinge axis (FORMATS.md §1) when it is within 60 degrees of the axis the
# chain's bend or the anatomy gives. Blender-made rigs agree (the shared avatars: 0.76-1.00 on every
# finger, 1.00 on elbows and knees); a glTF or FBX import's bone roll is the file's joint axes,
# arbitrary for this purpose (a Mixamo Xbot's knees point their X the other way, a Soldier's left
# and right forearms opposite ways). The thumb's axis is not the palm line's: only one along the
# bone is replaced.
HINGE_AGREE = 0.5


def bend_axis(rig: ArmatureReading, hinge: str) -> np.ndarray:
    """A hinge's flexion axis (world) where the avatar bone's local X cannot be it (it runs along
    the bone: an importer's bone roll). From the chain's bend at rest (parent x bone: the rest
    bend is taken as flexion) when it is bent, else by anatomy: an elbow flexes the forearm
    forward, a knee the shin back, a finger towards the palm (about the line from the index's
    knuckle to the pinky's, left hand; the mirror on the right). The bend is kept only where it
    does not contradict the anatomy."""
    b = sk.BONE_BY_NAME[hinge]
    parent = sk.BONE_BY_NAME[b.parent]
    p = rig.joints[b.head] - rig.joints[parent.head]
    d = normalize(rig.joints[b.tail] - rig.joints[b.head])
    side = hinge[-1]
    if hinge.startswith("forearm_"):
        anatomical = np.cross(d, rig.forward)
    elif hinge.startswith("shin_"):
        anatomical = np.cross(d, -rig.forward)
    elif f"mcp_index_{side}" in rig.joints and f"mcp_pinky_{side}" in rig.joints:
        across = rig.joints[f"mcp_pinky_{side}"] - rig.joints[f"mcp_index_{side}"]
        anatomical = across if side == "l" else -across
    else:
        anatomical = rig.lateral if side == "l" else -rig.lateral
    anatomical = normalize(anatomical - np.dot(anatomical, d) * d)
    bend = np.cross(p, d)
    if np.linalg.norm(bend) > np.sin(np.radians(BENT_DEG)) * np.linalg.norm(p):
        bend = normalize(bend)
        if np.dot(bend, anatomical) > -0.3:
            return bend
    return anatomical


def _rights(rig: ArmatureReading, overrides: dict[str, np.ndarray]) -> None:
    """Hinge rights from the avatar bones; every other right from the ONE rule the retargeting
    engine uses for the user and the avatar alike (`body.rest_frames.canonical_rest_frames`),
    so surface points expressed in these frames mean the same thing on both sides."""

    seg = rig.bone_map.bones
    hinge_world: dict[str, np.ndarray] = {}
    for name in HINGE_BONES:
        avatar_bone = seg.get(name)
        if avatar_bone is None or sk.BONE_BY_NAME[name].tail not in rig.joints:
            continue
        axis = rig.axis_world(avatar_bone, overrides.get(name, (1.0, 0.0, 0.0)))
        d = normalize(rig.joints[sk.BONE_BY_NAME[name].tail] - rig.joints[sk.BONE_BY_NAME[name].head])
        if name not in overrides:
            derived = bend_axis(rig, name)
            along = np.linalg.norm(axis - np.dot(axis, d) * d) < 0.5
            if along or (not name.startswith("thumb_") and np.dot(axis, derived) < HINGE_AGREE):
                axis = derived
                rig.derived_hinges.append(name)
        hinge_world[name] = axis
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
