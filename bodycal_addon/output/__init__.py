"""What a retargeted animation becomes (numpy only): `root_motion` (where the travel goes),
`rigify` (a generated Rigify rig's controls), `armature_space` (limbs keyed in the armature's
space), `keyreduce` and `bezier` (the keys, within a stated error), `metrics` and `review` (the
figures a bake is judged by), `review_page` (a batch's page), `vmc_bones` (the avatar as VMC bones,
with python-osc).

The package re-exports nothing: `vmc_bones` needs python-osc, the others are imported one by one."""
