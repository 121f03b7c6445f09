# The public names of fleshing_jax, each re-exported from the module that defines it. This stub is
# the one list of them: type checkers read it, and `__init__.py` loads each name from it on first
# use (so that `import fleshing_jax` and the command line's `--help` do not import JAX).

from . import data as data
from ._cache import compilation_cache_settings as compilation_cache_settings
from ._fit.chamfer import fit_spine_to_points as fit_spine_to_points
from ._fit.correspondences import fit_spine as fit_spine
from ._fit.problem import FitResult as FitResult
from ._fleshing.maps import cubic_root as cubic_root
from ._fleshing.methods import METHODS as METHODS
from ._fleshing.pipeline import (
    Fleshing as Fleshing,
    flesh as flesh,
    pose as pose,
    register as register,
)
from ._fleshing.projection import (
    Registration as Registration,
    closest_arc_length as closest_arc_length,
)
from ._fleshing.verify import (
    jacobian_determinant as jacobian_determinant,
    principal_stretch as principal_stretch,
)
from ._medial_axis.construct import medial_mesh as medial_mesh
from ._medial_axis.distance import medial_distance as medial_distance
from ._medial_axis.figure import plot_medial as plot_medial
from ._medial_axis.files import load_medial as load_medial, save_medial as save_medial
from ._medial_axis.medial_mesh import MedialMesh as MedialMesh
from ._medial_deform.arap import arap_medial as arap_medial
from ._medial_deform.deform import deform_medial as deform_medial
from ._medial_deform.fit_handles import fit_handles as fit_handles
from ._medial_deform.pose import MedialPose as MedialPose
from ._medial_deform.rig import MedialRig as MedialRig
from ._mesh.deform import deform_mesh as deform_mesh, flesh_chunked as flesh_chunked
from ._mesh.files import load_mesh as load_mesh, write_mesh_atomic as write_mesh_atomic
from ._mesh.holes import cap_holes as cap_holes
from ._mesh.shapes import (
    box_grid as box_grid,
    creature as creature,
    cube_cloud as cube_cloud,
    extrusion as extrusion,
    genus2_slab as genus2_slab,
    voxel_surface as voxel_surface,
)
from ._mesh.stretch import edge_stretch as edge_stretch
from ._mesh.volume import (
    face_volumes as face_volumes,
    triangulate as triangulate,
    volume as volume,
    volume_change as volume_change,
)
from ._skeleton.aim import aim as aim, nod as nod, turn as turn
from ._skeleton.build import skeleton as skeleton
from ._skeleton.files import load_skeleton as load_skeleton, save_skeleton as save_skeleton
from ._skeleton.fit_pose import SkeletonFit as SkeletonFit, fit_skeleton_pose as fit_skeleton_pose
from ._skeleton.joint_zone import joint_range as joint_range
from ._skeleton.limb_pose import LimbPose as LimbPose
from ._skeleton.plot import plot_skeleton as plot_skeleton
from ._skeleton.posing import (
    PosedSkeleton as PosedSkeleton,
    SkeletonRegistration as SkeletonRegistration,
    pose_skeleton as pose_skeleton,
    register_skeleton as register_skeleton,
)
from ._skeleton.rest_spine import rest_spine as rest_spine
from ._skeleton.skeleton import Limb as Limb, Skeleton as Skeleton
from ._skeleton.stretch import pose_stretch as pose_stretch
from ._spines.analytic import Arc as Arc, Helix as Helix, Line as Line
from ._spines.bent import BentSpine as BentSpine
from ._spines.bspline import BSpline as BSpline
from ._spines.files import load_spine as load_spine, save_spine as save_spine
from ._spines.frames import (
    frenet_frame as frenet_frame,
    rotation_minimizing_frame as rotation_minimizing_frame,
)
from ._spines.looked_up import LookedUpSpine as LookedUpSpine
from ._spines.parametric import AbstractParametricSpine as AbstractParametricSpine
from ._spines.polyline import Polyline as Polyline
from ._spines.polynomial import InterpolatingPolynomial as InterpolatingPolynomial
from ._spines.spine import AbstractSpine as AbstractSpine, initial_normal as initial_normal

__version__: str
