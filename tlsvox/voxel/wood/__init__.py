"""Wood, in one place: per voxel from the traced echoes, or solid from cylinders fitted to the wood echoes.

==================  ==================================================================================
module              what it holds
==================  ==================================================================================
:mod:`.voxels`      wood per voxel from the tracer's sums: the paper's stretched echo counts
                    (``count_stretch``) or a wood area density by the leaves' estimator (``voxlad``)
:mod:`.qsm`         cylinders fitted to the wood echoes (:func:`fit_cylinders`), the solid wood voxels
                    they fill (:func:`apply_cylinders`), bark echoes the classifier missed
                    (:func:`bark_echoes`)
:mod:`.solid`       the cells inside flat-ended cylinders, their surface and cap share, shared by the
                    synthetic tree's exact twin and :mod:`.qsm`
==================  ==================================================================================
"""

from tlsvox.voxel.wood.qsm import CylinderModel, apply_cylinders, bark_echoes, fit_cylinders, wood_points
from tlsvox.voxel.wood.solid import cap_share, cylinder_cells, cylinder_surface, dilate
from tlsvox.voxel.wood.voxels import WoodEstimate, WoodMethod, count_stretch, estimate_wood, wood_area_density

__all__ = ["CylinderModel", "WoodEstimate", "WoodMethod", "apply_cylinders", "bark_echoes", "cap_share",
           "count_stretch", "cylinder_cells", "cylinder_surface", "dilate", "estimate_wood", "fit_cylinders",
           "wood_area_density", "wood_points"]
