"""Egocentric self-contact mapping (Delahaye 2023, appendix C; DESIGN.md §5), numpy only, vectorised
over a leading frame axis. The package: `graph` (kinematic tree, paths, own-chain exclusions),
`surface` (posing the surface elements), `projection` (projection kernels), `weights`,
`mapping` (planning and the retro-projection), `one_frame` (one frame's mapping over flat pairs).
This module only re-exports their public names.

Three steps, each a public function:

1. `pose_surface(model, joints, bone_rotations) -> PosedSurface`: every surface element of a body
   model placed per frame from the canonical joint positions and bone frames (columns x, y, z as
   `surface_layout.bone_frame` gives: +Y along the bone, +X its right).
2. `project(points, surface) -> Projections`: each target point projected on each element
   (`x_ij`, `v_ij = p_j - x_ij`), with the surface coordinates that re-pose the projection on
   another body, and the angular factor of the raw weight.
3. `retarget_points(...)`: the retro-projection of Delahaye 2023, eq. 1, with the kinematic
   normalisation of eq. 2 and the floor singularity.

Example (helper code builds `joints` / `bone_rotations` dicts of (F, 3) / (F, 3, 3) arrays)::

    ids = common_elements(user_model, avatar_model)
    us = pose_surface(user_model, user_joints, user_rots, element_ids=ids)
    av = pose_surface(avatar_model, avatar_fk_joints, avatar_fk_rots, element_ids=ids)
    names = ["wrist_l", "wrist_r", "elbow_l", "elbow_r", "tip_index_l", "skull_base"]
    pts = np.stack([user_joints[n] for n in names], axis=1)          # (F, P, 3)
    new = retarget_points(pts, names, us, av)                          # (F, P, 3) avatar targets

Conventions and decisions (each one named in the code where it applies):
- Element order in a `PosedSurface`: capsules, then spheres, then meshes (`element_ids`). The user
  and the avatar must be posed with the same `element_ids` (see `common_elements`).
- A mesh element contributes its closest point (on its closest triangle, per frame and target);
  its angular factor blends its triangles' own by how near each is to being the closest
  (FACTOR_BLEND), so the weight moves continuously across edges and corners. Known limit: where
  two separate parts of a mesh are equally near (far beside the crude torso, its front and
  back), the closest point itself jumps; the step seen is ~1 mm.
- Targets are canonical joint names; the elements on a target's own limb chain are excluded
  (`own_chain_elements`, the single table of exclusions).
- Kinematic paths run over the simplified tree `GRAPH_BONES`: the limb, hand, finger, foot and
  head bones plus the shortcut bones (sacrum -> hips, sacrum -> clavicle root, clavicle root ->
  skull base); the vertebrae are skipped as the paper's Figure 13 does. Each element has one root
  node (`element_root`); the path runs from that node to the target's own joint, so the paper's
  extremity term `v.(p_j - e_j)` is the last bone of the path (the target is the tail of its
  bone). DESIGN.md Decision: absolute values in eq. 2.
- Floor: `h'_j = h_j tau'/tau` with the path from the supporting (lower) ankle to the target; the
  "x - r" extremity of that path is the ankle's height above the floor. Decision: with both feet
  down, the two feet's ratios are blended (SUPPORT_BLEND), so the choice never flips on noise.
- Raw weights: distances are floored at MIN_DISTANCE (1 mm), so a target on a surface takes (almost)
  all the weight of that element and nothing divides by zero; the triangle's cos(v, n) is taken
  from the plane shifted PENETRATION_TOLERANCE into the body (see _triangle_factor).
- Chains with zero weight are skipped: own-chain pairs have no chain at all (paper: "when the
  associated lambda for a kinematic chain is null, the computation ... is skipped").
- A mesh whose triangles differ between user and avatar (e.g. palms with other point counts) is
  re-posed in its bone's frame scaled by the bone length ratio instead of by barycentrics.

Speed: the hot path keeps vector components first ((3, F, P, E) arrays) and runs blocks of
BLOCK_PAIRS frames x targets x elements (fewer, larger numpy calls); everything
frame-independent (exclusions, kinematic paths as index arrays sorted by length) is computed once
per target/element set; targets that exclude the same elements are mapped on the others only,
but a few frames (up to MERGED_PAIRS frames x targets x elements: a live frame) are projected and
re-posed for every target on every element in one pass, and the groups run side by side, each
target on its own elements (`mapping._fused_groups`: groups keeping as many elements, or all
fewer than 8, padded with pairs of no weight, since numpy sums fewer than 8 items one after the
other): each target's sums run over its own elements in their order, so the values are its
group's, bit for bit, in a third of the numpy calls. The user's side is prepared once
(`prepare_targets`, several stages' targets at once with `exclude`) and mapped onto each avatar
pose (`map(targets=...)`); the pipeline computes it in float32 (`dtype`). A few frames' surfaces
pose every mesh point in one padded product (`SurfacePoser`, surface.FEW_FRAMES) (DESIGN.md
"Prepared solver"). One frame where it may differ by float32's rounding (`core/one_frame.ENABLED`)
takes `one_frame.OneFrameMapping`: the same mapping over flat arrays of the pairs that carry weight.
"""

from .graph import GRAPH_BONES, GRAPH_INDEX, GRAPH_NODES, TORSO_ROOT, element_root, kinematic_path, own_chain_elements
from .mapping import BLOCK_PAIRS, SUPPORT_BLEND, PreparedTargets, prepare_targets, retarget_points
from .projection import FACTOR_BLEND, PENETRATION_TOLERANCE, Projections, distances, project, repose
from .surface import JointTable, PosedSurface, SurfacePoser, common_elements, pose_surface
from .weights import MIN_DISTANCE, normalise_weights, raw_weights

__all__ = [
    "BLOCK_PAIRS", "FACTOR_BLEND", "GRAPH_BONES", "GRAPH_INDEX", "GRAPH_NODES", "MIN_DISTANCE",
    "PENETRATION_TOLERANCE", "SUPPORT_BLEND", "TORSO_ROOT", "JointTable", "PosedSurface", "PreparedTargets",
    "Projections", "SurfacePoser", "common_elements", "distances", "element_root", "kinematic_path",
    "normalise_weights",
    "own_chain_elements", "pose_surface", "prepare_targets", "project", "raw_weights", "repose", "retarget_points",
]
