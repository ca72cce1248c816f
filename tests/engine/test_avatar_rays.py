"""The avatar calibration's ray plan without Blender (DESIGN.md §4): `avatar/rays.surface_from_rays`
on the procedural avatar's armature read by the engine (`armature.read_armature`), cast against the
avatar's exact shapes by an analytic caster: capsules, the torso ellipsoid, the skull sphere and the
palm and sole boxes. The same truth checks as the BVH raycasts in Blender."""

from __future__ import annotations

import re

import numpy as np
import pytest
import truth_checks as tc

from bodycal_addon.avatar.armature import read_armature
from bodycal_addon.avatar.rays import planned_rays, surface_from_rays
from bodycal_addon.body import naming
from bodycal_addon.core.errors import BodyCalError
from sample_rigs import procedural


class AnalyticCaster:
    """First hits on exact capsules, ellipsoids (spheres) and triangle boxes, in world space."""

    def __init__(self, spec: procedural.ProceduralAvatar, matrix_world: np.ndarray):
        self.m = np.asarray(matrix_world, float)
        self.inv = np.linalg.inv(self.m)
        self.capsules = [(c["head"], c["tail"], c["radius"]) for c in spec.truth["capsules"].values()]
        t = spec.truth["torso"]
        self.ellipsoids = [(t["center"], t["semi_axes"]),
                           (spec.truth["skull"]["center"], np.full(3, spec.truth["skull"]["radius"]))]
        tris = []
        for part in spec.parts:
            if part.name.startswith(("palm_", "foot_")):
                for f in part.faces:
                    tris += [part.vertices[[f[0], f[k], f[k + 1]]] for k in range(1, len(f) - 1)]
        self.triangles = np.array(tris)
        self.rays = 0

    @staticmethod
    def _sphere(o, d, c, r):
        oc = o - c
        b, cc = oc @ d, oc @ oc - r * r
        disc = b * b - cc
        if disc < 0:
            return []
        s = np.sqrt(disc)
        return [-b - s, -b + s]

    def _capsule(self, o, d, a, b, r):
        axis = (b - a) / np.linalg.norm(b - a)
        length = np.linalg.norm(b - a)
        # The end spheres' surface counts only on their outer halves (inside the cylinder's span
        # it is the interior of the union).
        ts = [t for t in self._sphere(o, d, a, r) if (o + t * d - a) @ axis <= 0.0]
        ts += [t for t in self._sphere(o, d, b, r) if (o + t * d - a) @ axis >= length]
        dp, op = d - (d @ axis) * axis, (o - a) - ((o - a) @ axis) * axis
        qa, qb, qc = dp @ dp, 2 * dp @ op, op @ op - r * r
        if qa > 1e-15 and qb * qb - 4 * qa * qc >= 0:
            s = np.sqrt(qb * qb - 4 * qa * qc)
            for t in ((-qb - s) / (2 * qa), (-qb + s) / (2 * qa)):
                if 0.0 <= (o + t * d - a) @ axis <= length:
                    ts.append(t)
        return ts

    def _boxes(self, o, d):
        v0, e1, e2 = self.triangles[:, 0], self.triangles[:, 1] - self.triangles[:, 0], \
            self.triangles[:, 2] - self.triangles[:, 0]
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        ok = np.abs(det) > 1e-15
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = o - v0
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ d) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1)
        return list(t[hit])

    def cast(self, origin, direction, max_dist: float = 1e4):
        self.rays += 1
        # Cast in the avatar's own space (where the shapes are), report in the world.
        o = (self.inv @ np.append(origin, 1.0))[:3]
        d_local = self.inv[:3, :3] @ direction
        scale = np.linalg.norm(d_local)
        d = d_local / scale
        ts = self._boxes(o, d)
        for a, b, r in self.capsules:
            ts += self._capsule(o, d, a, b, r)
        for c, axes in self.ellipsoids:  # an ellipsoid is a unit sphere in its scaled space
            ds = d / axes
            n = np.linalg.norm(ds)
            ts += [t / n for t in self._sphere((o - c) / axes, ds / n, np.zeros(3), 1.0)]
        ts = [t for t in ts if t > 1e-9]
        if not ts:
            return None
        hit = (self.m @ np.append(o + min(ts) * d, 1.0))[:3]
        dist = float(np.linalg.norm(hit - origin))
        return (hit, dist) if dist <= max_dist else None


def _rest_bones(spec: procedural.ProceduralAvatar) -> dict[str, dict]:
    """The bones as Blender's `align_roll` rests them: +Y along the bone, +Z toward `z_axis`."""
    out = {}
    for name, b in spec.bones.items():
        y = (b.tail - b.head) / np.linalg.norm(b.tail - b.head)
        z = b.z_axis - (b.z_axis @ y) * y
        z /= np.linalg.norm(z)
        out[name] = {"parent": b.parent, "head": b.head, "tail": b.tail, "matrix": np.stack([np.cross(y, z), y, z], 1)}
    return out


def _measure(spec, matrix_world=None):
    matrix_world = np.eye(4) if matrix_world is None else matrix_world
    bones = _rest_bones(spec)
    rig = read_armature(spec.name, matrix_world, bones, naming.detect_bone_map(list(bones)))
    caster = AnalyticCaster(spec, matrix_world)
    return surface_from_rays(rig, caster, spec.name), caster


