"""Foundations every layer uses (the bottom layer; numpy, and mathutils in `one_frame`).

- `errors`: `BodyCalError`, the one error users see (one line: what is wrong, what to do), and
  `Cancelled`.
- `transforms`: rotations on arrays with leading frame axes; `geometry`: robust fits.
- `one_frame`: one frame's kernels in Blender's mathutils.
- `outputs`: output paths checked first and written safely; `paths`: where the extension's files are.

The package re-exports nothing: `errors` and `paths` are imported without numpy."""
