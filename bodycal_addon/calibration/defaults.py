"""Anthropometric defaults for what a recording does not measure (DESIGN.md §3: "Anything a
recording lacks is defaulted from anthropometric ratios of the eye height, and the report says
which"), so a 6-device AvatarGo recording still yields a complete body model.

Ratios are of the stature H = eye height / 0.936 (Drillis & Contini 1966 segment proportions;
Winter, "Biomechanics and Motor Control of Human Movement", Fig. 4.1). Positions are anchored on
what is known at the reference time (measured joints, device poses in the T-pose) and fall back to
a body frame: up = +Z, left `L`, forward `F` = L x up.

Where the devices sit on the body (checked against the CMU subjects of `evaluation/`):
- the foot tracker is strapped on the instep, in front of the ankle (the top of the navicular and
  cuneiforms, about a quarter of the foot's length, 0.035 H, ahead of the joint), along the foot,
  which points 10° out from the body's forward (the foot progression angle, 7-13° in adults);
  the ankle joint centre stands 0.045 H above the floor barefoot and 0.059-0.072 H in shoes (the
  CMU subjects): 0.060 H;
- the HMD's origin is at the eyes, about 0.049 H in front of and 0.020 H above the skull base
  (the atlanto-occipital joint lies just below the ear canal, which is level with the eyes);
- a controller's grip (OpenXR's grip pose) is the centre of the closed fist: 0.037 H along the
  hand from the wrist and 0.016 H to the palm side (palms down in the T-pose).

**Decision** (an elbow without limb trackers): between the shoulder and the wrist, its upper arm
the mean of two estimates about equally uncertain, the length its flex step measured (the hand
device's circle about the elbow, limbs.py: within 14 mm, sd 7, on five CMU clips x six sessions)
and the ratio's share of the reach (CMU subjects 2 and 5 have upper arms 59-60 % of the arm, the
ratio's 56 %: 18-22 mm short). Elbows with six devices: RMS 9.5 / 14.8 mm (left / right) by the
ratio, 10.0 / 11.5 by the measurement alone, 7.0 / 11.5 by the mean; worst 24 -> 21 mm.

**Decision** (a wrist / ankle without a limb tracker): the anatomical default above, moved half
way across the limb to the point of the end device its swing kept at one distance from the
shoulder / hip (limbs.py, the moving-point sphere): nobody holds the ankle or the wrist still in a
swing, and the device turns about that joint. Along the limb the swing cannot see the point (it
trades with the sphere's radius), so the default's height stands. Across the leg the two miss
the truth by RMS 26 mm (the default) and 18 mm (the swing) on three CMU clips x three sessions
(`evaluation/`): where the tracker sits on the instep (30-55 % of the foot) and how the foot stands
(05_06's right foot pitched toes down: 54-56 mm by the default alone) move the default; soft
tissue and a knee bending a few degrees in the swing move the swing's point (its signal is the
ankle's few degrees of wander). Half way and the inverse-variance 0.67 give the same RMS (20 mm
at the ankle), half way the smaller worst (30 against 37 mm). Six-device ankles: worst 69 -> 33
mm, RMS 27 -> 19 (three clips x six sessions, both sides); elbows, between the shoulder and the
wrist, median 9.7 -> 9.1 mm, worst 21 -> 21. The knee's flex step adds nothing here: a hinge's
circle leaves a sphere undetermined, and a moving-point circle of the foot about the knee put the
ankle 57-320 mm off (the thigh wanders as much as the ankle). Beyond Delahaye 2023 (appendix B
takes the ankle from two touches); the same functional idea as its limb joints.

With the six-device touches (lengths.py; DESIGN.md §3 "Touches with six devices") the wrists and
ankles are measured (no default), the knees and elbows placed here with the thigh, shin and
forearm the touches measured, and the hips the foot's swing placed raised or lowered to the
standing legs' reach (`_legs_from_touches`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..body import skeleton as sk
from ..core import transforms as tf
from ..core.transforms import EPS
from . import lengths
from .common import Session, State
from .hands import PHALANX_FRACTIONS

EYE_TO_STATURE = 0.93
R = {  # fractions of the stature (joint centres, so the shoulders are narrower than the biacromial width)
    "shoulder_height": 0.818, "shoulder_half_width": 0.1025, "hip_height": 0.53, "hip_half_width": 0.05,
    "thigh": 0.245, "shin": 0.246, "ankle_height": 0.060, "upperarm": 0.186, "forearm": 0.146, "hand": 0.108,
    "pelvis_forward_of_back_tracker": 0.055, "skull_base_back": 0.049, "skull_base_down": 0.020,
    "toe_forward": 0.08, "toe_height": 0.012, "wrist_in_from_grip": 0.037, "wrist_above_grip": 0.016,
    "ankle_behind_foot_tracker": 0.035, "foot_toe_out_deg": 10.0, "reference_bend_deg": 5.0,
    "foot_width": 0.05, "heel_back": 0.03,
    "skull_radius": 0.051, "skull_up": 0.043, "head_above_skull_base": 0.057, "hips_forward_of_skull_base": 0.02,
    "ankles_behind_hips": 0.02,
}
RADII = {"shoulder": 0.028, "elbow": 0.022, "wrist": 0.016, "hip": 0.05, "knee": 0.03, "ankle": 0.02,
         "finger": 0.0048}
# Finger bases relative to the wrist: (along the hand, across toward the thumb) and the finger
# length (base to extended tip), fractions of the stature.
FINGER_LAYOUT = {"thumb": (0.018, 0.022, 0.05), "index": (0.049, 0.012, 0.055), "middle": (0.050, 0.0, 0.06),
                 "ring": (0.047, -0.011, 0.056), "pinky": (0.043, -0.021, 0.045)}
# Torso crude mesh: (fraction along spine_root -> skull_base, toward the left, forward) x stature.
TORSO_LAYOUT = {"sternum": (0.62, 0.0, 0.10), "chest_l": (0.55, 0.06, 0.10), "chest_r": (0.55, -0.06, 0.10),
                "belly_ul": (0.35, 0.055, 0.095), "belly_ur": (0.35, -0.055, 0.095),
                "belly_ll": (0.10, 0.05, 0.09), "belly_lr": (0.10, -0.05, 0.09),
                "back_ul": (0.55, 0.05, -0.03), "back_ur": (0.55, -0.05, -0.03), "back_low": (0.15, 0.0, -0.03)}
# Jaw crude mesh around the skull base: (left, forward, up) x stature.
JAW_LAYOUT = {"ear_l": (0.04, 0.02, 0.02), "ear_r": (-0.04, 0.02, 0.02), "upper_lip": (0.0, 0.065, 0.0),
              "chin": (0.0, 0.06, -0.03), "jaw_l": (0.03, 0.045, -0.015), "jaw_r": (-0.03, 0.045, -0.015)}

UP = np.array([0.0, 0.0, 1.0])


def _horizontal(v) -> np.ndarray | None:
    v = np.array(v, float)
    v[2] = 0.0
    n = np.linalg.norm(v)
    return v / n if n > 1e-6 else None


class BodyFrame:
    """Up, left, forward, centre and stature at the reference time."""

    def __init__(self, session: Session, state: State):
        self.session, self.state = session, state
        has = session.has
        w = state.world
        left = None
        how = ""
        if "hip_l" in w and "hip_r" in w:
            left, how = _horizontal(w["hip_l"] - w["hip_r"]), "hip line"
        if left is None and has("hand_l") and has("hand_r") and session.reference_step == "tpose":
            left, how = _horizontal(session.ref_pose("hand_l")[0] - session.ref_pose("hand_r")[0]), "T-pose hands"
        if left is None and has("foot_l") and has("foot_r"):
            left, how = _horizontal(session.ref_pose("foot_l")[0] - session.ref_pose("foot_r")[0]), "feet"
        if left is None and has("head"):  # the view's axes (FORMATS.md §2.1): x right
            left, how = _horizontal(-tf.quat_to_matrix(session.ref_pose("head")[1])[:, 0]), "HMD's view"
        if left is None:
            left, how = np.array([1.0, 0, 0]), "assumed: facing -Y"
        self.left, self.left_from = left, how
        self.forward = np.cross(left, UP)
        if has("head"):
            self.eye_height = float(session.ref_pose("head")[0][2])
            self.eye_from = "HMD height"
        elif "shoulder_l" in w and "shoulder_r" in w:
            self.eye_height = float(0.5 * (w["shoulder_l"][2] + w["shoulder_r"][2]) / R["shoulder_height"]
                                    * EYE_TO_STATURE)
            self.eye_from = "shoulder height"
        else:
            self.eye_height, self.eye_from = 1.62, "assumed (no HMD)"
        self.stature = self.eye_height / EYE_TO_STATURE
        if "hip_l" in w and "hip_r" in w:
            c = 0.5 * (w["hip_l"] + w["hip_r"])
        elif has("pelvis"):
            c = session.ref_pose("pelvis")[0]
        elif has("head"):
            c = session.ref_pose("head")[0]
        else:
            c = np.zeros(3)
        self.centre = np.array([c[0], c[1], 0.0])

    def at(self, height: float, left: float = 0.0, forward: float = 0.0, base=None) -> np.ndarray:
        base = self.centre if base is None else np.array([base[0], base[1], 0.0])
        return base + self.left * left + self.forward * forward + UP * height


_SIGN = {"l": 1.0, "r": -1.0}  # toward the body's left


@dataclass
class _Placement:
    """What the passes of `default_joints` share: the world joints so far (`world`, measured and
    already defaulted), the defaulted ones alone (`placed`), and the stature `H`."""
    session: Session
    state: State
    body: BodyFrame
    world: dict[str, np.ndarray]
    placed: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def H(self) -> float:
        return self.body.stature

    def put(self, name: str, value, how: str) -> None:
        """Defaults joint `name` to `value` unless it is already known; two touches that estimate it
        win over the ratio. Records `how` in the session's defaults."""
        if name not in self.world:
            est = self.state.extra.get("touch_estimates", {}).get(name)
            if est is not None:
                value = self.session.to_world(est[0], est[1])
                how = f"mean of its two touches, in the {est[0]} tracker's frame (not rigid)"
            self.world[name] = self.placed[name] = np.asarray(value, float)
            self.session.default(name, how)


