"""Robust geometric fits for the user calibration (DESIGN.md §3; Delahaye 2023, appendix B).

- `fit_plane`: centroid + principal directions of the centred scatter matrix (the two largest
  eigenvalues span the plane, the third eigenvector is the normal).
- `fit_circle`: plane fit, projection, algebraic (Kåsa) circle fit in 2D refined to the geometric
  least squares; second pass without the points farther than 2 standard deviations from the mean
  distance to the centre (Delahaye 2023, appendix B, "Intermediate Joint and Bone Calibration").
- `fit_sphere`: algebraic least-squares sphere refined the same way, same 2-sigma second pass;
  radius = mean distance to the centre ("Anchor Joint and Bone Calibration").

Every fit reports its residual RMS, the points kept / used and a conditioning figure, and
raises `BodyCalError` naming the step and what to redo when the data cannot determine the fit
(too few points, too little motion, points nearly on a line or in a plane).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from .errors import BodyCalError
from .transforms import EPS, matrix_to_quat, quat_angle, quat_conj, quat_mul, quat_normalize

MIN_ARC_DEG = 40.0  # circle: arc a hinge must sweep for its axis to be trusted
MIN_SWING_DEG = 40.0  # sphere: main swing of an anchor joint
MIN_SWING_MINOR_DEG = 15.0  # sphere: the swing across it (an arc alone leaves the centre free along its axis)
COLLINEAR = 1e-3  # sqrt(λ2/λ1) below this: points on a line
RESIDUAL_GATE = 0.25  # a circle / sphere whose residual RMS exceeds this fraction of its radius is rejected


@dataclass
class Fit:
    """Common fields of every fit. `rms` is in metres; `inliers` marks the points kept (of the
    finite points given); `conditioning` is in [0, 1] (0: degenerate)."""

    kind: str
    rms: float
    kept: int
    of: int
    conditioning: float
    inliers: np.ndarray = field(repr=False)
    range_deg: float | None = None

    def quality(self) -> dict:
        q = {"rms_mm": round(self.rms * 1000.0, 3), "kept": int(self.kept), "of": int(self.of),
             "conditioning": round(float(self.conditioning), 4)}
        if self.range_deg is not None:
            q["range_deg"] = round(float(self.range_deg), 1)
        return q


@dataclass
class PlaneFit(Fit):
    point: np.ndarray = None  # centroid
    normal: np.ndarray = None
    axes: np.ndarray = None  # (2, 3) in-plane principal directions, largest first

    def project(self, p: np.ndarray) -> np.ndarray:
        p = np.asarray(p, float)
        return p - ((p - self.point) @ self.normal)[..., None] * self.normal

    def distance(self, p: np.ndarray) -> np.ndarray:
        """Signed distance along `normal`."""
        return (np.asarray(p, float) - self.point) @ self.normal


@dataclass
class CircleFit(Fit):
    center: np.ndarray = None
    normal: np.ndarray = None  # the plane's normal: for a hinge, its axis (sign not meaningful yet)
    radius: float = 0.0


@dataclass
class SphereFit(Fit):
    center: np.ndarray = None
    radius: float = 0.0


def _clean(points, name: str, minimum: int) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(points, float).reshape(-1, 3)
    finite = np.all(np.isfinite(p), axis=1)
    p = p[finite]
    if len(p) < minimum:
        raise BodyCalError(f"only {len(p)} usable points, at least {minimum} needed", source=name,
                           hint="record the step again with the trackers visible")
    return p, finite


def _principal(p: np.ndarray):
    c = p.mean(axis=0)
    d = p - c
    w, v = np.linalg.eigh(d.T @ d / max(len(p), 1))
    order = np.argsort(w)[::-1]
    return c, np.maximum(w[order], 0.0), v[:, order].T  # eigenvalues, eigenvectors as rows, largest first


def fit_plane(points, *, name: str = "plane") -> PlaneFit:
    """Least-squares plane; `conditioning` = sqrt(λ2 / λ1): how far the points are from a line."""
    p, _ = _clean(points, name, 3)
    c, w, v = _principal(p)
    scale = np.sqrt(w[0])
    if scale < 1e-9:
        raise BodyCalError("all points are at the same place", source=name, hint="move while recording")
    cond = float(np.sqrt(w[1] / w[0]))
    if cond < COLLINEAR:
        raise BodyCalError("points lie nearly on a line: no plane through them", source=name,
                           hint="spread the points out in two directions")
    normal = v[2]
    dist = (p - c) @ normal
    return PlaneFit("plane", float(np.sqrt(np.mean(dist ** 2))), len(p), len(p), cond, np.ones(len(p), bool),
                    point=c, normal=normal, axes=v[:2].copy())


def _kasa_2d(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Algebraic circle x² + y² = 2 a x + 2 b y + k, centred and scaled for conditioning."""
    m = xy.mean(axis=0)
    s = max(float(np.sqrt(((xy - m) ** 2).sum(1).mean())), EPS)
    q = (xy - m) / s
    a = np.column_stack([2 * q, np.ones(len(q))])
    b = (q ** 2).sum(1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    centre = sol[:2]
    r2 = sol[2] + centre @ centre
    return m + s * centre, float(s * np.sqrt(max(r2, 0.0)))


def _geometric(p: np.ndarray, centre: np.ndarray, radius: float, iterations: int = 20):
    """Gauss-Newton on the orthogonal distances |p - c| - r from an algebraic start (2D circle or
    3D sphere). **Decision**: the algebraic (Kåsa) fits shrink the radius on a short arc or cap
    with noise, and the centre follows it toward the points: 30 mm on a 70° hip swing of a real
    clip whose reach varied by 4 mm; the geometric fit has no such bias. It keeps the algebraic
    answer when it does not improve on it (exact or degenerate data)."""
    c, r = np.array(centre, float), float(radius)

    def cost(c_, r_):
        return float(np.sum((np.linalg.norm(p - c_, axis=1) - r_) ** 2))

    best = cost(c, r)
    for _ in range(iterations):
        d = p - c
        dist = np.linalg.norm(d, axis=1)
        if np.any(dist < EPS):
            break
        jac = np.column_stack([-d / dist[:, None], -np.ones(len(p))])
        step, *_ = np.linalg.lstsq(jac, -(dist - r), rcond=None)
        c_new, r_new = c + step[:-1], r + step[-1]
        new = cost(c_new, r_new)
        if not np.isfinite(new) or new >= best:
            break
        c, r, best = c_new, r_new, new
        if np.abs(step).max() < 1e-9 * max(r, 1e-9):
            break
    return c, abs(r)


def _arc_deg(angles: np.ndarray) -> float:
    """Angle a set of directions in a plane sweeps: 360° minus the largest gap between them."""
    if len(angles) < 2:
        return 0.0
    a = np.sort(np.mod(angles, 2 * np.pi))
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
    return float(np.degrees(2 * np.pi - gaps.max()))


def _two_sigma(dist: np.ndarray) -> np.ndarray:
    """Delahaye 2023, appendix B: drop points whose distance to the centre is more than two standard
    deviations from the mean distance."""
    mu, sd = dist.mean(), dist.std()
    return np.abs(dist - mu) <= max(2.0 * sd, 1e-9 * max(mu, 1.0))  # exact data: keep everything


def _robust_passes(p: np.ndarray, fit, minimum: int, passes: int):
    """Repeat the 2-sigma pass on the kept points until none is dropped (at most `passes` times).

    **Decision** (DESIGN.md §3): the paper makes one second pass; with 10% gross outliers one pass
    still keeps the outliers nearest the surface (the first fit's spread is inflated by them).
    Repeating converges in 2-4 passes; test_geometry shows it beats one pass on such data."""
    keep = np.ones(len(p), bool)
    result = fit(p)
    for _ in range(passes):
        centre = result[0] if not isinstance(result[0], PlaneFit) else result[1]
        dist = np.linalg.norm(p - centre, axis=1)
        new = keep & _two_sigma_masked(dist, keep)
        if new.sum() < minimum or new.sum() == keep.sum():
            break
        keep = new
        result = fit(p[keep])
    return result, keep


def _two_sigma_masked(dist: np.ndarray, mask: np.ndarray) -> np.ndarray:
    out = np.zeros(len(dist), bool)
    out[mask] = _two_sigma(dist[mask])
    return out


def fit_circle(points, *, name: str = "circle", robust: bool = True, passes: int = 8,
               min_arc_deg: float = MIN_ARC_DEG) -> CircleFit:
    """Circle through 3D points: plane, projection, 2D algebraic fit, optional 2-sigma pass.

    `range_deg` is the arc the points sweep around the centre; `conditioning` = sqrt(λ2/λ1) of the
    points (0 on a line)."""
    p, _ = _clean(points, name, 5)

    def once(q):
        plane = fit_plane(q, name=name)
        uv = (q - plane.point) @ plane.axes.T
        c2, r = _geometric(uv, *_kasa_2d(uv))
        centre = plane.point + c2 @ plane.axes
        return plane, centre, r

    (plane, centre, r), keep = _robust_passes(p, once, 5, passes if robust else 0)
    q = p[keep]
    rel = q - centre
    h = rel @ plane.normal
    rho = np.linalg.norm(rel - h[:, None] * plane.normal, axis=1)
    rms = float(np.sqrt(np.mean((rho - r) ** 2 + h ** 2)))
    arc = _arc_deg(np.arctan2(rel @ plane.axes[1], rel @ plane.axes[0]))
    fit = CircleFit("circle", rms, int(keep.sum()), len(p), plane.conditioning, keep, arc,
                    center=centre, normal=plane.normal, radius=r)
    if arc < min_arc_deg:
        raise BodyCalError(f"only {arc:.0f} degrees of motion recorded, at least {min_arc_deg:.0f} needed",
                           source=name, hint="flex the joint through a wider range and record the step again")
    if r > 0 and rms > RESIDUAL_GATE * r:
        raise BodyCalError(f"the points do not lie on a circle (residual {rms * 1000:.0f} mm for a radius of "
                           f"{r * 1000:.0f} mm)", source=name,
                           hint="keep the other joints still while flexing and record the step again")
    return fit


def _sphere_lsq(p: np.ndarray) -> tuple[np.ndarray, float, float]:
    """Algebraic sphere |x|² = 2 c·x + k (centred and scaled); returns centre, radius and the
    inverse condition number of the design matrix."""
    m = p.mean(axis=0)
    s = max(float(np.sqrt(((p - m) ** 2).sum(1).mean())), EPS)
    q = (p - m) / s
    a = np.column_stack([2 * q, np.ones(len(q))])
    b = (q ** 2).sum(1)
    sol, _, _, sv = np.linalg.lstsq(a, b, rcond=None)
    centre = sol[:3]
    r2 = sol[3] + centre @ centre
    inv_cond = float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0
    if len(p) > 4:  # four points: the algebraic sphere is exact
        centre, r = _geometric(q, centre, float(np.sqrt(max(r2, 0.0))))
        return m + s * centre, float(s * r), inv_cond
    return m + s * centre, float(s * np.sqrt(max(r2, 0.0))), inv_cond


def swing_deg(rel: np.ndarray) -> tuple[float, float]:
    """Angular extent of directions from a centre along their two principal tangent directions
    (major, minor), from the 2nd to the 98th percentile so single outliers do not count (the sphere
    fit's check, and the live wizard's swing progress, recording/live/wizard.py)."""
    u = rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), EPS)
    mean = u.mean(axis=0)
    mean /= max(np.linalg.norm(mean), EPS)
    t = u - (u @ mean)[:, None] * mean
    _, w, v = _principal(t)
    out = []
    for axis in v[:2]:
        ang = np.degrees(np.arctan2(t @ axis, u @ mean))
        lo, hi = np.percentile(ang, [2, 98])
        out.append(float(hi - lo))
    return out[0], out[1]


