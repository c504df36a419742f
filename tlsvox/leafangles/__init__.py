"""The leaf angle distribution measured from the scans, per crown layer.

The paper's first preprocessing step needs the leaf inclination distribution
for G(theta); the paper took it from photographs.  Here it comes from the leaf
echoes' local geometry:

1. **Plane fits.**  Each leaf echo's neighbours within a leaf-scale radius
   (default 2.5 cm, half a leaf length), in the world frame, one scan at a
   time, give a covariance matrix; its smallest eigenvector is the leaf
   normal, folded to the upper hemisphere; its zenith angle is the leaf
   inclination ``t``.
2. **Visibility.**  A leaf whose normal makes the angle ``a`` with the beam is
   hit in proportion to ``|cos a|``, and the echo density falls as 1/r^2, so
   an echo stands for a leaf area proportional to ``r^2 / |cos a|``.  Fits
   nearer edge-on than ``|cos a| = cap`` (0.2) are dropped: there the normal
   is set by the errors along the beam (range noise, and echoes whose
   sub-rays met a leaf and whatever lies just behind or in front of it),
   which pile up normals perpendicular to the beam with the largest weights.
3. **The measurement, simulated and inverted** (``method="deconvolve"``, the
   default).  At leaf scale the range noise (5 mm on the VZ-400, along the
   beam) is comparable with the spread of a leaf's echoes (about 7 mm); a
   wide beam's partial hits put the echo on the pulse's central direction;
   sub-rays on a leaf and on what lies behind it merge into one echo between
   the two (within the range resolution); and leaves are seen in part.  So
   single normals scatter by tens of degrees and the weighted histogram is
   biased.  The default models the measurement: for every true inclination
   bin, leaves of that inclination are scanned in simulation around sampled
   echoes (their range, beam and outward direction) on the scan's angular
   grid by the instrument's beam (its sub-rays stop on the first leaf they
   meet; each pulse gives one echo on its central direction at the
   power-weighted mean range of its sub-rays' hits, with the range noise),
   and fitted, weighted and dropped as the measured ones are.  Each simulated
   leaf draws an occlusion level: whole, cut by one or two straight edges
   (others hide part of it), or with a second leaf behind it in one of four
   distance bands (0-2.5, 2.5-5, 5-10, 10-25 cm; ``second_leaf``); and it
   faces a random azimuth or away from the crown centre (the trunk's axis,
   :func:`trunk_center` of the wood echoes at its base; ``azimuth``).  An
   echo's observation is its measured inclination bin, the azimuth of its
   normal from the outward direction (4 classes) and its neighbour count
   (7 classes), or the count alone when it has no fit.  The expected
   histogram of the observations is linear in the leaf-area distribution for
   given shares of the occlusion levels and azimuth models, and all are
   fitted by maximum likelihood (EM): the azimuth models' shares first, per
   layer, together with the rest; then each layer keeps the model with the
   larger share (a mixture of the two read the four planophile crowns
   0.7-1.9 deg steeper than the right model alone), and its distribution and occlusion mix (per
   scan and layer) are fitted with that model.  The sampled echoes stand for
   the leaf area around them, so each weighs r^2 in the simulation.  Everything
   is simulated per scan and crown layer (the upper layers are farther from
   ground scanners, seen more steeply and more hidden); the crown's
   distribution is the one that explains every layer's rows together.
   ``method="weighted"`` is step 2 alone.

Accuracy (``benchmarks/bench_leaf_angles.py``, docs/bench/leaf_angles*.md):
on the oak's two VZ-400 scans (7-sub-ray beam, 5 mm range noise) with
uniform, planophile and erectophile leaves, facing outwards (the paper's oak)
or random azimuths, on two oaks (seeds 0 and 1), every crown's mean
inclination is within 3.1 deg and its G within 3.9 % over the scanned
zenith angles, and 46 of the 48 layers are within 5 deg and 5 %; the two
others are erectophile layers that miss on G alone (6.2 and 5.2 %, means
within 3.5 deg).  Uniform and erectophile crowns read 1.2-3.1 deg flat,
planophile ones -0.6 to +1.4 deg (docs/bench/leaf_angle_kernel.md: the
kernel measures 30-75 deg leaves 1-4 deg steeper than the scans do).  Each
layer's azimuth model is the right one on all four oaks.  Two scans take
44-58 s (2 cores) and 1.3-1.4 GiB.

**Limits.**  One trunk: the outward model faces leaves away from one vertical
axis.  The simulated leaves are flat ellipses of ``leaf_size``, and a second
leaf behind the first has the first's inclination bin.

The crown is cut into ``layers`` equal-height layers between the 1st and 99th
height percentiles of the leaf echoes with a plane fit; every layer gets its
histogram, mean inclination and a beta distribution (Goel & Strebel 1984)
fitted by moments, a :class:`~voxlidar.leaf_orientation.LeafAngle` usable as
``voxelize(leaf_angle=...)`` and stored in the scene file like any other.

Examples
--------
>>> from tlsvox.leafangles import fit_beta
>>> la = fit_beta(np.full(18, 1 / 18))  # a flat histogram: the uniform distribution
>>> round(la.mu, 2), round(la.nu, 2)
(1.0, 1.0)

References
----------
Goel, N. S. & Strebel, D. E. (1984). Simple beta distribution representation
    of leaf orientation in vegetation canopies. Agronomy Journal 76(5), 800-802.
    doi:10.2134/agronj1984.00021962007600050021x
Kasa, I. (1976). A circle fitting procedure and its error analysis. IEEE
    Transactions on Instrumentation and Measurement 25(1), 8-14.
Richardson, W. H. (1972). Bayesian-based iterative method of image
    restoration. JOSA 62(1), 55-59. doi:10.1364/JOSA.62.000055
Bailey, B. N. & Mahaffee, W. F. (2017). Rapid measurement of the
    three-dimensional distribution of leaf orientation and the leaf angle
    probability density function using terrestrial LiDAR scanning. Remote
    Sensing of Environment 194, 63-76. doi:10.1016/j.rse.2017.03.011
"""

from __future__ import annotations

import numpy as np  # noqa: F401  (the doctest above uses np)

from tlsvox.leafangles._histogram import fit_beta, histogram_G
from tlsvox.leafangles._layers import LayerLeafAngles, LeafAngleMeasurement
from tlsvox.leafangles._measure import LeafAngleMethod, measure_leaf_angles
from tlsvox.leafangles._planes import trunk_center
from tlsvox.leafangles.settings import (
    DeconvolutionSettings,
    HistogramSettings,
    InstrumentSettings,
    LeafAngleSettings,
    PlaneFitSettings,
)

__all__ = ["LeafAngleMethod", "LayerLeafAngles", "LeafAngleMeasurement", "LeafAngleSettings", "HistogramSettings",
           "PlaneFitSettings", "InstrumentSettings", "DeconvolutionSettings", "measure_leaf_angles", "fit_beta",
           "histogram_G", "trunk_center"]
