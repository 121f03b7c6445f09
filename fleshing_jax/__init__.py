"""fleshing_jax: spine-driven bending of 3D shapes with exact local volume preservation.

An implementation of "Fleshing: Spine-driven Bending with Local Volume Preservation"
(Zhuo & Rossignac, 2013) in JAX.

Layout, each layer importing only those before it: shared helpers (`_numerics`, `_checks`,
`_batching`) ← `_spines` ← `_fleshing` ← `_fit`, `_mesh` ← `_medial_axis` (the medial
mesh) ← `_medial_deform` (its deformation), `_skeleton` (Fleshing on the medial axis) ←
`_cli`, `_demo`; `data` (the example meshes) imports none of them.
This file only re-exports, lazily: the names are listed in `__init__.pyi` and each is
imported on first use (`lazy_loader`, SPEC 1 of the Scientific Python community).
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach_stub(__name__, __file__)

__version__ = "0.1.0"
