"""fleshing_jax: spine-driven bending of 3D shapes with exact local volume preservation.

An implementation of "Fleshing: Spine-driven Bending with Local Volume Preservation"
(Zhuo & Rossignac, 2013) in JAX.
"""

from ._analytic import Arc as Arc, Helix as Helix, Line as Line
from ._bspline import BSpline as BSpline
from ._chamfer import fit_spine_to_points as fit_spine_to_points
from ._fit import fit_spine as fit_spine
from ._fit_common import FitResult as FitResult
from ._fleshing import (
    Fleshing as Fleshing,
    flesh as flesh,
    pose as pose,
    register as register,
)
from ._frames import (
    frenet_frame as frenet_frame,
    rotation_minimizing_frame as rotation_minimizing_frame,
)
from ._io import load_spine as load_spine, save_spine as save_spine
from ._maps import METHODS as METHODS, cubic_root as cubic_root
from ._mesh import (
    cap_holes as cap_holes,
    deform_mesh as deform_mesh,
    flesh_chunked as flesh_chunked,
    load_mesh as load_mesh,
    write_mesh_atomic as write_mesh_atomic,
)
from ._parametric import AbstractParametricSpine as AbstractParametricSpine
from ._polyline import Polyline as Polyline
from ._polynomial import InterpolatingPolynomial as InterpolatingPolynomial
from ._projection import Registration as Registration, closest_arc_length as closest_arc_length
from ._shapes import (
    box_grid as box_grid,
    creature as creature,
    cube_cloud as cube_cloud,
    extrusion as extrusion,
    genus2_slab as genus2_slab,
    voxel_surface as voxel_surface,
)
from ._spine import AbstractSpine as AbstractSpine, initial_normal as initial_normal
from ._verify import jacobian_determinant as jacobian_determinant
from ._volume import (
    face_volumes as face_volumes,
    triangulate as triangulate,
    volume as volume,
    volume_change as volume_change,
)

__version__ = "0.1.0"
