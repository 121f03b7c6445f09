"""Medial-axis-driven deformation with volume preservation (Lan et al. 2017): a surface bound to
the spheres of a medial mesh (`_medial_axis`), moved as rigidly as possible by handles.

Imports the shared helpers, `_fit`, `_mesh` and `_medial_axis`. Binding in NumPy, posing in
JAX, one concept a module: `footprint` (binding vertices to footprint spheres), `pose`
(`MedialPose`), `quaternions` (rotations as quaternions and back), `cells` and `arap`
(`arap_medial`), `skin` (medial / LBS / DQS skins), `implicit` (the implicit-skinning
correction), `rig` (`MedialRig`), `fit_handles` (handle targets fitted to vertex targets),
`deform` (`deform_medial`), `handle_files` (the command line's handle JSON).
"""
