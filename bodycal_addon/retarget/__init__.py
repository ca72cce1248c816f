"""Retargeting engine (DESIGN.md §5-6): egocentric mapping, IK, fingers, and the per-frame pipeline."""