def fit_sphere(points, *, name: str = "sphere", robust: bool = True, passes: int = 8,
               min_swing_deg: float = MIN_SWING_DEG, min_minor_deg: float = MIN_SWING_MINOR_DEG) -> SphereFit:
    """Sphere through 3D points (algebraic least squares), optional 2-sigma pass; radius = mean
    distance to the centre. With exactly 4 points the sphere through them is exact.

    `range_deg` is the main swing seen from the centre; `conditioning` the inverse condition
    number of the algebraic system (0: the points do not determine a sphere)."""
    p, _ = _clean(points, name, 4)
    c, w, v = _principal(p)
    if np.sqrt(w[0]) < 1e-9:
        raise BodyCalError("all points are at the same place: no motion recorded", source=name,
                           hint="move the limb around and record the step again")
    if np.sqrt(w[1] / w[0]) < COLLINEAR:
        raise BodyCalError("points lie nearly on a line: the sphere is undetermined", source=name,
                           hint="move the limb in more than one direction")
    if len(p) > 4 and np.sqrt(w[2] / w[0]) < COLLINEAR:
        raise BodyCalError("points lie nearly in one plane: the sphere is undetermined", source=name,
                           hint="swing the limb forward-backward and sideways, not in one plane")
    (centre, r, inv_cond), keep = _robust_passes(p, _sphere_lsq, 5, passes if robust and len(p) > 4 else 0)
    q = p[keep]
    dist = np.linalg.norm(q - centre, axis=1)
    if len(q) > 4:
        r = float(dist.mean())  # Delahaye 2023: radius = mean distance to the centre
    rms = float(np.sqrt(np.mean((dist - r) ** 2)))
    major, minor = swing_deg(q - centre) if len(q) > 4 else (None, None)
    fit = SphereFit("sphere", rms, int(keep.sum()), len(p), inv_cond, keep, major, center=centre, radius=r)
    if len(q) > 4:
        if major < min_swing_deg:
            raise BodyCalError(f"only {major:.0f} degrees of motion recorded, at least {min_swing_deg:.0f} needed",
                               source=name, hint="swing the limb through a wider range and record the step again")
        if minor < min_minor_deg:
            raise BodyCalError(f"the motion stays in one plane ({minor:.0f} degrees across it, at least "
                               f"{min_minor_deg:.0f} needed)", source=name,
                               hint="swing the limb sideways as well as forward and back")
        if rms > RESIDUAL_GATE * r:
            raise BodyCalError(f"the points do not lie on a sphere (residual {rms * 1000:.0f} mm for a radius of "
                               f"{r * 1000:.0f} mm)", source=name,
                               hint="keep the body still while swinging the limb and record the step again")
    elif inv_cond < 1e-6:
        raise BodyCalError("the four points lie in one plane: no sphere through them", source=name,
                           hint="touch points that are not on one circle")
    return fit


