"""Co-registration of TLS scans, and georegistration to the airborne cloud.

Each scan comes in its own scanner frame.  :func:`register_pair` finds the
rigid transform ``T`` (4x4) that maps a *source* scan's scanner frame into
the *reference* scan's frame:

1. **Targets** (retro-reflectors read above 0 dB): bright small clusters
   (:func:`detect_targets`), their centres fitted to the known target shape;
   correspondences from inter-target distances, which a rigid motion keeps
   (:func:`match_targets`); a least-squares rigid fit (:func:`rigid_fit`,
   Kabsch/Umeyama).
2. **FPFH + RANSAC** (:func:`global_fpfh`) when there are no targets: Fast
   Point Feature Histograms (Rusu et al. 2009) matched by a seeded NumPy
   RANSAC (Fischler & Bolles 1981) -- repeatable, unlike Open3D's
   multithreaded one -- with a levelled model (yaw + translation from 2
   matches) for levelled scanners, run on disjoint parts of the matches,
   which must agree.
3. **ICP** (:func:`refine_icp`): point-to-plane, coarse to fine voxel sizes
   (Chen & Medioni 1992), with a robust (Tukey) loss.

The final transform is scored by *fitness* (the fraction of source points
with a reference point within a distance) and the inlier RMSE, and by
:func:`coincidence`: how much more often than by chance the two scans'
points lie within 15 mm of each other.  A transform whose fitness is below
``min_fitness`` -- also after removing the dominant plane (the ground), which
alone can align two unrelated scans -- or whose coincidence is not at least
twice the chance level raises :class:`RegistrationError` carrying the
figures: never a silent wrong answer.

:func:`~tlsvox.register.georegister.georegister` places the registered TLS
cloud in the airborne frame (the airborne cloud registered onto it).

Modules, one concept each: ``_transforms`` (rigid transforms and fits),
``_targets``, ``_features`` (FPFH + RANSAC), ``_icp`` (ICP and the scores),
``_pair`` (the pipeline's stages), ``settings`` (its settings), ``_files`` (merged cloud and transforms on disk),
``georegister``.
"""

from tlsvox.errors import RegistrationError
from tlsvox.register._features import global_fpfh
from tlsvox.register._files import read_transforms, write_registered
from tlsvox.register._icp import coincidence, refine_icp
from tlsvox.register._pair import RegistrationMethod, RegistrationResult, register_pair, register_scans
from tlsvox.register._targets import TargetShape, detect_targets, match_targets
from tlsvox.register._transforms import pose_error, rigid_fit, rotation_about_z, true_relative_transform
from tlsvox.register.georegister import georegister
from tlsvox.register.settings import RegisterSettings

__all__ = [
    "RegistrationError",
    "RegistrationMethod",
    "RegistrationResult",
    "RegisterSettings",
    "TargetShape",
    "coincidence",
    "detect_targets",
    "georegister",
    "global_fpfh",
    "match_targets",
    "pose_error",
    "read_transforms",
    "refine_icp",
    "register_pair",
    "register_scans",
    "rigid_fit",
    "rotation_about_z",
    "true_relative_transform",
    "write_registered",
]