def default_joints(session: Session, state: State, body: BodyFrame) -> dict[str, np.ndarray]:
    """World positions of every canonical joint the steps did not measure (not spine vertebrae,
    clavicles or spine_root: the trunk rules place those)."""
    placing = _Placement(session, state, body, dict(state.world))
    _legs_from_touches(placing)
    _place_pelvis_and_hips(placing)
    _place_legs(placing)
    _place_arms(placing)
    _place_head(placing)
    _place_fingers(placing)
    return placing.placed


def _place_pelvis_and_hips(placing: _Placement) -> None:
    """Pelvis pass: the pelvis from the hips, else the pelvis tracker, else under the skull base
    (the HMD's) at the standing legs' height, else the stature; then each hip beside it. Reads the
    reference poses; adds pelvis, hip_l, hip_r when unmeasured."""
    session, body, w, H, put = placing.session, placing.body, placing.world, placing.H, placing.put
    if "pelvis" not in w:
        if "hip_l" in w and "hip_r" in w:
            put("pelvis", 0.5 * (w["hip_l"] + w["hip_r"]), "midpoint of the hips")
        elif session.kind("pelvis") == "estimated":
            put("pelvis", session.ref_pose("pelvis")[0], "where the estimated pelvis stands "
                "(estimated_devices.provisional_body: under the skull base, the legs' height above the floor)")
        elif session.has("pelvis"):
            p = session.ref_pose("pelvis")[0]
            put("pelvis", body.at(R["hip_height"] * H, 0, R["pelvis_forward_of_back_tracker"] * H, p),
                f"{R['pelvis_forward_of_back_tracker']} H in front of the pelvis tracker, {R['hip_height']} H high")
        else:
            put("pelvis", body.at(R["hip_height"] * H), f"{R['hip_height']} H above the floor")
    for s in sk.SIDES:
        put(f"hip_{s}", w["pelvis"] + body.left * _SIGN[s] * R["hip_half_width"] * H,
            f"{R['hip_half_width']} H beside the pelvis")


