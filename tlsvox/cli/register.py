"""``tlsvox register`` and ``tlsvox classify``: sub-commands over the library.

:func:`register` adds both sub-commands to an ``argparse`` sub-parser set;
each sets ``func`` to its handler, which takes the parsed namespace and
returns an exit status (0 = success, 1 = a clear failure printed to stderr).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError, TlsvoxError
from tlsvox.scan import sidecar_paths
from voxlidar.cli import number
from voxlidar.safeio import check_distinct, check_figure_path, check_outputs, json_text

__all__ = ["register", "cmd_register", "cmd_classify"]

_REGISTER_HELP = """\
Co-register two or more scans of one plot and merge them.

Every scan is registered to the first one (the reference): retro-reflective
targets when three or more are seen by both scans (bright clusters above
0 dB), otherwise FPFH features + RANSAC, refined by point-to-plane ICP.  A
result that cannot be trusted (no consensus, low fitness) stops with the
fit figures instead of writing a wrong cloud.

Writes the merged cloud (LAS 1.4, reference frame, point_source_id = scan id)
and a JSON with each scan's 4x4 pose and fit figures (fitness, inlier RMSE,
and, for simulated scans, the error against the true pose).
"""

_CLASSIFY_HELP = """\
Classify the echoes of each scan as leaf, wood, noise, ground or target.

