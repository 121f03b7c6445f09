"""The medial axis of a mesh (Lan et al. 2017, after Q-MAT and Sun et al. 2013): medial spheres
joined into cones and slabs, and, later, medial-axis-driven deformation (issue 18).

Imports the shared helpers and the subsystems below it (`_spines`, `_fleshing`, `_fit`,
`_mesh`).
"""