def _place_ankle(placing: _Placement, s: str) -> None:
    """The ankle of side `s`, unless measured: behind the foot tracker on the instep (moved toward
    the hip swing's point), or under the hip."""
    session, body, H, put = placing.session, placing.body, placing.H, placing.put
    if session.kind(f"foot_{s}") == "estimated":
        put(f"ankle_{s}", session.ref_pose(f"foot_{s}")[0], "where the estimated foot stands "
            "(estimated_devices.provisional_body: under the hip, a little behind it)")
    elif session.has(f"foot_{s}"):
        # On the instep the tracker is ahead of the ankle along the foot; the height is the
        # ankle's above the floor, whatever the tracker's.
        p = session.ref_pose(f"foot_{s}")[0]
        toe_out = np.radians(R["foot_toe_out_deg"])
        along = body.forward * np.cos(toe_out) + body.left * _SIGN[s] * np.sin(toe_out)
        back = p - along * R["ankle_behind_foot_tracker"] * H
        ankle, how = _with_swing_point(placing, f"ankle_{s}", np.array([back[0], back[1], R["ankle_height"] * H]))
        put(f"ankle_{s}", ankle, f"{R['ankle_height']} H above the floor, {R['ankle_behind_foot_tracker']} H "
            f"behind the foot tracker along the foot{how}")
    else:
        put(f"ankle_{s}", body.at(R["ankle_height"] * H, _SIGN[s] * R["hip_half_width"] * H),
            f"{R['ankle_height']} H high under the hip")


