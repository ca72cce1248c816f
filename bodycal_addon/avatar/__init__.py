"""Avatars measured from their armature and mesh, or estimated from bone lengths (numpy only).

- `armature`: `ArmatureReading`, an armature in canonical terms (`read_armature` is blender/'s).
- `rays`: the surface calibration's ray plan and `surface_from_rays` (DESIGN.md §4).
- `estimate`: `estimate_surface`, a body surface from a bare skeleton (DESIGN.md §8).
- `structure`: `map_by_structure`, a bone map from a rig's shape when no naming scheme reads it.
- `foot_contact`, `surface_fit`, `template`: the sole's contact points, small robust fits, the
  mean avatar the estimate starts from.

The package re-exports nothing: its modules are imported one by one."""
