"""fleshing_jax: spine-driven bending of 3D shapes with exact local volume preservation.

An implementation of "Fleshing: Spine-driven Bending with Local Volume Preservation"
(Zhuo & Rossignac, 2013) in JAX.
"""

from ._analytic import Arc as Arc, Helix as Helix, Line as Line
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
from ._maps import METHODS as METHODS, cubic_root as cubic_root
from ._projection import Registration as Registration, closest_arc_length as closest_arc_length
from ._spine import AbstractSpine as AbstractSpine, initial_normal as initial_normal
from ._verify import jacobian_determinant as jacobian_determinant

__version__ = "0.1.0"
