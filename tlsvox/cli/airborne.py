"""``tlsvox voxelize`` on airborne full-waveform files: a plant-area scene from ALS pulses.

A NEON record folder (``return.csv`` and its geolocation) or a LAS 1.3/1.4
file with waveform packets is read as pulses (:func:`clsim.replay.read_measured`:
positions rebuilt from the scan geometry, the sensor's flight fitted to the
packets' lines), its echoes taken from the waveforms' template decomposition
or the file's discrete returns (:func:`clsim.replay.scene_echoes`), weighted
by their energy against a full hit's or 1/n, traced as beams and estimated
(:func:`clsim.replay.scene_from_pulses`, :func:`tlsvox.voxel.airborne.voxelize_beams`).

This is the one place where ``tlsvox`` uses ``clsim``: the waveform readers
and the decomposition live there; they are imported only when an airborne
file is given, so ``import tlsvox`` still loads no ``clsim`` module.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError, TlsvoxError

__all__ = ["TLS_ONLY", "airborne_kind", "run_airborne"]

#: Options of ``tlsvox voxelize`` that mean nothing for airborne pulses (dest: flag).
TLS_ONLY = {"transforms": "--transforms", "scanner_frame": "--scanner-frame", "angular_grid": "--angular-grid",
            "scanner_rpy": "--scanner-rpy", "max_range": "--max-range", "scan_origin": "--scan-origin",
            "qsm": "--qsm", "qsm_keep_labels": "--qsm-keep-labels", "fill": "--fill", "undetected": "--undetected",
            "lad_voxel_size": "--lad-voxel-size", "leaf_angle_by_layer": "--leaf-angle-by-layer",
            "leaf_azimuth": "--leaf-azimuth", "wood": "--wood", "layout": "--layout",
            "leaf_reflectance": "--leaf-reflectance", "wood_reflectance": "--wood-reflectance",
            "detection_threshold_db": "--detection-threshold-db", "plan": "--plan", "config": "--config",
            "write_config": "--write-config", "ground_tolerance": "--ground-tolerance"}
#: LAS point formats that carry a waveform packet.
WAVEFORM_FORMATS = (4, 5, 9, 10)


def airborne_kind(path) -> str | None:
    """``"neon"``, ``"las-waveform"`` or None (a terrestrial scan) for one SCAN argument."""
    p = Path(path)
    if p.is_dir():
        return "neon" if (p / "return.csv").is_file() else None
    if p.name.lower() == "return.csv" and p.is_file():
        return "neon"
    if p.suffix.lower() in (".las", ".laz") and p.is_file():
        import laspy

        try:
            with laspy.open(p) as f:
                fmt = f.header.point_format.id
        except Exception:  # noqa: BLE001 - not readable as LAS: the scan reader says why
            return None
        return "las-waveform" if fmt in WAVEFORM_FORMATS else None
    return None


def _refuse_tls_options(args, parser_defaults: dict) -> None:
    given = [flag for dest, flag in TLS_ONLY.items()
             if dest in parser_defaults and getattr(args, dest, None) != parser_defaults[dest]]
    if args.leaf_angle == "measured":
        given.append("--leaf-angle measured")
    if args.echo_weights == "threshold":
        given.append("--echo-weights threshold")
    if given:
        raise InputError(f"{', '.join(given)}: terrestrial-scan option(s), not for airborne pulses; drop them "
                         "(tlsvox voxelize --help, airborne files)")


def run_airborne(args, parser_defaults: dict) -> int:
    """Voxelise one airborne file (``args.scans[0]``) into ``args.output``; returns the exit code."""
    import time

    from voxlidar.safeio import check_outputs, json_text, staged

    if len(args.scans) != 1:
        raise InputError(f"give one airborne file at a time (got {len(args.scans)} inputs); airborne and "
                         "terrestrial scans are not voxelised together")
    _refuse_tls_options(args, parser_defaults)
    src = Path(args.scans[0])
    if Path(args.output).suffix.lower() != ".npz":
        raise InputError(f"-o {args.output} must end in .npz (the scene file); --vox PATH adds an AMAPVox .vox")
    if args.vox is not None and Path(args.vox).suffix.lower() != ".vox":
        raise InputError(f"--vox {args.vox} must end in .vox")
    files = sorted(src.iterdir()) if src.is_dir() else [src, src.with_suffix(".wdp")]
    check_outputs([("airborne file", f) for f in files], [("-o", args.output), ("--vox", args.vox)])
    if not (np.isfinite(args.voxel_size) and 0 < args.voxel_size <= 100):
        raise InputError(f"--voxel-size {args.voxel_size} must be a size in metres above 0 (e.g. 0.5 for airborne "
                         "pulses about 0.4 m apart)")
    if args.divergence_mrad is not None and not (np.isfinite(args.divergence_mrad) and args.divergence_mrad > 0):
        raise InputError(f"--divergence-mrad {args.divergence_mrad} must be a half angle above 0 mrad (e.g. 0.25)")
    if not (np.isfinite(args.beams_per_footprint) and args.beams_per_footprint > 0):
        raise InputError(f"--beams-per-footprint {args.beams_per_footprint} must be > 0 (e.g. 3)")
    from clsim.replay import pool_sigma, prepare, read_measured, scene_echoes, scene_from_pulses

    t0 = time.perf_counter()
    measured = read_measured(src, divergence_mrad=args.divergence_mrad)
    prepared = prepare(measured)
    weights = "uniform" if args.echo_weights == "uniform" else "energy"
    echoes = scene_echoes(prepared, source=args.airborne_echoes, weights=weights)
    every = np.arange(len(measured))
    pool = pool_sigma(echoes, every, args.beams_per_footprint)
    tracer = None
    if args.device:
        from tlsvox.voxel.trace import Tracer

        tracer = Tracer(args.device)
    bounds = None if args.bounds is None else np.reshape(args.bounds, (2, 3))
    scene = scene_from_pulses(echoes, every, voxel_size=args.voxel_size, pool_m=pool,
                              n_min=1 if args.n_min is None else args.n_min, estimator=args.estimator or "beer_lambert",
                              ground=args.ground or "none", bounds=bounds, tracer=tracer, progress=not args.quiet,
                              return_path="turbid" if args.no_hotspot else "hotspot")
    air = scene.meta["airborne"]
    air.update(source=str(src), reader=measured.meta.get("source", "NEON records"), pulses=len(measured),
               echo_source=args.airborne_echoes, echo_weights=weights, pulse_shape=prepared.shape_source,
               divergence_mrad=float(measured.divergence_mrad), beams_per_footprint=float(args.beams_per_footprint),
               geometry=measured.meta.get("geometry"))
    warnings = scene.meta.setdefault("warnings", [])
    if air["occluded_voxels"] > 0.5 * max(air["voxels"], 1):
        warnings.append(f"{air['occluded_voxels']} of {air['voxels']} voxels are occluded (below where the records "
                        f"end, or crossed by too few pulses for {args.voxel_size:g} m voxels); raise --voxel-size or "
                        "--beams-per-footprint if the canopy itself is occluded")
    for w in warnings:
        print(f"tlsvox voxelize: warning: {w}", file=sys.stderr)
    if args.strict and warnings:
        raise TlsvoxError(f"{len(warnings)} quality warning(s) with --strict; nothing was written (drop --strict to "
                          "keep the result)")
    with staged([args.output, args.vox]) as tmp:
        scene.save(tmp[args.output])
        if args.vox:
            from tlsvox.voxel.amapvox import write_vox

            write_vox(scene, tmp[args.vox])
    if not args.quiet:
        print(json_text({"output": str(args.output), "input": str(src), "pulses": len(measured),
                         "grid": list(scene.shape), "voxel_size": scene.voxel_size, "voxels_stored": scene.n_voxels,
                         "plant_area_m2": round(scene.total_leaf_area(), 3), "estimator": scene.meta["estimator"],
                         "echoes": {"source": args.airborne_echoes, "weights": weights, "count": air["echoes"],
                                    "ground": air.get("ground_echoes", 0)},
                         "ground_z": scene.ground_z, "pool_m": round(pool, 3), "occluded_voxels": air["occluded_voxels"],
                         "note": air["note"], "seconds": round(time.perf_counter() - t0, 2)}, indent=1))
    return 0
