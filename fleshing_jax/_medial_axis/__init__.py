"""The medial axis of a mesh (Q-MAT, Li et al. 2015; Sun et al. 2013): medial spheres joined
into cones and slabs, the first half of "Medial-axis-driven shape deformation with volume
preservation" (Lan et al. 2017).

Imports the shared helpers and `_mesh`. NumPy/SciPy preprocessing, one concept a module:
`surface` (closed-mesh checks, samples, exact closest points and signs), `weld` (texture
seams welded), `shells` (a mesh's shells: nesting, orientation, crossings), `voronoi` (the
initial medial axis: inner Voronoi complex of the samples), `connect` (its pieces joined),
`simplify` (Q-MAT's sphere-quadric edge collapses), `refine` (the spheres fitted to the surface
after the collapses: our own addition), `construct` (`medial_mesh`), `medial_mesh`
(`MedialMesh`), `primitives` (closed-form distances to spheres, cones, slabs and their union),
`envelope` (marching tetrahedra of the union), `distance` (`medial_distance`), `files` (`.ma`
files), `figure` (`plot_medial`), `animal` (a thin-limbed test shape).
"""