def _legs_from_touches(placing: _Placement) -> None:
    """Six devices with the knee touches (lengths.py): each touched leg's thigh and shin measured
    from the hip (pelvis tracker's frame) and the ankle (foot tracker's, measured or defaulted
    here); and when the foot's swing placed the hips, their height from the standing legs
    (lengths.py, Decision), both at the mean of the touched legs' heights, the thighs measured
    again from the moved hips until they settle. A hip from touches or a thigh tracker is not
    weak along the leg and stays. Moves measured hips: `state.world` and their pelvis frame too."""
    session, state, w = placing.session, placing.state, placing.world
    pairs = {}
    for s in sk.SIDES:
        foot = f"foot_{s}"
        if session.has(f"shin_{s}") or not session.has(foot) or "pelvis" not in state.local.get(f"hip_{s}", {}):
            continue
        pair = lengths.touch_pair(session, state, "knee", s, foot)
        if pair is not None:
            pairs[s] = pair
    if not pairs:
        return
    radius = RADII["knee"] * placing.H
    for s in pairs:
        _place_ankle(placing, s)
    ankle_local = {s: session.to_local(f"foot_{s}", w[f"ankle_{s}"]) for s in pairs}
    moved = [s for s in sk.SIDES if session.quality.get(f"swing_hip_{s}", {}).get("frames") == f"foot_{s} in pelvis"]
    before = {s: float(w[f"hip_{s}"][2]) for s in moved}
    found = {}
    for _ in range(lengths.SETTLE_PASSES if moved else 1):
        found = {}
        for s, pair in pairs.items():
            l2 = lengths.length_to(session, pair, f"foot_{s}", ankle_local[s], radius)
            if "pelvis" in session.estimated:
                # Decision: an estimated pelvis does not follow a performer crouching to touch a
                # knee (it stays where it stood, estimated_devices.BENT_DROP), so the thigh is what
                # closes the table's hip height over the measured shin (the feet do stay put).
                l1 = None if l2 is None else lengths.upper_closing_reach(
                    l2, float(np.linalg.norm(w[f"hip_{s}"] - w[f"ankle_{s}"])), R["reference_bend_deg"])
            else:
                l1 = lengths.length_to(session, pair, "pelvis", state.local[f"hip_{s}"]["pelvis"], radius)
            if l1 is not None and l2 is not None:
                found[s] = (l1, l2)
        heights = []
        for s, (l1, l2) in found.items():
            reach = lengths.two_bone_reach(l1, l2, R["reference_bend_deg"])
            a, h = w[f"ankle_{s}"], w[f"hip_{s}"]
            across = float(np.linalg.norm((h - a)[:2]))
            if reach > across:
                heights.append(float(a[2]) + float(np.sqrt(reach * reach - across * across)))
        if not moved or not heights:
            break
        z = float(np.mean(heights))
        for s in moved:
            h = w[f"hip_{s}"].copy()
            h[2] = z
            w[f"hip_{s}"] = state.world[f"hip_{s}"] = h
            state.set_local(f"hip_{s}", "pelvis", session.to_local("pelvis", h))
    state.extra["leg_lengths"] = found
    for s in moved:
        if w[f"hip_{s}"][2] != before[s]:
            session.quality.setdefault(f"swing_hip_{s}", {})["height_from_legs_mm"] = round(
                (float(w[f"hip_{s}"][2]) - before[s]) * 1000, 1)
    for s, (l1, l2) in found.items():
        session.use(f"knee_{s} touches", {"thigh_mm": round(l1 * 1000, 1), "shin_mm": round(l2 * 1000, 1),
                                           "frames": f"hip in pelvis, ankle in foot_{s}"})