Per scan: two or three Gaussians fitted to the reflectance of the vegetation
echoes (chosen by BIC, --components), leaf/wood threshold midway
between the leaf and wood means (or at equal posterior),
optional geometric refinement of branch edges.  Methods (--method):
neighbourhood (default) fits the mean dB reflectance of each echo and its
10 nearest neighbours, on the echoes of single-echo pulses, and calls an
echo noise when it has no neighbour within 10 scan-grid steps; echo does the
same per echo; paper is the paper's rule (noise below 50 %% of the nominal
leaf reflectance); geometric needs no reflectance (x, y, z only): it fits the
Gaussians to a wood score, the linearity + planarity x verticality of the
points within 0.3 m (branches line up, stems stand upright, leaves scatter).
Raw intensity: --intensity relative, or --calibration CSV (a reference
target's intensity against range).  Writes OUT/NAME.classified.laz per scan (LAS
classification: 2 ground, 5 leaf, 7 noise, 64 wood, 65 target) and
OUT/classification.json with thresholds, fits and, for simulated scans,
the confusion matrix and precision/recall against the truth.
"""


def register(subparsers) -> None:
    """Add the ``register`` and ``classify`` sub-commands to ``subparsers``."""
    from tlsvox.classify import ClassifyMethod, ThresholdRule
    from tlsvox.register import RegistrationMethod

    p = subparsers.add_parser("register", help="co-register scans and merge them",
                              description=_REGISTER_HELP,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scans", nargs="+", metavar="SCAN", help="scan files (LAS/LAZ/PLY/PCD/XYZ); the first is the reference")
    p.add_argument("-o", "--output", required=True, help="merged cloud, .las or .laz")
    p.add_argument("--transforms", default=None, help="JSON of poses and fit figures (default: OUTPUT with .transforms.json)")
    p.add_argument("--method", default="auto", choices=[m.value for m in RegistrationMethod if m is not RegistrationMethod.ICP],
                   help="coarse alignment (default: auto = targets, else FPFH)")
    p.add_argument("--min-fitness", type=number(lo=0, hi=1), default=0.25, help="least accepted fitness (default 0.25)")
    p.add_argument("--icp-after-targets", action="store_true", help="also refine a target fit by ICP")
    p.add_argument("--seed", type=int, default=0, help="first RANSAC seed (default 0)")
    p.set_defaults(func=cmd_register)

    c = subparsers.add_parser("classify", help="leaf/wood/noise classification by reflectance or geometry",
                              description=_CLASSIFY_HELP,
                              formatter_class=argparse.RawDescriptionHelpFormatter)
    c.add_argument("scans", nargs="+", metavar="SCAN",
                   help="scan files with reflectance (dB) or intensity (x, y, z only with --method geometric)")
    c.add_argument("-o", "--output", required=True, help="output folder")
    c.add_argument("--rule", default="midway", choices=[r.value for r in ThresholdRule],
                   help="leaf/wood threshold rule (default: midway, the paper's)")
    c.add_argument("--components", default="bic", type=_components,
                   help="Gaussians fitted to the reflectances: bic (default: the better of 2 and 3 by the "
                        "Bayesian information criterion) or an integer >= 2 (2: the paper's fit)")
    c.add_argument("--method", default="neighbourhood", choices=[m.value for m in ClassifyMethod],
                   help="classification method (default: neighbourhood)")
    c.add_argument("--incidence-correction", action="store_true",
                   help="divide reflectance by the estimated incidence cosine before the fit")
    c.add_argument("--refine", action="store_true", help="geometric refinement of branch edges")
    c.add_argument("--no-ground", action="store_true", help="do not set the ground plane apart")
    c.add_argument("--intensity", choices=["calibrated", "relative"], default="calibrated",
                   help="calibrated (default): reflectance (dB) as the scan holds it; relative: raw intensity, "
                        "range-normalised and divided by the scan's median (the leaf/wood split does not depend "
                        "on the scale; targets are echoes 10 times the median or brighter; stated in "
                        "classification.json)")
    c.add_argument("--calibration", type=Path, default=None, metavar="CSV",
                   help="raw intensity to reflectance: a CSV with columns range_m,intensity of a reference target "
                        "(header row), its reflectance --reference-reflectance")
    c.add_argument("--reference-reflectance", type=number(lo=0, lo_open=True), default=None,
                   help="with --calibration: the reference target's Lambertian reflectance (default 1.0; "
                        "Spectralon 0.99)")
    c.add_argument("--plot", type=Path, default=None, metavar="PATH",
                   help="also write the reflectance histograms (paper Fig. 3) to PATH (.png, .pdf, .svg, .jpg)")
    c.set_defaults(func=cmd_classify)



def cmd_register(args) -> int:
    """Handler of ``tlsvox register``."""
    from tlsvox.readers import read_any
    from tlsvox.register import register_scans, write_registered

    out = Path(args.output)
    if out.suffix.lower() not in (".las", ".laz"):
        raise InputError(f"-o {out} must end in .las or .laz (the merged registered cloud)")
    check_distinct("scan", args.scans)
    check_outputs(_scan_inputs(args.scans),
                  [("-o", out), ("--transforms", Path(args.transforms) if args.transforms
                                 else out.with_suffix(".transforms.json"))])
    scans = [read_any(p, scan_id=k) for k, p in enumerate(args.scans)]
    if len(scans) < 2:
        raise TlsvoxError(f"register needs at least 2 scans, got {len(scans)}")
    results = register_scans(scans, method=args.method, min_fitness=args.min_fitness,
                             icp_after_targets=args.icp_after_targets, seed=args.seed)
    las, js = write_registered(args.output, scans, results=results, transforms_path=args.transforms)
    for r in results:
        if r is None:
            continue
        line = (f"{r.source} -> {r.reference}: {r.method}, fitness {r.fitness:.3f}, "
                f"inlier RMSE {r.inlier_rmse_m * 1000:.1f} mm")
        if r.error_vs_truth:
            line += (f"; vs truth {r.error_vs_truth['rotation_deg']:.4f} deg, "
                     f"{r.error_vs_truth['translation_m'] * 1000:.1f} mm")
        print(line)
    print(f"wrote {las} and {js}")
    return 0


def _components(text: str):
    """argparse type of ``--components``: an integer >= 2 or 'bic'."""
    from tlsvox.classify._mixture import parse_components

    try:
        return parse_components(text)
    except InputError as e:
        raise argparse.ArgumentTypeError(f"{text!r}: give an integer >= 2 or 'bic'") from e


def cmd_classify(args) -> int:
    """Handler of ``tlsvox classify``."""
    from tlsvox.classify import ClassifySettings, classify_scan, score
    from tlsvox.readers import read_any
    from voxlidar.safeio import atomic_write

    out = Path(args.output)
    names = [Path(p).with_suffix("").name for p in args.scans]
    check_outputs(_scan_inputs(args.scans),
                  [(f"-o {out}/", p) for n in names
                   for p in (out / f"{n}.classified.laz", *sidecar_paths(out / f"{n}.classified.laz"))]
                  + [(f"-o {out}/", out / "classification.json")]
                  + [("--plot", args.plot)])
    check_figure_path("--plot", args.plot)
    calibration = None
    if args.calibration is not None:
        from tlsvox.reflectance import CalibrationTable

        if args.intensity == "relative":
            raise InputError("--calibration and --intensity relative say different things of the intensity: give one")
        if not args.calibration.is_file():
            raise InputError(f"--calibration {args.calibration}: no such file; give a CSV with columns "
                             "range_m,intensity")
        calibration = CalibrationTable.from_csv(args.calibration, reference_reflectance=1.0 if
                                                args.reference_reflectance is None else args.reference_reflectance)
    elif args.reference_reflectance is not None:
        raise InputError("--reference-reflectance needs --calibration CSV (it is that table's target)")
    geometric = args.method == "geometric"
    scans = [read_any(p, scan_id=k, require_reflectance=not geometric) for k, p in enumerate(args.scans)]
    settings = ClassifySettings.from_kwargs(method=args.method, rule=args.rule, components=args.components,
                                            refine=args.refine, incidence_correction=args.incidence_correction,
                                            ground=not args.no_ground)
    if args.intensity == "relative":
        settings = ClassifySettings.from_kwargs(settings, source="intensity", allow_relative=True)
    results = [classify_scan(s, settings, calibration=calibration) for s in scans]
    doc = {"scans": []}
    out.mkdir(parents=True, exist_ok=True)
    for s, c, name in zip(scans, results, names):
        entry = c.summary()
        if s.truth_material is not None:
            sc = score(c.labels, s.truth_material)
            entry["score"] = sc.to_dict()
            print(f"{s.name}: leaf P/R {sc.precision['leaf']:.3f}/{sc.recall['leaf']:.3f}, "
                  f"wood P/R {sc.precision['wood']:.3f}/{sc.recall['wood']:.3f}")
        _write_classified(out / f"{name}.classified.laz", s, c.labels)
        doc["scans"].append(entry)
    atomic_write(out / "classification.json",
                 lambda tmp: Path(tmp).write_text(json_text(doc, indent=1)))
    if args.plot:
        from tlsvox.classify.plots import plot_reflectance_histograms

        plot_reflectance_histograms(results, args.plot)
    print(f"wrote {len(scans)} classified scan(s) to {out}")
    return 0


def _scan_inputs(paths) -> list:
    """(label, path) of every scan file and the sidecars read beside it."""
    return [("scan", p) for path in paths for p in (path, *sidecar_paths(path))]


def _write_classified(path: Path, scan, labels) -> None:
    """Write a scan with its labels as LAS classification codes, with its pulse table
    and pose sidecars, so that ``tlsvox voxelize`` takes it as it is."""
    import dataclasses

    from tlsvox.scan import CLASSIFY_MARK

    # the scan keeps its name, so `voxelize --transforms` finds its pose by it
    out = dataclasses.replace(scan, classification=np.asarray(labels, dtype=np.uint8),
                              meta=dict(scan.meta, classes=CLASSIFY_MARK))
    out.write(path)