@dataclass
class MovingSphereFit(SphereFit):
    local: np.ndarray = None  # the point on the sphere, in the moving device's frame


def fit_sphere_moving_point(positions, rotations, *, name: str = "sphere", robust: bool = True, passes: int = 1,
                            spread: float = 0.05, noise: float = 0.005) -> MovingSphereFit:
    """The centre of a sphere traced by a point riding on a moving device, the point found with it:
    minimises sum (|c - p_t - R_t a| - r)^2 over the centre c, the point a in the device's frame
    and the radius r (Gauss-Newton from `fit_sphere` of the device's origin and a = 0).

    A device strapped 7 cm off the ankle (a foot tracker on the instep, a controller in the fist)
    swings on the hip's (shoulder's) sphere only as far as the ankle (wrist) holds still: a few
    degrees of wander there change its reach by millimetres, and a 70° cap turns that into
    centimetres along its axis. The point that keeps its distance is the joint the wander turns
    about; along the limb it trades with the radius, so it is held near the device's origin by a
    prior of `spread` metres against position errors of `noise`. positions (N, 3) and rotations
    (N, 3, 3) are the device's, in the frame the centre is fixed in.

    One 2-sigma pass by default (Delahaye 2023's): what is left after the moving point is smooth (a
    knee bending a little), and repeated passes peel the cap's rim away a band at a time, which
    weakens the very direction that is weak (on real clips they dropped 30-40% of the swing and
    doubled the worst hip error, 20 -> 29 mm)."""
    p = np.asarray(positions, float)
    R = np.asarray(rotations, float)
    base = fit_sphere(p, name=name, robust=robust, passes=passes)
    keep = base.inliers.copy()

    def solve(k):
        c, a, r = base.center.copy(), np.zeros(3), float(base.radius)
        pk, Rk = p[k], R[k]
        for _ in range(30):
            v = c - pk - np.einsum("nij,j->ni", Rk, a)
            d = np.linalg.norm(v, axis=1)
            u = v / np.maximum(d, EPS)[:, None]
            jac = np.zeros((len(pk) + 3, 7))
            jac[:len(pk), :3] = u / noise
            jac[:len(pk), 3:6] = -np.einsum("ni,nij->nj", u, Rk) / noise
            jac[:len(pk), 6] = -1.0 / noise
            jac[len(pk):, 3:6] = np.eye(3) / spread
            res = np.concatenate([(d - r) / noise, a / spread])
            step, *_ = np.linalg.lstsq(jac, -res, rcond=None)
            c, a, r = c + step[:3], a + step[3:6], r + step[6]
            if np.abs(step).max() < 1e-9:
                break
        return c, a, r

    def misfit(c, a, r):
        return np.linalg.norm(c - p - np.einsum("nij,j->ni", R, a), axis=1) - r

    c, a, r = solve(keep)
    for _ in range(passes if robust else 0):
        new = keep & _two_sigma_masked(np.abs(misfit(c, a, r)) + r, keep)
        if new.sum() < 5 or new.sum() == keep.sum():
            break
        keep = new
        c, a, r = solve(keep)
    rms = float(np.sqrt(np.mean(misfit(c, a, r)[keep] ** 2)))
    return MovingSphereFit("sphere", rms, int(keep.sum()), len(p), base.conditioning, keep, base.range_deg,
                           center=c, radius=float(r), local=a)