@pytest.mark.parametrize("kwargs", [{}, {"arm_drop_deg": 40.0}, {"belly": 0.12}], ids=["tpose", "apose", "belly"])
def test_the_ray_plan_measures_the_exact_shapes(kwargs):
    spec = procedural.build_spec(**kwargs)
    model, caster = _measure(spec)
    tc.check_layout(model)
    tc.check_truth(model, spec)
    assert model.extra["rig"]["rest_pose"] == ("A" if kwargs.get("arm_drop_deg") else "T")
    assert caster.rays > 500 and model.calibration["quality"]["capsule:forearm_l"]["spread_mm"] < 1.0


def test_the_planned_ray_count_is_the_count_cast():
    """The sidebar's progress bar runs to `planned_rays`: it ends at 100 %, not before or after."""
    for spec in (procedural.build_spec(), procedural.build_spec(arm_drop_deg=40.0)):
        bones = _rest_bones(spec)
        rig = read_armature(spec.name, np.eye(4), bones, naming.detect_bone_map(list(bones)))
        _model, caster = _measure(spec)
        assert planned_rays(rig) == caster.rays
    # A rig without fingers plans no finger capsules.
    fingerless = {k: v for k, v in bones.items() if not k.startswith(("thumb", "index", "middle", "ring", "pinky"))}
    rig = read_armature(spec.name, np.eye(4), fingerless, naming.detect_bone_map(list(fingerless)))
    assert planned_rays(rig) < caster.rays - 20 * 72


def test_a_moved_turned_scaled_armature_moves_the_measurements_with_it():
    spec = procedural.build_spec()
    ref, _ = _measure(spec)
    c, s = np.cos(0.7), np.sin(0.7)
    mw = np.array([[c, -s, 0, 2.0], [s, c, 0, -3.0], [0, 0, 1, 0.1], [0, 0, 0, 1.0]]) @ np.diag([1.3, 1.3, 1.3, 1])
    moved, _ = _measure(spec, mw)
    for j in ("pelvis", "wrist_l", "ankle_r", "skull_base"):
        assert np.allclose(moved.joints[j].world, (mw @ np.append(ref.joints[j].world, 1.0))[:3], atol=1e-6), j
    for b in ("forearm_l", "thigh_r", "index_2_l"):
        assert moved.bones[b].radius_head == pytest.approx(ref.bones[b].radius_head * 1.3, abs=2e-4), b
    assert moved.element("sphere:skull").radius == pytest.approx(ref.element("sphere:skull").radius * 1.3, abs=2e-4)


def test_a_caster_that_never_hits_gives_one_clear_error():
    spec = procedural.build_spec()

    class Nothing:
        rays = 0

        def cast(self, origin, direction, max_dist=1e4):
            self.rays += 1
            return None

    bones = _rest_bones(spec)
    rig = read_armature(spec.name, np.eye(4), bones, naming.detect_bone_map(list(bones)))
    with pytest.raises(BodyCalError, match=r"capsule:\w+: only 0 of 60 rays .* hit the mesh") as info:
        surface_from_rays(rig, Nothing(), spec.name)
    assert "\n" not in str(info.value)


def test_a_limb_and_a_foot_the_mesh_leaves_bare_are_estimated_and_said():
    """A stylised character (RobotExpressive: shoulder balls and bare rods of upper arms, a disc of
    a foot) was refused at its first bare part ('capsule:upperarm_l: only 21 of 60 rays ...', then
    'the ray for mesh:sole_l sole_3_l ... missed'). A bare limb's capsule and a foot the sole rays
    miss take the body's proportions, and the calibration lists them; the rest is measured."""
    spec = procedural.build_spec()
    bones = _rest_bones(spec)
    rig = read_armature(spec.name, np.eye(4), bones, naming.detect_bone_map(list(bones)))
    shoulder, elbow = rig.joints["shoulder_l"], rig.joints["elbow_l"]
    ankle, across = rig.joints["ankle_l"], rig.joints["ankle_l"] - rig.joints["ankle_r"]

    class Bare(AnalyticCaster):
        def cast(self, origin, direction, max_dist=1e4):
            along = (origin - shoulder) @ (elbow - shoulder) / np.sum((elbow - shoulder) ** 2)
            on_upper_arm = 0.05 < along < 0.95 and np.linalg.norm(
                origin - shoulder - along * (elbow - shoulder)) < 1e-6
            under_left_foot = origin[2] < ankle[2] and (origin - ankle + 0.5 * across) @ across > 0
            if on_upper_arm or under_left_foot:
                self.rays += 1
                return None
            return super().cast(origin, direction, max_dist)

    model = surface_from_rays(rig, Bare(spec, np.eye(4)), spec.name)
    defaulted = model.calibration["defaulted"]
    assert re.search(r"only 0 of 60 rays from bone upperarm_l hit the mesh", defaulted["capsule:upperarm_l"])
    assert "mesh:sole_l" in defaulted and "mesh:sole_r" not in defaulted and "capsule:forearm_l" not in defaulted
    assert {"capsule:upperarm_l", "mesh:sole_l"} <= {e.id for e in model.surface}
    assert model.calibration["quality"]["mesh:sole_l"] == {"estimated": True}
    truth, _ = _measure(spec)
    sole = model.element("mesh:sole_l")
    true = truth.element("mesh:sole_l")
    spread = [np.linalg.norm(sole.points[k].local - true.points[k].local) for k in true.points]
    assert max(spread) < 0.06, spread  # the template's sole, scaled by the foot: near the real one
