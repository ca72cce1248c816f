"""Robust geometric fits for the user calibration (DESIGN.md §3; paper 000, appendix B).

- `fit_plane`: centroid + principal directions of the centred scatter matrix (the two largest
  eigenvalues span the plane, the third eigenvector is the normal).
- `fit_circle`: plane fit, projection, algebraic (Kåsa) circle fit in 2D; second pass without
  the points farther than 2 standard deviations from the mean distance to the centre
  (paper 000, appendix B, "Intermediate Joint and Bone Calibration").
- `fit_sphere`: algebraic least-squares sphere, same 2-sigma second pass; radius = mean distance
  to the centre ("Anchor Joint and Bone Calibration").

Every fit reports its residual RMS, the points kept / used and a conditioning figure, and
raises `BodyCalError` naming the step and what to redo when the data cannot determine the fit
(too few points, too little motion, points nearly on a line or in a plane).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import BodyCalError
from .transforms import matrix_to_quat, quat_angle, quat_conj, quat_mul, quat_normalize

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
    s = max(float(np.sqrt(((xy - m) ** 2).sum(1).mean())), 1e-12)
    q = (xy - m) / s
    a = np.column_stack([2 * q, np.ones(len(q))])
    b = (q ** 2).sum(1)
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    centre = sol[:2]
    r2 = sol[2] + centre @ centre
    return m + s * centre, float(s * np.sqrt(max(r2, 0.0)))


def _arc_deg(angles: np.ndarray) -> float:
    """Angle a set of directions in a plane sweeps: 360° minus the largest gap between them."""
    if len(angles) < 2:
        return 0.0
    a = np.sort(np.mod(angles, 2 * np.pi))
    gaps = np.diff(np.concatenate([a, a[:1] + 2 * np.pi]))
    return float(np.degrees(2 * np.pi - gaps.max()))


def _two_sigma(dist: np.ndarray) -> np.ndarray:
    """Paper 000, appendix B: drop points whose distance to the centre is more than two standard
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
        c2, r = _kasa_2d(uv)
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
    s = max(float(np.sqrt(((p - m) ** 2).sum(1).mean())), 1e-12)
    q = (p - m) / s
    a = np.column_stack([2 * q, np.ones(len(q))])
    b = (q ** 2).sum(1)
    sol, _, _, sv = np.linalg.lstsq(a, b, rcond=None)
    centre = sol[:3]
    r2 = sol[3] + centre @ centre
    inv_cond = float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0
    return m + s * centre, float(s * np.sqrt(max(r2, 0.0))), inv_cond


def _swing_deg(rel: np.ndarray) -> tuple[float, float]:
    """Angular extent of directions from a centre along their two principal tangent directions
    (major, minor), from the 2nd to the 98th percentile so single outliers do not count."""
    u = rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-12)
    mean = u.mean(axis=0)
    mean /= max(np.linalg.norm(mean), 1e-12)
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
        r = float(dist.mean())  # paper 000: radius = mean distance to the centre
    rms = float(np.sqrt(np.mean((dist - r) ** 2)))
    major, minor = _swing_deg(q - centre) if len(q) > 4 else (None, None)
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
class RigidPointFit(Fit):
    local_a: np.ndarray = None  # the point in frame A
    local_b: np.ndarray = None  # the same point in frame B


def fit_rigid_point(rot_a, pos_a, rot_b, pos_b, *, name: str = "joint", robust: bool = True,
                    passes: int = 8) -> RigidPointFit:
    """The point fixed in two moving frames (a ball joint between two tracked bones): least squares
    of R_a(t) a + p_a(t) = R_b(t) b + p_b(t) over frames t (the "symmetrical centre of rotation
    estimation", Ehrig et al. 2006), with the same repeated 2-sigma pass on the per-frame misfit.
    `rot_*` are (F, 3, 3) matrices, `pos_*` (F, 3). Unlike a sphere fit of one tracker's origin
    in the other's frame, it uses both trackers' rotations, so a short swing arc or tracker
    wobble does not trade the centre against the radius.

    `conditioning` = smallest / largest singular value of the system (0: the frames never rotated
    relative to each other); `range_deg` = the largest relative rotation from the mean pose."""
    ra, pa, rb, pb = (np.asarray(x, float) for x in (rot_a, pos_a, rot_b, pos_b))
    ok = np.all(np.isfinite(pa), 1) & np.all(np.isfinite(pb), 1) & np.all(np.isfinite(ra), (1, 2)) & \
        np.all(np.isfinite(rb), (1, 2))
    ra, pa, rb, pb = ra[ok], pa[ok], rb[ok], pb[ok]
    if len(pa) < 10:
        raise BodyCalError(f"only {len(pa)} usable frames, at least 10 needed", source=name,
                           hint="record the step again with both trackers visible")

    def solve(k):
        a = np.concatenate([ra[k], -rb[k]], axis=2).reshape(-1, 6)
        y = (pb[k] - pa[k]).reshape(-1)
        x, _, _, sv = np.linalg.lstsq(a, y, rcond=None)
        return x, float(sv[-1] / sv[0]) if sv[0] > 0 else 0.0

    def misfit(x):
        return np.linalg.norm(np.einsum("fij,j->fi", ra, x[:3]) + pa - np.einsum("fij,j->fi", rb, x[3:]) - pb, axis=1)

    keep = np.ones(len(pa), bool)
    x, cond = solve(keep)
    for _ in range(passes if robust else 0):
        res = misfit(x)
        new = keep & (res <= res[keep].mean() + 2.0 * res[keep].std() + 1e-12)
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
    if cond < 1e-4 or rng_deg < 10.0:
        raise BodyCalError(f"only {rng_deg:.0f} degrees of motion recorded between the two trackers",
                           source=name, hint="move the limb through a wider range and record the step again")
    return RigidPointFit("rigid_point", float(np.sqrt(np.mean(res ** 2))), int(keep.sum()), len(pa), cond,
                         keep, rng_deg, local_a=x[:3], local_b=x[3:])


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
    e1 /= max(np.linalg.norm(e1), 1e-12)
    e2 = np.cross(axis, e1)
    return axis, _arc_deg(np.arctan2(u @ e2, u @ e1))


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