@dataclass
class RigidPointFit(Fit):
    local_a: np.ndarray = None  # the point in frame A
    local_b: np.ndarray = None  # the same point in frame B
    weak_axis: bool = False  # hinge-like motion: placed along the axis by `along_axis_as`


HINGE_WEAK = 0.3  # smallest / next singular value below this: one direction may be a hinge's free axis ...
HINGE_SE = 0.0005  # ... and it is when the data leave the point uncertain along it by more than this (m)
HINGE_NOISE_FLOOR = 1e-4  # m: the residual assumed at least this (exact data of a true hinge stay free)
HINGE_ALONG_BONE = 0.7  # |cos| between the free direction and the hint's offset: a twist, not a hinge


def _hinge_free(a: np.ndarray, y: np.ndarray, x: np.ndarray, sv: np.ndarray) -> bool:
    """Whether the least squares `a x = y` (singular values `sv`) leaves x free along its weakest
    direction: far less determined than the next (a hinge; a small range of motion shrinks all
    three alike and is not one) AND uncertain by more than HINGE_SE there, the standard error
    residual / singular value. The ratio alone called a real wrist a hinge when the take twisted
    it 34 degrees about the forearm and bent it 2: its centre was then slid 0.2 m along the
    forearm, where the data had put it within 1.3 mm (CMU 05_06, evaluation/)."""
    if sv[-1] >= HINGE_WEAK * sv[-2]:
        return False
    rms = max(float(np.sqrt(np.mean((a @ x - y) ** 2))), HINGE_NOISE_FLOOR)
    return rms > HINGE_SE * sv[-1]