def _place_legs(placing: _Placement) -> None:
    """Legs pass, side by side: the ankle behind the foot tracker on the instep (or under the hip),
    the knee between hip and ankle, slightly bent, and the toe ahead of the ankle. Needs the hips."""
    session, body, w, H, put = placing.session, placing.body, placing.world, placing.H, placing.put
    for s in sk.SIDES:
        _place_ankle(placing, s)
        a, h = w[f"ankle_{s}"], w[f"hip_{s}"]
        measured = placing.state.extra.get("leg_lengths", {}).get(s)
        l1, l2 = measured if measured else (R["thigh"] * H, R["shin"] * H)
        how = ("its thigh and shin from the knee touches" if measured else "at the thigh : shin ratio")
        put(f"knee_{s}", _relaxed_mid(session, placing.state, h, a, l1, l2, f"shin_{s}"),
            f"between the hip and the ankle, {how}, bent {R['reference_bend_deg']:.0f}° "
            f"(standing, nobody locks the knee straight)")
        put(f"toe_{s}", body.at(R["toe_height"] * H, 0, R["toe_forward"] * H, w[f"ankle_{s}"]),
            f"{R['toe_forward']} H in front of the ankle")


def _place_arms(placing: _Placement) -> None:
    """Arms pass: the shoulders (in the T-pose on the line between the hands), the wrists
    (`_place_wrist`), then the elbows between them, slightly bent."""
    session, body, w, H, put = placing.session, placing.body, placing.world, placing.H, placing.put
    tpose_hands = session.reference_step == "tpose" and session.has("hand_l") and session.has("hand_r")
    if tpose_hands:
        hl, hr = session.ref_pose("hand_l")[0], session.ref_pose("hand_r")[0]
        mid, across = 0.5 * (hl + hr), (hl - hr) / max(np.linalg.norm(hl - hr), 1e-9)
    for s in sk.SIDES:
        if tpose_hands:
            put(f"shoulder_{s}", mid + across * _SIGN[s] * R["shoulder_half_width"] * H,
                f"on the T-pose hand line, {R['shoulder_half_width']} H from the middle")
        else:
            put(f"shoulder_{s}", body.at(R["shoulder_height"] * H, _SIGN[s] * R["shoulder_half_width"] * H),
                f"{R['shoulder_height']} H high, {R['shoulder_half_width']} H beside the middle")
        _place_wrist(placing, s, w[f"shoulder_{s}"])
    table = _table_arm(placing)
    for s in sk.SIDES:
        sh, wr = w[f"shoulder_{s}"], w[f"wrist_{s}"]
        l1, l2 = R["upperarm"] * H, R["forearm"] * H
        how = "at the upper arm : forearm ratio"
        upper = placing.state.extra.get("upper_lengths", {}).get(f"elbow_{s}")
        touched = _arm_from_touches(placing, s, sh, wr)
        if touched is not None:
            (l1, l2), how = touched
        elif upper is not None:  # the module docstring's Decision: the mean of the two estimates
            reach = float(np.linalg.norm(wr - sh))
            bent = _bent_lengths(0.5 * upper + 0.5 * reach * l1 / (l1 + l2), reach)
            if bent is not None:
                (l1, l2), how = bent, "the upper arm as long as the mean of its flex step's and the ratio's"
        elif table is not None:
            (l1, l2), how = table
            put(f"elbow_{s}", _bent_elbow(body, s, sh, wr, l1, l2), f"{how}, bent back, down and out to the "
                "hand where the standing moment found it")
            continue
        put(f"elbow_{s}", _relaxed_mid(session, placing.state, sh, wr, l1, l2, f"forearm_{s}"),
            f"between the shoulder and the wrist, {how}, bent {R['reference_bend_deg']:.0f}° (nobody locks "
            f"the elbow straight)")


