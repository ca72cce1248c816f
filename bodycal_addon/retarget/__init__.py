"""The retargeting engine (DESIGN.md §1, §5-6): a performer's pose onto an avatar, numpy only.

- `takes`: `RecordingTake`, `CharacterTake`: what a session reads from a pose source.
- `methods`: the methods' one registry (`METHOD_INFO`, `methods_for`, `check_method`).
- `solver`: `PreparedSolver`, everything fixed for a (performer, avatar, method); `solver_methods`
  its per-method stages; `pipeline`: the bake's entry points over a take in chunks.
- `egocentric/` (the self-contact mapping), `ik`, `fingers`, `feet`, `lower_body/`, `offsets`,
  `user_animation`, `trackers`, `pose_source`, `transfer`: the steps.
- `avatar_pose` (`AvatarRig`, the face of `rig/`: the plan, forward kinematics, the spine chain
  and the basis solve; with `pose_kernels`, `rig_one_frame`): canonical bone frames <-> the
  avatar's pose bones; `placement`: where the performance plays.

The package re-exports nothing: the command line imports `methods` and `placement` for its
`--help`, which must not load the solver."""