def fit_rigid_point(rot_a, pos_a, rot_b, pos_b, *, name: str = "joint", robust: bool = True,
                    passes: int = 8, along_axis_as=None) -> RigidPointFit:
    """The point fixed in two moving frames (a ball joint between two tracked bones): least squares
    of R_a(t) a + p_a(t) = R_b(t) b + p_b(t) over frames t (the "symmetrical centre of rotation
    estimation", Ehrig et al. 2006), with the same repeated 2-sigma pass on the per-frame misfit.
    `rot_*` are (F, 3, 3) matrices, `pos_*` (F, 3). Unlike a sphere fit of one tracker's origin
    in the other's frame, it uses both trackers' rotations, so a short swing arc or tracker
    wobble does not trade the centre against the radius.

    A joint that mostly turns about one axis (a hinge: the ankle, the wrist in a recording that
    hardly deviates it) leaves the point free along that axis. With `along_axis_as` (a point in
    frame A) the fit then takes that point's coordinate along the axis instead of failing
    (`weak_axis` is set on the result); without it, such data raises.

    `conditioning` = smallest / largest singular value of the system (0: the frames never rotated
    relative to each other); `range_deg` = the largest relative rotation from the mean pose."""
    ra, pa, rb, pb = (np.asarray(x, float) for x in (rot_a, pos_a, rot_b, pos_b))
    ok = np.all(np.isfinite(pa), 1) & np.all(np.isfinite(pb), 1) & np.all(np.isfinite(ra), (1, 2)) & \
        np.all(np.isfinite(rb), (1, 2))
    ra, pa, rb, pb = ra[ok], pa[ok], rb[ok], pb[ok]
    if len(pa) < 10:
        raise BodyCalError(f"only {len(pa)} usable frames, at least 10 needed", source=name,
                           hint="record the step again with both trackers visible")
    weak = [False]

    def solve(k):
        a = np.concatenate([ra[k], -rb[k]], axis=2).reshape(-1, 6)
        y = (pb[k] - pa[k]).reshape(-1)
        u, sv, vt = np.linalg.svd(a, full_matrices=False)
        cond = float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0
        x = vt.T @ ((u.T @ y) / np.maximum(sv, sv[0] * 1e-12 + EPS))
        weak[0] = along_axis_as is not None and _hinge_free(a, y, x, sv)
        if weak[0]:  # slide along the free direction to the given point's coordinate on the axis
            x = vt[:5].T @ ((u[:, :5].T @ y) / sv[:5])
            w = vt[-1]
            hint = np.asarray(along_axis_as, float) - x[:3]
            if abs(hint @ w[:3]) > HINGE_ALONG_BONE * np.linalg.norm(hint) * np.linalg.norm(w[:3]):
                raise BodyCalError("the joint turned only about the bone between the two trackers (a twist), "
                                   "which leaves its place along the bone free", source=name,
                                   hint="flex and bend the joint as well as twisting it")
            x = x + w * ((hint @ w[:3]) / max(w[:3] @ w[:3], EPS))
        return x, cond

    def misfit(x):
        return np.linalg.norm(np.einsum("fij,j->fi", ra, x[:3]) + pa - np.einsum("fij,j->fi", rb, x[3:]) - pb, axis=1)

    keep = np.ones(len(pa), bool)
    x, cond = solve(keep)
    for _ in range(passes if robust else 0):
        res = misfit(x)
        new = keep & (res <= res[keep].mean() + 2.0 * res[keep].std() + EPS)
        if new.sum() < 10 or new.sum() == keep.sum():
            break
        keep = new
        x, cond = solve(keep)
    res = misfit(x)[keep]
    rel = np.einsum("fji,fjk->fik", rb[keep], ra[keep])  # R_b^T R_a
    q = matrix_to_quat(rel)
    q = np.where((q @ q[0])[:, None] < 0, -q, q)
    mean = quat_normalize(q.mean(axis=0))
    rng_deg = float(np.degrees(np.percentile(quat_angle(quat_mul(quat_conj(mean), q)), 98)) * 2.0)
    if (cond < 1e-4 and not weak[0]) or rng_deg < 10.0:
        raise BodyCalError(f"only {rng_deg:.0f} degrees of motion recorded between the two trackers",
                           source=name, hint="move the limb through a wider range and record the step again")
    return RigidPointFit("rigid_point", float(np.sqrt(np.mean(res ** 2))), int(keep.sum()), len(pa), cond,
                         keep, rng_deg, local_a=x[:3], local_b=x[3:], weak_axis=bool(weak[0]))