def _table_arm(placing: _Placement):
    """((upper arm, forearm), how) for arms nothing measured, or None when the reference step
    measures them (a T-pose or a stand step holds the arms straight).

    Without either the reference is a moment the performer stood still with the hands anywhere
    (a Beat Saber player holds them at the chest): the hand's distance to the shoulder is no
    arm's length, and taking it for one gave arms of 7 to 53 cm on the real three-point takes
    (the avatar's hands then fell up to 63 cm short of the controllers, bench_three_point). The
    arms are the table's, both alike, lengthened together when a hand already reached further."""
    session, w, H = placing.session, placing.world, placing.H
    if session.reference_step in ("tpose", "stand") or not (session.has("hand_l") and session.has("hand_r")):
        return None
    measured = placing.state.extra.get("upper_lengths", {})
    if any(f"elbow_{s}" in measured or session.has(f"forearm_{s}") for s in sk.SIDES):
        return None
    l1, l2 = R["upperarm"] * H, R["forearm"] * H
    most = (l1 + l2) * np.cos(np.radians(R["reference_bend_deg"]) / 2)
    reach = max(float(np.linalg.norm(w[f"wrist_{s}"] - w[f"shoulder_{s}"])) for s in sk.SIDES)
    if reach <= most:
        return (l1, l2), f"the table's upper arm and forearm ({R['upperarm']} H, {R['forearm']} H)"
    k = reach / most
    return (l1 * k, l2 * k), (f"the table's upper arm and forearm lengthened {k:.2f} times to the hand that "
                              f"reached furthest at the standing moment")


def _bent_elbow(body: BodyFrame, s: str, sh: np.ndarray, wr: np.ndarray, l1: float, l2: float) -> np.ndarray:
    """The elbow of an arm of lengths `l1`, `l2` from the shoulder `sh` to the wrist `wr`, bent
    back, down and out (where a relaxed elbow goes)."""
    d = wr - sh
    reach = float(np.linalg.norm(d))
    if reach < 1e-6:
        return sh - UP * l1
    u = d / reach
    out = body.left * _SIGN[s]
    pole = -body.forward - UP + 0.5 * out
    pole = pole - (pole @ u) * u
    if np.linalg.norm(pole) < 1e-9:  # the arm along the pole itself: bend out to the side
        pole = out - (out @ u) * u
    pole = pole / max(np.linalg.norm(pole), 1e-9)
    along = float(np.clip((l1 * l1 - l2 * l2 + reach * reach) / (2 * reach), -l1, l1))  # law of cosines
    return sh + u * along + pole * np.sqrt(max(l1 * l1 - along * along, 0.0))


def _arm_from_touches(placing: _Placement, s: str, sh: np.ndarray, wr: np.ndarray):
    """Six devices with the elbow touches (lengths.py): ((upper arm, forearm), how) with the forearm
    from the touches and the wrist in the hand device's frame, the upper arm closing the T-pose's
    reach; None without them."""
    session, state = placing.session, placing.state
    hand = f"hand_{s}"
    if session.has(f"forearm_{s}") or not session.has(hand):
        return None
    pair = lengths.touch_pair(session, state, "elbow", s, hand)
    if pair is None:
        return None
    l2 = lengths.length_to(session, pair, hand, session.to_local(hand, wr), RADII["elbow"] * placing.H)
    if l2 is None:
        return None
    l1 = lengths.upper_closing_reach(l2, float(np.linalg.norm(wr - sh)), R["reference_bend_deg"])
    if l1 is None:
        return None
    session.use(f"elbow_{s} touches", {"forearm_mm": round(l2 * 1000, 1), "upper_arm_mm": round(l1 * 1000, 1),
                                       "frames": f"wrist in {hand}"})
    return (l1, l2), "its forearm from the elbow touches"


SWING_POINT_WEIGHT = 0.5  # the module docstring's Decision (a wrist / ankle without a limb tracker)


