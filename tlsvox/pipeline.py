"""The whole first half of the paper in one call: scans -> voxel scene.

register (targets, else FPFH + ICP) -> classify (leaf / wood / ground / noise)
-> cylinders fitted to the wood echoes (:mod:`tlsvox.voxel.wood.qsm`; leaf-classed echoes
on their bark relabelled wood) -> beam tracing and LAD estimation
(:func:`tlsvox.voxel.stages`) -> the cylinders fill solid wood voxels -> Scene.

Georeferencing: registration puts every scan in the reference scan's frame.
To place the scene in the world (the airborne frame) the reference scan needs
a pose: with real data it comes from GNSS / total station, or from
:mod:`tlsvox.register.georegister` against the airborne point cloud; for a simulated scan
``georeference="true"`` uses its true pose (``pose_true``), which is the role
those tools play.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError

__all__ = ["PipelineResult", "scene_from_scans"]


@dataclass
class PipelineResult:
    """What :func:`scene_from_scans` made, stage by stage."""

    scene: object
    registration: list
    classifications: list
    voxelized: object
    timings: dict = field(default_factory=dict)
    cylinders: object = None  #: the tlsvox.voxel.wood.qsm.CylinderModel fitted (None with qsm=False)

    def summary(self) -> dict:
        reg = [r.to_dict() if r is not None else None for r in self.registration]
        for r in reg:
            if r is not None:
                r.pop("stages", None)
        doc = {"registration": reg, "classification": [c.summary() for c in self.classifications],
               "timings_s": self.timings}
        if self.cylinders is not None:
            doc["qsm"] = (self.scene.meta or {}).get("qsm", self.cylinders.summary())
        return doc


def scene_from_scans(scans, *, voxel_size: float = 0.2, estimator: str = "bcmle", leaf_angle="uniform",
                     leaf_azimuth: str = "outward", refine: bool = True, georeference: str = "true",
                     register_kwargs=None, voxelize_kwargs=None, qsm: bool = True, qsm_kwargs=None,
                     qsm_relabel: bool = True, progress: bool = True) -> PipelineResult:
    """Register, classify and voxelise a set of scans of one tree.

    Parameters
    ----------
    scans : list of tlsvox.scan.Scan
        Scans in their own scanner frames (``pose`` unknown).
    voxel_size : float, metres
    estimator : {"bcmle", "voxlad", "beer_lambert", "contact_frequency"}
    leaf_angle, leaf_azimuth
        Leaf angle model for G(theta) and for the simulator.
    refine : bool
        Geometric (linearity) refinement of the wood class.
    georeference : {"true", "none"}
        ``true``: the reference scan (the first) takes its ``pose_true``
        (simulated scans); ``none``: the scene stays in the first scan's frame.
    register_kwargs, voxelize_kwargs : dict, optional
        Passed to :func:`tlsvox.register.register_scans` and :func:`tlsvox.voxel.stages`.
    qsm : bool
        Fit cylinders to the wood-classified echoes (:func:`tlsvox.voxel.wood.qsm.fit_cylinders`)
        and fill solid wood voxels from them (:func:`tlsvox.voxel.wood.qsm.apply_cylinders`);
        wood echoes no cylinder explains stay turbid wood.  Default on
        (docs/voxelize.md, "Solid wood from fitted cylinders", measures it).
    qsm_kwargs : dict, optional
        Passed to :func:`tlsvox.voxel.wood.qsm.fit_cylinders`.
    qsm_relabel : bool
        With ``qsm``: leaf-classed echoes on a fitted cylinder's bark
        (:func:`tlsvox.voxel.wood.qsm.bark_echoes`) are relabelled wood before the scans
        are voxelised (each classification's ``on_cylinders`` counts them), so
        bark the classifier missed is not counted as leaf area.  The cylinders
        are fitted to the classifier's wood echoes, before the relabelling;
        the scene's turbid wood and ``apply_cylinders`` (its
        ``wood_echoes_explained`` too) see the wood echoes after it.

    Returns
    -------
    PipelineResult
    """
    from tlsvox.classify import classify_scan
    from tlsvox.register import register_scans
    from tlsvox.voxel.stages import voxelize

    scans = list(scans)
    if len(scans) < 1:
        raise InputError("scans is empty: pass the scans of one tree")
    if georeference not in ("true", "none"):
        raise InputError(f"georeference={georeference!r} must be 'true' or 'none'")
    from tlsvox.voxel.estimators import FillMode
    from tlsvox.voxel.fills import check_calibration_scans

    if FillMode.parse((voxelize_kwargs or {}).get("fill", "none"), "fill") is FillMode.CALIBRATED:
        check_calibration_scans(len(scans))  # said before registration, classification and the cylinders run
    timings = {}
    ref = scans[0]
    if georeference == "true":
        if ref.pose_true is None:
            raise InputError(f"georeference='true' needs the reference scan's pose_true; {ref.name!r} has none. "
                             "Use georeference='none' or set scans[0].pose from GNSS / tlsvox.register.georegister")
        ref.pose = np.array(ref.pose_true)
    t0 = time.perf_counter()
    registration = register_scans(scans, **(register_kwargs or {})) if len(scans) > 1 else [None]
    timings["register"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    classes = [classify_scan(s, refine=refine) for s in scans]
    timings["classify"] = time.perf_counter() - t0
    model = None
    if qsm:
        from tlsvox.voxel.wood.qsm import bark_echoes, fit_cylinders, wood_points

        t0 = time.perf_counter()
        model = fit_cylinders(wood_points(scans, [c.labels for c in classes], class_codes="pointclass"),
                              **(qsm_kwargs or {}))
        if qsm_relabel:
            barks = bark_echoes(scans, model, [c.labels for c in classes])
            classes = [c.with_bark(bark) for c, bark in zip(classes, barks)]
        timings["qsm"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    vox = voxelize(scans, voxel_size=voxel_size, classes=[c.labels for c in classes], class_codes="pointclass",
                   leaf_angle=leaf_angle, leaf_azimuth=leaf_azimuth, estimator=estimator, progress=progress,
                   **(voxelize_kwargs or {}))
    timings["voxelize"] = time.perf_counter() - t0
    scene = vox.scene
    if qsm:
        from tlsvox.voxel.wood.qsm import apply_cylinders

        t0 = time.perf_counter()
        scene, _ = apply_cylinders(scene, model, wood_points(scans, [c.labels for c in classes],
                                                             class_codes="pointclass"))
        timings["qsm"] += time.perf_counter() - t0
    return PipelineResult(scene=scene, registration=registration, classifications=classes, voxelized=vox,
                          timings=timings, cylinders=model)
