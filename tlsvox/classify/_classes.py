"""The classes an echo can get, and the truth material each corresponds to.
"""

from __future__ import annotations

import enum

from voxlidar.materials import Material


class PointClass(enum.IntEnum):
    """Class of an echo; values are the LAS ``classification`` codes written.

    Ground 2 and low noise 7 are ASPRS codes, leaf uses 5 (high vegetation),
    wood and target take user-definable codes (64, 65).
    """

    GROUND = 2
    LEAF = 5
    NOISE = 7
    WOOD = 64
    TARGET = 65


#: truth material -> the class a perfect classifier would give
TRUTH_CLASS = {
    Material.NONE: PointClass.NOISE,
    Material.LEAF: PointClass.LEAF,
    Material.BARK: PointClass.WOOD,
    Material.GROUND: PointClass.GROUND,
    Material.TARGET: PointClass.TARGET,
}
