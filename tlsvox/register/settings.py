"""The settings of :func:`~tlsvox.register.register_pair`, in four groups, and their TOML file.

==============  ================================================================  =============================
group           fields                                                            the stage that reads it
==============  ================================================================  =============================
``coarse``      method, global_voxel_m, n_hypotheses, min_consensus,              the coarse alignment by
                consensus_rot_deg, consensus_trans_m, ransac_samples, levelled,   features (FPFH + RANSAC)
                seed
``targets``     target_tolerance_m, target_shape, target_radius_m,                the coarse alignment by
                min_target_reflectance_db, icp_after_targets                      targets
``icp``         voxel_sizes                                                       the ICP refinement
``acceptance``  min_fitness, min_coincidence_ratio, coincidence_m                 the acceptance test
==============  ================================================================  =============================

A start transform (``init=``) is data, not a setting: it is passed beside
them. ``RegistrationResult.settings`` records them in full.

Examples
--------
>>> s = RegisterSettings.from_kwargs(method="fpfh", voxel_sizes=[0.3, 0.1])
>>> s.coarse.method, s.icp.voxel_sizes, s.acceptance.min_fitness
('fpfh', (0.3, 0.1), 0.25)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from tlsvox.grouped import GroupedSettings

__all__ = ["AcceptanceSettings", "CoarseSettings", "IcpSettings", "RegisterSettings", "TargetSettings"]


@dataclass(frozen=True)
class CoarseSettings:
    """The coarse alignment: which method, and the feature matching's RANSAC."""

    method: str = "auto"  #: "auto", "targets", "fpfh" or "icp"
    global_voxel_m: float = 0.3  #: voxel of the FPFH + RANSAC stage, metres
    n_hypotheses: int = 5  #: best distinct RANSAC peaks kept
    min_consensus: int = 1  #: least group size tried
    consensus_rot_deg: float = 1.0  #: hypotheses within this rotation converge together
    consensus_trans_m: float = 0.1  #: and within this translation
    ransac_samples: int = 200_000  #: minimal samples per RANSAC run
    levelled: bool = True  #: scanners levelled: RANSAC fits yaw and translation
    seed: int = 0  #: seeds the RANSAC samples and the coincidence sample


@dataclass(frozen=True)
class TargetSettings:
    """The coarse alignment by retro-reflective targets."""

    target_tolerance_m: float = 0.03  #: matched target distances agree within this
    target_shape: str = "cylinder"  #: "cylinder", "sphere" or "flat"
    target_radius_m: float = 0.05
    min_target_reflectance_db: float = 0.0  #: brighter echoes are target candidates
    icp_after_targets: bool = False  #: refine a target fit with ICP


@dataclass(frozen=True)
class IcpSettings:
    """The ICP refinement."""

    voxel_sizes: tuple = (0.2, 0.08, 0.03)  #: ICP scales, coarse to fine, metres


@dataclass(frozen=True)
class AcceptanceSettings:
    """The test a registration must pass."""

    min_fitness: float = 0.25  #: least fitness, on all points and off the dominant plane
    min_coincidence_ratio: float = 2.0  #: least coincident points against chance
    coincidence_m: float = 0.015  #: points this near coincide, metres


@dataclass(frozen=True)
class RegisterSettings(GroupedSettings):
    """Every setting of a :func:`~tlsvox.register.register_pair` run, in four groups (module docstring)."""

    GROUPS: ClassVar[dict[str, type]] = {"coarse": CoarseSettings, "targets": TargetSettings, "icp": IcpSettings,
                                         "acceptance": AcceptanceSettings}
    LABEL: ClassVar[str] = "register"

    coarse: CoarseSettings = field(default_factory=CoarseSettings)
    targets: TargetSettings = field(default_factory=TargetSettings)
    icp: IcpSettings = field(default_factory=IcpSettings)
    acceptance: AcceptanceSettings = field(default_factory=AcceptanceSettings)