def _with_swing_point(placing: _Placement, name: str, value: np.ndarray) -> tuple[np.ndarray, str]:
    """`value` (the anatomical default of wrist / ankle `name`) moved across the limb half way to
    the point the limb's swing found in the end device's frame (limbs.py, `swing_points`), and a
    note for the report; unchanged (and no note) when the swing found none."""
    found = placing.state.extra.get("swing_points", {}).get(name)
    if found is None or name in placing.world:
        return value, ""
    device, point, toward = found
    here = placing.session.to_local(device, value)
    d = point - here
    across = d - (d @ toward) * toward  # along the limb the swing cannot see the point
    moved = here + SWING_POINT_WEIGHT * across
    q = placing.session.quality.setdefault(f"{name} from the swing", {})
    q.update({"across_limb_mm": round(float(np.linalg.norm(across)) * 1000, 1), "weight": SWING_POINT_WEIGHT})
    return placing.session.to_world(device, moved), (f", moved across the limb {SWING_POINT_WEIGHT:g} of the way to "
                                                      f"the point its swing kept at one distance")


def _bent_lengths(l1: float | None, reach: float) -> tuple[float, float] | None:
    """(l1, l2): a measured upper bone `l1` and the lower bone that closes the triangle to `reach`
    with the joint bent R["reference_bend_deg"]; None when there is no such triangle with the
    lower bone at least half the upper one (a measurement that does not fit the limb)."""
    if l1 is None:
        return None
    b = np.radians(R["reference_bend_deg"])
    disc = reach * reach - (l1 * np.sin(b)) ** 2
    if disc <= 0.0:
        return None
    l2 = float(-l1 * np.cos(b) + np.sqrt(disc))
    return (l1, l2) if l2 >= 0.5 * l1 else None


def _place_wrist(placing: _Placement, s: str, sh: np.ndarray) -> None:
    """The wrist of side `s`: in from the hand device's grip toward the shoulder `sh` (and above
    it, palms down, in the T-pose), else the arm hanging straight down."""
    session, H = placing.session, placing.H
    if session.has(f"hand_{s}"):
        p = session.ref_pose(f"hand_{s}")[0]
        out_dir = (p - sh) / max(np.linalg.norm(p - sh), 1e-9)
        wrist = p - out_dir * R["wrist_in_from_grip"] * H
        how = f"{R['wrist_in_from_grip']} H from the hand device toward the shoulder"
        if session.reference_step == "tpose":  # palms down: the fist's centre is below the wrist
            wrist = wrist + UP * R["wrist_above_grip"] * H
            how += f", {R['wrist_above_grip']} H above it"
        wrist, moved = _with_swing_point(placing, f"wrist_{s}", wrist)
        placing.put(f"wrist_{s}", wrist, how + moved)
    else:
        placing.put(f"wrist_{s}", sh - UP * (R["upperarm"] + R["forearm"]) * H, "arm hanging straight down")


def _place_head(placing: _Placement) -> None:
    """Head pass: the skull base behind and below the HMD (or at 0.87 H), the head bone's tip above
    it."""
    session, body, w, H, put = placing.session, placing.body, placing.world, placing.H, placing.put
    if "skull_base" not in w:
        if session.has("head"):
            put("skull_base", skull_base_under_hmd(session, body.forward, H),
                f"{R['skull_base_back']} H behind and {R['skull_base_down']} H below the HMD")
        else:
            put("skull_base", body.at(0.87 * H), "0.87 H above the floor")
    put("head", w["skull_base"] + UP * R["head_above_skull_base"] * H,
        f"{R['head_above_skull_base']} H above the skull base (the head bone's tip)")


def skull_base_under_hmd(session: Session, forward: np.ndarray, H: float) -> np.ndarray:
    """The skull base's default: behind (against `forward`) and below the HMD's origin (the eyes)
    at the reference time, for a body of stature `H`."""
    p = session.ref_pose("head")[0]
    return p - forward * R["skull_base_back"] * H - UP * R["skull_base_down"] * H


def _place_fingers(placing: _Placement) -> None:
    """Fingers pass, side by side, finger by finger: mcp and tip from `FINGER_LAYOUT` along the hand
    (`hand_axes`), pip and dip at the phalanx fractions between them. Needs the wrists."""
    w, H, put = placing.world, placing.H, placing.put
    for s in sk.SIDES:
        along, palm_n, thumb = hand_axes(placing.session, placing.state, placing.body, s, w)
        for f, (a, c, length) in FINGER_LAYOUT.items():
            mcp = w[f"wrist_{s}"] + along * a * H + thumb * c * H
            put(f"mcp_{f}_{s}", mcp, "hand layout ratios of the stature")
            direction = along if f != "thumb" else (along + thumb) / np.linalg.norm(along + thumb)
            put(f"tip_{f}_{s}", w[f"mcp_{f}_{s}"] + direction * length * H, "finger length ratio of the stature")

            fa, fb = PHALANX_FRACTIONS[f]
            m, t = w[f"mcp_{f}_{s}"], w[f"tip_{f}_{s}"]
            put(f"pip_{f}_{s}", m + fa * (t - m), "phalanx fractions")
            put(f"dip_{f}_{s}", m + fb * (t - m), "phalanx fractions")


