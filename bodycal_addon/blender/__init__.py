"""Everything in BodyCal that touches `bpy`: scene I/O, raycasting, baking, the CLI bridge."""
