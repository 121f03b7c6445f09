"""fleshing_jax: spine-driven bending of 3D shapes with exact local volume preservation.

An implementation of "Fleshing: Spine-driven Bending with Local Volume Preservation"
(Zhuo & Rossignac, 2013) in JAX.
"""

from ._analytic import Arc as Arc, Helix as Helix, Line as Line
from ._bspline import BSpline as BSpline
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
from ._parametric import AbstractParametricSpine as AbstractParametricSpine
from ._polyline import Polyline as Polyline
from ._polynomial import InterpolatingPolynomial as InterpolatingPolynomial
from ._projection import Registration as Registration, closest_arc_length as closest_arc_length
from ._spine import AbstractSpine as AbstractSpine, initial_normal as initial_normal
from ._verify import jacobian_determinant as jacobian_determinant

__version__ = "0.1.0"
