"""The medial axis of a mesh (Q-MAT, Li et al. 2015; Sun et al. 2013) and medial-axis-driven
deformation with volume preservation (Lan et al. 2017): medial spheres joined into cones and
slabs, a surface bound to them, moved as rigidly as possible by handles.

Imports the shared helpers and the subsystems below it (`_spines`, `_fleshing`, `_fit`,
`_mesh`).

Modules, one concept each. The medial mesh (NumPy/SciPy preprocessing): `surface`
(closed-mesh checks, samples, exact closest points and signs), `voronoi` (the initial medial
axis: inner Voronoi complex of the samples), `simplify` (Q-MAT's sphere-quadric edge
collapses), `refine` (the spheres fitted to the surface after the collapses: our own
addition), `construct` (`medial_mesh`), `medial_mesh` (`MedialMesh`), `primitives`
(closed-form distances to spheres, cones, slabs and their union), `envelope` (marching
tetrahedra of the union), `connect` (the pieces of an initial axis joined), `shells` (a
mesh's shells: nesting, orientation, crossings), `distance` (`medial_distance`), `files`
(`.ma` files), `figure` (`plot_medial`), `rest_spine` (a Fleshing rest spine along the
medial graph's longest path).
The deformation (binding in NumPy, posing in JAX): `footprint` (binding vertices to footprint
spheres), `pose` (`MedialPose`), `quaternions` (rotations as quaternions and back), `cells`
and `arap` (`arap_medial`), `skin` (medial / LBS / DQS skins), `implicit` (the
implicit-skinning correction), `rig` (`MedialRig`), `fit_handles` (handle targets fitted to
vertex targets), `deform` (`deform_medial`), `handle_files` (the command line's handle JSON).
"""
