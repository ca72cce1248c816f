"""The canonical body (DESIGN.md §2): what the user and every avatar are described in.

- `skeleton`: the canonical joints, bones and segments (`SEGMENTS`, `SIDES`, `FINGERS`, ...).
- `naming`: `BoneMap` and the naming schemes (`SCHEMES`, `detect_bone_map`) from avatar bones to segments.
- `bone_presets`: `BonePreset`, `load_preset`: bone map presets (FORMATS.md §5).
- `bodymodel`: `BodyModel`, the `*.body.json` of a user or an avatar (FORMATS.md §3).
- `rest_frames`, `surface_layout`: the bones' rest frames, the surface elements shared by both.
- `animation`: `AvatarAnimation`, what the engine hands to the bake, and `resample`.

The package re-exports nothing: most modules import `skeleton` or `naming` alone, which stays cheap."""