def fixed_point_spread(rotations, noise: float, count: float) -> float:
    """How well rotations `rotations` (N, 3, 3) of one frame relative to another fix the point
    `fit_rigid_point` finds: its standard error for `noise` of independent misfit per frame over
    `count` independent frames. The fit's normal matrix depends on the rotations only, [[N I, -S],
    [-S^T, N I]] with S their sum, so the point's block of its inverse is (N (I - C C^T))^-1 with C
    their mean: infinite for one rotation or rotations about one axis (the point slides along it),
    shrinking as they turn about two directions. Same units as `noise`."""
    rel = np.asarray(rotations, float)
    if len(rel) < 2 or count <= 0:
        return float("inf")
    c = rel.mean(axis=0)
    w = np.linalg.eigvalsh(np.eye(3) - c @ c.T)
    if w[0] <= 1e-12:
        return float("inf")
    return float(noise * np.sqrt(np.sum(1.0 / w) / count))


def fit_rotation_axis(rotations, *, name: str = "hinge") -> tuple[np.ndarray, float]:
    """Axis of a hinge from relative rotations (F, 3, 3) of one bone's frame seen from the other:
    each of the three axes of the moving frame sweeps a circle about the hinge axis, so the axis
    is the common normal of the three swept planes (smallest eigenvector of the summed scatter of
    the columns). Returns (unit axis, sign arbitrary; angle in degrees the frames turned about it).

    Orientation noise of a tracker is a fraction of a degree where its position wobbles by
    millimetres over a lever of 20-30 cm, so this axis is steadier than a circle fit's normal."""
    r = np.asarray(rotations, float)
    r = r[np.all(np.isfinite(r), axis=(1, 2))]
    if len(r) < 5:
        raise BodyCalError(f"only {len(r)} usable frames, at least 5 needed", source=name,
                           hint="record the step again with both trackers visible")
    scatter = np.zeros((3, 3))
    for k in range(3):
        c = r[:, :, k] - r[:, :, k].mean(axis=0)
        scatter += c.T @ c / len(r)
    w, v = np.linalg.eigh(scatter)
    axis = v[:, 0]
    # angle swept: the column most perpendicular to the axis, its direction in the plane
    k = int(np.argmin(np.abs(axis @ r.mean(axis=0))))
    u = r[:, :, k] - np.outer(r[:, :, k] @ axis, axis)
    e1 = u.mean(axis=0)
    e1 /= max(np.linalg.norm(e1), EPS)
    e2 = np.cross(axis, e1)
    return axis, _arc_deg(np.arctan2(u @ e2, u @ e1))


