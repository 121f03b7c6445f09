"""The medial axis of a mesh (Lan et al. 2017, after Q-MAT and Sun et al. 2013): medial spheres
joined into cones and slabs, and, later, medial-axis-driven deformation (issue 18).

Imports the shared helpers and the subsystems below it (`_spines`, `_fleshing`, `_fit`,
`_mesh`).

Modules, one concept each (NumPy/SciPy preprocessing; only `MedialMesh` is a pytree):
`surface` (closed-mesh checks, samples, exact closest points and signs), `voronoi` (the
initial medial axis: inner Voronoi complex of the samples), `simplify` (Q-MAT's
sphere-quadric edge collapses), `construct` (`medial_mesh`), `medial_mesh` (`MedialMesh`),
`primitives` (closed-form distances to spheres, cones, slabs and their union), `envelope`
(surface nets of the union), `distance` (`medial_distance`), `files` (`.ma` files),
`rest_spine` (a Fleshing rest spine along the medial graph's longest path), `footprint`
(binding vertices to footprint spheres), `skin` (medial / LBS / DQS skins), `implicit` (the
implicit-skinning correction), `rig` (`MedialRig`), `cells` and `arap` (ARAP
deformation of the medial mesh by handles: `arap_medial`), `fit_handles` (handle targets
fitted to vertex targets).
"""
