"""The review of a bake (DESIGN.md §7 "Review", FORMATS.md §4.5): the figures an animator would
scrub the result for, over the whole take, each against the limit its benchmark holds it to, and
the frames that matter (the worst contact gap, the lowest foot skin, the largest foot slide, the
largest wrist acceleration, the take's middle). Numpy only; Blender measures the evaluated mesh at
the few frames this module asks for (blender/review.py) and draws the sheet.

Every figure is `metrics`' (DESIGN.md §7), the benchmarks' own, with their limits:
- contact gap: the source's self-contacts found on the source (its palm's skin within
  CONTACT_MM of its own body, the elements of its own arm left out: `metrics.contact_gap`), and
  in those frames the avatar's palm to the touched element of its calibrated body model
  (`metrics.model_contact_gaps`, bench_retarget_quality's second figure); flagged past
  `metrics.CONTACT_GAP_P95_MM` (p95 of |gap|). The worst frame's gap is measured on the touched
  part's evaluated skin too (`mesh_metrics.contact_gaps`' `against="target"`: the sheet's label);
- foot skin: the lowest skin of each foot on the evaluated mesh (`mesh_metrics.foot_skin`, as
  bench_real_motion) at the frames where the avatar's sole points (its body model's outline and
  contact points, `metrics.foot_points`) are lowest; flagged below `metrics.FOOT_SKIN_LOWEST_MM`;
- foot slide: the avatar's heel and ball contact points while the source's heel (ankle), resp.
  ball (toe), is on the ground (`metrics.ground_contact`), p95 in mm per 90 Hz frame
  (`metrics.slide_p95_mm`) against the source's own scaled like the legs; flagged past
  `metrics.SLIDE_RATIO` times it and `metrics.SLIDE_P95_MM` both (a source that hardly slides
  would make any slide a large ratio); without a source, the avatar's own planted frames
  (`metrics.planted_frames`) and the absolute limit alone;
- wrist / ankle acceleration: p95 (`metrics.acceleration_p95`) against the source's scaled the
  way the method scales motion (`metrics.motion_scale`); flagged past `metrics.ACCEL_RATIO`.

A bake whose check on the evaluated rig failed (blender/bake_check.py) has no animation to review:
it is one flag, `verification`, and comes first wherever reviews are listed (`severity`).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from ..body import naming
from ..body import skeleton as sk
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints, model_rest_frames
from ..retarget.avatar_pose import AvatarRig
from ..retarget.egocentric import pose_surface
from ..retarget.offsets import eye_height
from ..retarget.placement import floor_height, play_area_to_world, rest_heading
from ..retarget.solver_methods import surface_bones, surface_correction
from . import metrics

FORMAT = "bodycal-review"
VERSION = 1
CONTACT_MM = 10.0  # the source touches its own body where its palm's skin is this close to it
MIN_CONTACT_FRAMES = 2  # shorter runs of contact frames are noise, not a touch
SKIN_CANDIDATES = 4  # per foot: the frames the evaluated mesh's foot skin is measured at
CHUNK = 2000  # frames posed at once (the pipeline's chunk)
PLOT_POINTS = 800  # a series is thinned to about this many points for the plots (its extremes kept)
# The source's stick figure on the sheet: its canonical bones between these joints.
GHOST_BONES = tuple((b.head, b.tail) for b in sk.BONES if not b.shortcut and b.name.split("_")[0] not in
                    (*sk.FINGERS, "metacarpal", "breast"))
GHOST_JOINTS = tuple(sorted({j for pair in GHOST_BONES for j in pair}, key=sk.JOINT_INDEX.get))
VERIFICATION = 1e9  # a failed verification's `excess`: past every other flag
SHEET_FRAMES = ("worst contact gap", "lowest foot skin", "largest foot slide", "largest wrist acceleration",
                "middle of the take")


@dataclass
class Flag:
    """One figure of the review against its limit."""

    name: str  # "contact gap", "foot skin", "foot slide", "wrist acceleration", "ankle acceleration", "verification"
    value: float | None  # in `unit`; None: not measured (said in `text`)
    limit: float | None
    unit: str
    over: bool  # past the limit: red
    frame: float | None  # the scene frame to look at
    text: str  # one line, what the sidebar and the page show
    excess: float = 0.0  # how far past the limit (value over limit; > 1 is over): the page's order

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class SheetFrame:
    title: str  # one of SHEET_FRAMES
    index: int  # the animation's frame
    frame: float  # the scene frame
    label: str  # the figure there


@dataclass
class Review:
    """The review of one bake: its flags (worst first), the sheet's frames and the plots' series."""

    flags: list[Flag]
    frames: list[SheetFrame] = field(default_factory=list)
    series: dict = field(default_factory=dict)  # what the plots draw (lists, JSON-able)
    source: str | None = None  # "recording", "animation" or None (the review command without --source)
    figures: dict[str, float] = field(default_factory=dict)  # the bake's own (Summary.figures, mm)
    notes: list[str] = field(default_factory=list)

    @property
    def over(self) -> list[Flag]:
        return [f for f in self.flags if f.over]

    def severity(self) -> tuple:
        """Sort key, worst first: a failed verification, then the most flags past their limits,
        then how far past."""
        failed = any(f.name == "verification" and f.over for f in self.flags)
        worst = max((f.excess for f in self.flags), default=0.0)
        return (not failed, -len(self.over), -worst)

    def to_dict(self) -> dict:
        return {"source": self.source, "figures": self.figures, "flags": [f.to_dict() for f in self.flags],
                "sheet_frames": [asdict(f) for f in self.frames], "notes": self.notes, "series": self.series}

    @classmethod
    def from_dict(cls, data: dict) -> Review:
        return cls([Flag(**f) for f in data.get("flags", [])], [SheetFrame(**f) for f in data.get("sheet_frames", [])],
                   data.get("series", {}), data.get("source"), data.get("figures", {}), data.get("notes", []))


def verification_failed(line: str) -> Review:
    """The review of a bake its check on the evaluated rig refused: one flag, first everywhere."""
    return Review([Flag("verification", None, None, "", True, None, f"verification failed: {line}", VERIFICATION)])


# --- the source's side ------------------------------------------------------------------------------------


@dataclass
class SourceMotion:
    """What the review reads of the source (the performer from the trackers, or the source
    character), at the animation's frames, in the avatar's world."""

    joints: dict[str, np.ndarray]  # GHOST_JOINTS (and the toes) -> (F, 3)
    contacts: list[dict]  # {"effector", "target", "frames" (F,) bool, "gap" (F,) the source's, m}
    scale: dict[str, float]  # metrics.motion_scale: the source's wrist / ankle motion as the avatar's
    kind: str  # "recording" or "animation"

    def at(self, samples) -> SourceMotion:
        """The source at these of its samples (the animation's frames, when the bake resampled it)."""
        idx = np.asarray(samples, int)
        contacts = [dict(c, frames=_without_short_runs(c["frames"][idx], MIN_CONTACT_FRAMES), gap=c["gap"][idx])
                    for c in self.contacts]
        return SourceMotion({j: v[idx] for j, v in self.joints.items()}, [c for c in contacts if c["frames"].any()],
                            dict(self.scale), self.kind)


def source_motion(source, avatar: BodyModel, method: str, placement: str = "object") -> SourceMotion:
    """The source's joints and self-contacts over the take (`source`: retarget/pose_source.py's,
    the one the bake was computed from), brought into the avatar's world as the bake's placement
    brings the performance (`placement.play_area_to_world`)."""
    model = source.model
    pos = complete_joints(model)
    frames0 = model_rest_frames(model, pos)
    corr = surface_correction(model, frames0, pos)
    surface = surface_bones(model)
    to_world = play_area_to_world(avatar, placement)
    nf = source.frame_count
    keep = {j: np.empty((nf, 3)) for j in GHOST_JOINTS}
    effectors = {s: _effector(model, s) for s in sk.SIDES}
    gaps = {s: np.full(nf, np.nan) for s in sk.SIDES}
    nearest = {s: np.full(nf, -1) for s in sk.SIDES}
    ids = [e.id for e in model.surface]
    for a in range(0, nf, CHUNK):
        b = min(nf, a + CHUNK)
        up = source.pose(a, b, rest=(pos, frames0))
        bone_frames = up.frames if up.surface_frames is None else up.surface_frames
        joints = {j: up.joints[:, i] for i, j in enumerate(sk.JOINTS)}
        for j in keep:
            keep[j][a:b] = joints[j] @ to_world[:3, :3].T + to_world[:3, 3]
        if not ids:
            continue
        frames = {bone.name: bone_frames[:, i] @ corr[i] for i, bone in enumerate(sk.BONES)}
        surf = pose_surface(surface, joints, frames)
        points = np.stack([_effector_point(model, joints, frames, effectors[s]) for s in sk.SIDES], axis=1)
        gap, element = metrics.nearest_contact(points, surf, [f"wrist_{s}" for s in sk.SIDES])
        for k, s in enumerate(sk.SIDES):
            gaps[s][a:b], nearest[s][a:b] = gap[:, k] - effectors[s][1], element[:, k]
    element_ids = surf.element_ids if ids else []
    contacts = []
    for s in sk.SIDES:
        touching = np.abs(np.nan_to_num(gaps[s], nan=np.inf)) <= CONTACT_MM / 1000.0
        for e in np.unique(nearest[s][touching]):
            frames = _without_short_runs(touching & (nearest[s] == e), MIN_CONTACT_FRAMES)
            if frames.any():
                contacts.append({"effector": effectors[s][0], "target": element_ids[int(e)], "frames": frames,
                                 "gap": np.where(frames, gaps[s], np.nan)})
    rig_like = AvatarRig.from_model(avatar)
    limb = metrics.limb_ratios(rig_like, pos)
    scale = metrics.motion_scale(method, limb, eye_height(avatar) / max(eye_height(model), 1e-9))
    return SourceMotion(keep, contacts, scale, "animation" if source.character else "recording")


def _effector(model: BodyModel, side: str) -> tuple[str, float]:
    """The source's effector on side `side` and its skin offset: the palm's centre (on the skin),
    else the wrist (inside the limb, its radius deep)."""
    if any(e.id == f"mesh:palm_{side}" for e in model.surface):
        return f"palm_{side}", 0.0
    bone = model.bones.get(f"forearm_{side}")
    return f"wrist_{side}", float(getattr(bone, "radius_tail", None) or 0.0)


def _effector_point(model: BodyModel, joints: dict, frames: dict, effector: tuple[str, float]) -> np.ndarray:
    name, _ = effector
    side = name[-1]
    wrist = joints[f"wrist_{side}"]
    if not name.startswith("palm_"):
        return wrist
    el = model.element(f"mesh:palm_{side}")
    local = np.mean([p.local for p in el.points.values()], axis=0)
    return wrist + frames[f"hand_{side}"] @ local


def _without_short_runs(mask: np.ndarray, shortest: int) -> np.ndarray:
    """`mask` without its runs of True shorter than `shortest` frames."""
    out = mask.copy()
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    for start, stop in zip(edges[::2], edges[1::2]):
        if stop - start < shortest:
            out[start:stop] = False
    return out


# --- the avatar's side and the plan -----------------------------------------------------------------------


@dataclass
class ReviewPlan:
    """The review's figures over the take, before the evaluated mesh is measured: what Blender
    measures at the frames it asks for (`skin_frames`; the worst contact's point), then `conclude`."""

    scene_frames: np.ndarray  # (F,) the scene frame of every animation frame
    fps: float  # the animation's samples per second
    floor: float  # the avatar's floor (world z)
    series: dict  # the plots' data, full length (numpy)
    figures: dict  # name -> value
    picks: dict  # SHEET_FRAMES title -> (animation frame, label) known before the mesh
    skin_frames: dict[str, np.ndarray]  # side -> animation frames to measure the foot skin at
    contact_point: tuple | None  # (animation frame, effector, target, world point (3,), skin offset): the worst
    source: SourceMotion | None
    forward: np.ndarray  # (3,) the way the avatar faces over the take: the sheet's camera looks from there
    height: float  # m, the avatar standing: the sheet's scale
    pelvis_bone: str | None  # the armature's pelvis bone: the sheet's camera follows it
    bake_figures: dict[str, float] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def ghost(self, index: int) -> dict[str, np.ndarray] | None:
        """The source's joints at an animation frame (the sheet's stick figure), None without a source."""
        if self.source is None:
            return None
        return {j: v[index] for j, v in self.source.joints.items()}

    def conclude(self, skin: dict[str, np.ndarray] | None, contact_skin_gap: float | None = None) -> Review:
        """The review, once Blender measured the evaluated mesh: `skin` side -> (n,) the lowest foot
        skin (world z) at `skin_frames[side]` (None: no mesh); `contact_skin_gap` the worst contact's
        gap on the skin (m)."""
        flags, picks = [], dict(self.picks)
        frame_of = self.scene_frames
        fig = self.figures
        # contact gap
        if "contact_p95" in fig:
            p95, worst = fig["contact_p95"], self.contact_point
            over = p95 > metrics.CONTACT_GAP_P95_MM
            what = f"{part_name(worst[1])} on {part_name(worst[2])}" if worst else ""
            flags.append(Flag("contact gap", p95, metrics.CONTACT_GAP_P95_MM, "mm", over,
                              float(frame_of[worst[0]]) if worst else None,
                              f"contact gap p95 {p95:.1f} mm (limit {metrics.CONTACT_GAP_P95_MM:g}), worst "
                              f"{fig['contact_worst']:.1f} mm: {what}", p95 / metrics.CONTACT_GAP_P95_MM))
            if worst:
                on_skin = "" if contact_skin_gap is None else f" (skin {contact_skin_gap * 1000:.1f})"
                picks["worst contact gap"] = (worst[0], f"{what}: {fig['contact_worst']:.1f} mm{on_skin}")
        elif self.source is not None:
            flags.append(Flag("contact gap", None, metrics.CONTACT_GAP_P95_MM, "mm", False, None,
                              "contact gap: the source never touches its own body"))
        # foot skin
        series = self.series
        if skin:
            lows = {s: (np.asarray(v, float) - self.floor) * 1000.0 for s, v in skin.items()}
            series["skin"] = {s: (self.skin_frames[s], lows[s]) for s in lows}
            side, k = min(((s, int(np.nanargmin(v))) for s, v in lows.items() if np.isfinite(v).any()),
                          key=lambda sk_: lows[sk_[0]][sk_[1]], default=(None, None))
            if side is not None:
                low = float(lows[side][k])
                index = int(self.skin_frames[side][k])
                limit = metrics.FOOT_SKIN_LOWEST_MM
                flags.append(Flag("foot skin", low, limit, "mm", low < limit, float(frame_of[index]),
                                  f"lowest foot skin {low:.1f} mm ({_side(side)} foot; limit {limit:g})",
                                  low / limit if low < 0 else 0.0))
                picks["lowest foot skin"] = (index, f"{_side(side)} foot skin {low:.1f} mm")
        # slide and acceleration (figures made in `plan`)
        flags += self._slide_flag() + self._accel_flags()
        frames = [SheetFrame(title, int(picks[title][0]), float(frame_of[picks[title][0]]), picks[title][1])
                  for title in SHEET_FRAMES if title in picks]
        flags.sort(key=lambda f: (not f.over, -f.excess))
        return Review(flags, frames, _plot_series(series, self.scene_frames),
                      None if self.source is None else self.source.kind,
                      {k: round(float(v), 3) for k, v in self.bake_figures.items()}, list(self.notes))

    def _slide_flag(self) -> list[Flag]:
        fig = self.figures
        if "slide_p95" not in fig:
            return []
        p95, ratio = fig["slide_p95"], fig.get("slide_ratio")
        over = p95 > metrics.SLIDE_P95_MM and (ratio is None or ratio > metrics.SLIDE_RATIO)
        vs = "" if ratio is None else f", {ratio:.2f}x the source's (limit {metrics.SLIDE_RATIO:g}x)"
        excess = p95 / metrics.SLIDE_P95_MM if ratio is None else min(p95 / metrics.SLIDE_P95_MM,
                                                                      ratio / metrics.SLIDE_RATIO)
        return [Flag("foot slide", p95, metrics.SLIDE_P95_MM, "mm", over, float(self.scene_frames[fig["slide_at"]]),
                     f"foot slide p95 {p95:.2f} mm a 90 Hz frame ({fig['slide_where']}; limit "
                     f"{metrics.SLIDE_P95_MM:g}){vs}", excess)]

    def _accel_flags(self) -> list[Flag]:
        out = []
        for joint in ("wrist", "ankle"):
            ratio = self.figures.get(f"{joint}_accel_ratio")
            at = self.figures.get(f"{joint}_accel_at")
            if ratio is None:
                continue
            mine = self.figures[f"{joint}_accel_p95"]
            if not np.isfinite(ratio):
                out.append(Flag(f"{joint} acceleration", mine, None, "m/s²", False, float(self.scene_frames[at]),
                                f"{joint} acceleration p95 {mine:.0f} m/s² (no source to compare with)"))
                continue
            limit = metrics.ACCEL_RATIO
            out.append(Flag(f"{joint} acceleration", ratio, limit, "x source", ratio > limit,
                            float(self.scene_frames[at]), f"{joint} acceleration p95 {ratio:.2f}x the source's "
                            f"(limit {limit:g}x; {mine:.0f} m/s²)", ratio / limit))
        return out


def plan(anim: AvatarAnimation, avatar: BodyModel, source: SourceMotion | None, frame_start: float, rate: float,
         bake_figures: dict | None = None) -> ReviewPlan:
    """The review's figures of a computed animation (its engine values: `rotations`,
    `root_location`, `joints_world`) on `avatar` (the model the bake used), against the source's
    (`source_motion`, None: the avatar alone). `frame_start` and `rate`: where the bake keys sample
    k (`frame_start + (t_k - t_0) x rate`)."""
    nf = anim.frame_count
    time = np.asarray(anim.time, float)
    fps = 1.0 / float(np.median(np.diff(time))) if nf > 1 else rate
    scene_frames = frame_start + (time - time[0]) * rate
    rig = AvatarRig.from_model(avatar)
    floor = floor_height(avatar)
    contacts = source.contacts if source is not None else []
    usable = [c for c in contacts if _has_element(avatar, c["target"])]
    feet = {s: {"outline": np.empty(nf), "heel": np.empty((nf, 3)), "ball": np.empty((nf, 3))} for s in sk.SIDES
            if _has_element(avatar, f"mesh:sole_{s}")}
    gaps = [np.full(nf, np.nan) for _ in usable]
    points = [np.full((nf, 3), np.nan) for _ in usable]
    offsets = [0.0] * len(usable)
    for a in range(0, nf, CHUNK):
        b = min(nf, a + CHUNK)
        pose = rig.fk(anim.rotations[a:b], anim.root_location[a:b], locations=_locations(rig, anim, a, b))
        for s, out in feet.items():
            fp = metrics.foot_points(avatar, rig, pose, s)
            out["outline"][a:b] = np.concatenate([fp["outline"], fp["support"]], axis=1)[..., 2].min(axis=1)
            out["heel"][a:b], out["ball"][a:b] = fp["heel"], fp["ball"]
        for k, c in enumerate(usable):
            idx = np.flatnonzero(c["frames"][a:b])
            if idx.size:
                effector = _avatar_effector(avatar, c["effector"])
                joints = {j: anim.joints_world[j][a:b] for j in anim.joints_world}
                g, p, off = metrics.posed_contact_gaps(avatar, rig, pose, effector, c["target"], idx, joints)
                gaps[k][a + idx], points[k][a + idx], offsets[k] = g, p, off
    series: dict = {"contact": [], "sole": {}, "slide": {}, "accel": {}}
    figures: dict = {}
    picks: dict = {"middle of the take": (nf // 2, "")}
    contact_point = None
    if usable:
        pooled = np.concatenate([g[np.isfinite(g)] for g in gaps])
        stats = metrics.stats_mm(pooled)
        figures["contact_p95"], figures["contact_worst"] = stats["p95"], stats["max"]
        worst = max(range(len(usable)), key=lambda k: np.nanmax(np.abs(gaps[k])))
        i = int(np.nanargmax(np.abs(gaps[worst])))
        c = usable[worst]
        contact_point = (i, c["effector"], c["target"], points[worst][i], offsets[worst])
        for k, c in enumerate(usable):
            series["contact"].append({"pair": f"{part_name(c['effector'])} on {part_name(c['target'])}",
                                      "avatar": gaps[k] * 1000.0, "source": c["gap"] * 1000.0})
    skin_frames = {}
    for s, out in feet.items():
        height = (out["outline"] - floor) * 1000.0
        series["sole"][s] = height
        skin_frames[s] = _lowest_frames(height, SKIN_CANDIDATES, max(1, int(round(0.25 * fps))))
    _slides(series, figures, feet, source, fps, nf)
    _accelerations(series, figures, anim, source, fps)
    if "slide_at" in figures:
        picks["largest foot slide"] = (figures["slide_at"], f"{figures['slide_where']}: "
                                       f"{figures['slide_max']:.1f} mm a 90 Hz frame")
    if "wrist_accel_at" in figures:
        i = figures["wrist_accel_at"]
        picks["largest wrist acceleration"] = (i, f"{figures['wrist_accel_side']} wrist "
                                               f"{figures['wrist_accel_max']:.0f} m/s²")
    picks["middle of the take"] = (nf // 2, f"{time[nf // 2] - time[0]:.1f} s of {time[-1] - time[0]:.1f} s")
    notes = [] if source is not None else ["no source given: contact gaps are not measured, slides and "
                                           "accelerations not compared"]
    pos = complete_joints(avatar)
    height = float(max(p[2] for p in pos.values()) - floor)
    pelvis_bone = naming.BoneMap.from_dict(avatar.extra["rig"].get("bone_map", {})).bones.get("pelvis")
    return ReviewPlan(np.round(scene_frames, 4), fps, floor, series, figures, picks, skin_frames, contact_point,
                      source, _facing(anim, avatar), max(height, 0.3), pelvis_bone, dict(bake_figures or {}), notes)


def _facing(anim: AvatarAnimation, avatar: BodyModel) -> np.ndarray:
    """(3,) the floor direction the avatar faces on average over the take (its hip line, right to
    left, turned a quarter about the vertical); its rest heading when the hips are not known."""
    if "hip_l" in anim.joints_world and "hip_r" in anim.joints_world:
        lateral = np.nanmean(np.asarray(anim.joints_world["hip_l"], float)
                             - np.asarray(anim.joints_world["hip_r"], float), axis=0)
        lateral[2] = 0.0
        n = np.linalg.norm(lateral)
        if np.isfinite(n) and n > 1e-6:
            return np.array([lateral[1], -lateral[0], 0.0]) / n
    return rest_heading(avatar)


PART_NAMES = {"skull": "head", "jaw": "jaw", "torso": "torso", "upperarm": "upper arm", "forearm": "forearm",
              "thigh": "thigh", "shin": "shin", "palm": "palm", "sole": "sole", "wrist": "wrist"}


def part_name(name: str) -> str:
    """A body part as the sheet says it: "palm_r" -> "right palm", "mesh:torso/belly_c2" -> "torso",
    "capsule:upperarm_l" -> "left upper arm"."""
    base = name.split("/", 1)[0].split(":", 1)[-1]
    parts = base.split("_")
    side = {"l": "left ", "r": "right "}.get(parts[-1], "") if len(parts) > 1 else ""
    core = "_".join(parts[:-1]) if side else base
    return side + PART_NAMES.get(core, core.replace("_", " "))


def _locations(rig: AvatarRig, anim: AvatarAnimation, a: int, b: int) -> np.ndarray | None:
    """(b - a, N, 3) every rig bone's pose location when bones other than the root carry one (an
    output's root bone under root motion, read back: `blender/review.played_animation`), else None."""
    if not anim.bone_locations:
        return None
    index = {n: i for i, n in enumerate(rig.names)}
    out = np.zeros((b - a, len(rig.names), 3))
    out[:, rig.root] = anim.root_location[a:b]
    for name, loc in anim.bone_locations.items():
        if name in index:
            out[:, index[name]] = np.asarray(loc)[a:b]
    return out


def _side(s: str) -> str:
    return {"l": "left", "r": "right"}[s]


def _has_element(model: BodyModel, element: str) -> bool:
    eid = element.split("/", 1)[0]
    return any(e.id == eid for e in model.surface)


def _avatar_effector(avatar: BodyModel, effector: str) -> str:
    """The source's effector as this avatar can show it: a palm by its wrist on an avatar without a
    palm (no fingers), as bench_avatars measures it."""
    if effector.startswith("palm_") and not _has_element(avatar, f"mesh:{effector}"):
        return f"wrist_{effector[-1]}"
    return effector


def _lowest_frames(height: np.ndarray, count: int, apart: int) -> np.ndarray:
    """Up to `count` frames where `height` is lowest, at least `apart` frames from each other."""
    order = np.argsort(np.nan_to_num(height, nan=np.inf), kind="stable")
    chosen: list[int] = []
    for i in order:
        if not np.isfinite(height[i]):
            break
        if all(abs(int(i) - j) >= apart for j in chosen):
            chosen.append(int(i))
            if len(chosen) == count:
                break
    return np.array(sorted(chosen), int)


def _slides(series, figures, feet, source, fps, nf) -> None:
    worst = (-1.0, None, None)
    mine, theirs = [], []
    for s, out in feet.items():
        for part, joint in (("heel", "ankle"), ("ball", "toe")):
            if source is not None:
                down = metrics.ground_contact(source.joints[f"{joint}_{s}"], fps)
                src = metrics.slide_p95_mm(source.joints[f"{joint}_{s}"], down, fps)
            else:
                down = metrics.planted_frames(out[part], dt=1.0 / fps)
                src = None
            steps = metrics.slide_steps_mm(out[part], down, fps)
            series["slide"][f"{part}_{s}"] = steps
            p95 = metrics.slide_p95_mm(out[part], down, fps)
            if p95 is None:
                continue
            mine.append(p95)
            if src is not None:
                theirs.append(src * (source.scale["ankle"] if source else 1.0))
            if np.isfinite(steps).any() and np.nanmax(steps) > worst[0]:
                worst = (float(np.nanmax(steps)), int(np.nanargmax(steps)) + 1, f"{_side(s)} {part}")
    if not mine:
        return
    figures["slide_p95"] = max(mine)
    if theirs:
        figures["slide_ratio"] = max(mine) / max(max(theirs), 1e-6)
        series["slide_source_p95"] = max(theirs)
    figures["slide_max"], figures["slide_at"], figures["slide_where"] = worst


def _accelerations(series, figures, anim, source, fps) -> None:
    for joint in ("wrist", "ankle"):
        ratios, best = [], (-1.0, None, None)
        for s in sk.SIDES:
            name = f"{joint}_{s}"
            if name not in anim.joints_world:
                continue
            a = metrics.acceleration(anim.joints_world[name], fps)
            mine = metrics.acceleration_p95(anim.joints_world[name], fps)
            entry = {"avatar": a}
            if source is not None and name in source.joints:
                k = source.scale[joint]
                entry["source"] = metrics.acceleration(source.joints[name], fps) * k
                ratios.append(mine / max(metrics.acceleration_p95(source.joints[name], fps) * k, 1e-9))
            series["accel"][name] = entry
            figures[f"{joint}_accel_p95"] = max(figures.get(f"{joint}_accel_p95", 0.0), mine)
            if np.isfinite(a).any() and np.nanmax(a) > best[0]:
                best = (float(np.nanmax(a)), int(np.nanargmax(a)), _side(s))
        if best[1] is None:
            continue
        figures[f"{joint}_accel_ratio"] = max(ratios) if ratios else math.nan
        figures[f"{joint}_accel_max"], figures[f"{joint}_accel_at"], figures[f"{joint}_accel_side"] = best


def _thin(values: np.ndarray, points: int = PLOT_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(indices, values) of a series thinned to about `points` for a plot: each block's lowest and
    highest kept (in their order), so a spike still shows."""
    v = np.asarray(values, float)
    n = len(v)
    if n <= points:
        return np.arange(n), v
    block = int(np.ceil(2 * n / points))
    blocks = -(-n // block)
    padded = np.full(blocks * block, np.nan)
    padded[:n] = v
    rows = padded.reshape(blocks, block)
    filled = np.where(np.isfinite(rows), rows, np.inf)
    low = filled.argmin(axis=1)
    high = np.where(np.isfinite(rows), rows, -np.inf).argmax(axis=1)
    idx = np.sort(np.stack([low, high], axis=1), axis=1) + (np.arange(blocks) * block)[:, None]
    idx = np.minimum(idx.ravel(), n - 1)
    return idx, v[idx]


def _plot_series(series: dict, scene_frames: np.ndarray) -> dict:
    """The plots' data as JSON-able lists: [scene frames], [values] per line (thinned), NaN as None."""

    def line(values, frames=None):
        if frames is None:
            idx, v = _thin(values)
            f = scene_frames[idx]
        else:
            f, v = scene_frames[np.asarray(frames, int)], np.asarray(values, float)
        return [[round(float(x), 3) for x in f], [None if not np.isfinite(y) else round(float(y), 3) for y in v]]

    out: dict = {"contact": [{"pair": c["pair"], "avatar": line(c["avatar"]), "source": line(c["source"])}
                             for c in series.get("contact", [])],
                 "sole": {s: line(v) for s, v in series.get("sole", {}).items()},
                 "skin": {s: line(v, frames) for s, (frames, v) in series.get("skin", {}).items()},
                 "slide": {k: line(np.concatenate([[np.nan], v])) for k, v in series.get("slide", {}).items()},
                 "accel": {j: {who: line(v) for who, v in e.items()} for j, e in series.get("accel", {}).items()}}
    if "slide_source_p95" in series:
        out["slide_source_p95"] = round(float(series["slide_source_p95"]), 3)
    return out