def _relaxed_mid(session: Session, state: State, root, effector, l1: float, l2: float, hinge_bone: str):
    """A hinge joint the recording does not measure, at the reference time: on the root-effector
    line in the ratio l1 : l2, moved off it as a limb bent by R["reference_bend_deg"] is, toward
    the side the measured hinge axis gives (a flex step seen through the hand / foot device, limbs.py);
    on the line when no axis was measured. A standing person's elbows and knees are not locked
    straight: 2-10° in a T-pose (the CMU subjects' walks never straighten them past 2°)."""
    root, effector = np.asarray(root, float), np.asarray(effector, float)
    d = effector - root
    mid = root + l1 / max(l1 + l2, 1e-9) * d
    hinge = state.hinge_right.get(hinge_bone)
    if hinge is None:
        return mid
    right = tf.rotate(session.ref_pose(hinge[0])[1], hinge[1])
    away = np.cross(d, right)  # a positive turn about +right flexes: the joint sits on this side
    away -= (away @ d) / max(d @ d, EPS) * d
    n = np.linalg.norm(away)
    if n < 1e-9:
        return mid
    bend = np.radians(R["reference_bend_deg"])
    offset = l1 * l2 * np.sin(bend) / max(np.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * np.cos(bend)), 1e-9)
    return mid + away / n * offset


def hand_axes(session: Session, state: State, body: BodyFrame, s: str, w: dict) -> tuple:
    """(along the hand toward the fingers, palm normal out of the palm, toward the thumb), world."""
    plane = state.palm_planes.get(f"hand_{s}")
    sign = 1.0 if s == "l" else -1.0
    if f"mcp_middle_{s}" in w and f"wrist_{s}" in w:
        along = w[f"mcp_middle_{s}"] - w[f"wrist_{s}"]
    elif session.reference_step == "tpose":
        along = body.left * sign
    elif session.has(f"hand_{s}") and f"wrist_{s}" in w:
        # the fist's centre is along the hand from the wrist (`_place_wrist` put the wrist in from the
        # grip): with the controllers held wherever the reference moment found them, a hand hanging
        # down held the controller across its fingers, and the avatar's hand turned that way on it
        along = session.ref_pose(f"hand_{s}")[0] - w[f"wrist_{s}"]
    else:
        along = -UP
    along = along / max(np.linalg.norm(along), 1e-9)
    if plane is not None and session.has(f"hand_{s}"):
        q = session.ref_pose(f"hand_{s}")[1]
        n = tf.rotate(q, plane[1])
    elif session.reference_step == "tpose":
        n = -UP
    else:
        n = -body.left * sign
    n = n - (n @ along) * along
    n = n / max(np.linalg.norm(n), 1e-9)
    # thumb side: palm down with the fingers pointing away from the body, the thumb is forward.
    # Decision: the thumb follows from the palm's normal and the hand's direction by the side's
    # handedness, and nothing turns it alone: a thumb turned forward without its palm made the hand
    # its mirror image (the palm mesh on the back of the hand) wherever the hand pointed up, or
    # forward with the palm toward the body, at the reference moment (a real Beat Saber replay's two
    # hands, an A-Frame take's left one). In a T-pose or hanging down the thumb is forward anyway.
    thumb = np.cross(n, along) * sign
    return along, n, thumb


def default_radii(state: State, body: BodyFrame, session: Session) -> None:
    H = body.stature
    for s in sk.SIDES:
        for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"):
            if f"{j}_{s}" not in state.radii:
                state.radii[f"{j}_{s}"] = RADII[j] * H
                session.default(f"radius {j}_{s}", f"{RADII[j]} H")
        for f in sk.FINGERS:
            if f"finger_{f}_{s}" not in state.radii:
                state.radii[f"finger_{f}_{s}"] = RADII["finger"] * H
                session.default(f"radius finger_{f}_{s}", f"{RADII['finger']} H")