def two_bone_mid(root, effector, l1, l2, swivel) -> np.ndarray:
    """The middle joint of a two-bone chain of lengths l1, l2 from `root` to `effector` (arrays
    (..., 3)), on the side of the root-effector line toward `swivel` (law of cosines; a chain too
    short to reach stays on the line, one too long folds as far as it can)."""
    root, effector, swivel = (np.asarray(x, float) for x in (root, effector, swivel))
    v = effector - root
    d = np.linalg.norm(v, axis=-1)
    axis = v / np.maximum(d, EPS)[..., None]
    d = np.clip(d, abs(l1 - l2) + 1e-9, l1 + l2 - 1e-9)
    cos_a = np.clip((l1 * l1 + d * d - l2 * l2) / (2.0 * l1 * d), -1.0, 1.0)
    pole = swivel - np.sum(swivel * axis, axis=-1, keepdims=True) * axis
    pole = pole / np.maximum(np.linalg.norm(pole, axis=-1, keepdims=True), EPS)
    return root + l1 * (cos_a[..., None] * axis + np.sqrt(1.0 - cos_a * cos_a)[..., None] * pole)


def robust_mean(points, *, name: str = "points", minimum: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Mean of points after the same 2-sigma pass on the distance to their median; returns
    (mean, kept mask over the finite points)."""
    p, _ = _clean(points, name, minimum)
    med = np.median(p, axis=0)
    d = np.linalg.norm(p - med, axis=1)
    keep = d <= max(2.0 * np.sqrt(np.mean(d ** 2)), 1e-9)
    if keep.sum() == 0:
        keep[:] = True
    return p[keep].mean(axis=0), keep


def running_median(x: np.ndarray, w: int) -> np.ndarray:
    """Centred running median over the leading axis (edges padded with the end values): the
    calibration's glitch and touch filters, and the live wizard's speeds."""
    if len(x) < w:
        return np.repeat(np.median(x, axis=0, keepdims=True), len(x), axis=0)
    pad = w // 2
    xp = np.concatenate([np.repeat(x[:1], pad, 0), x, np.repeat(x[-1:], pad, 0)])
    return np.median(sliding_window_view(xp, w, axis=0), axis=-1)
