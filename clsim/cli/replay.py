"""``clsim replay``: simulate a measured file's own pulses as fired and score them against the measurement.

Examples
--------
>>> from clsim.cli.app import build_parser
>>> a = build_parser().parse_args(["replay", "neon", "-o", "out/replay"])
>>> a.scheme, a.photons, a.folds, a.voxel_size
('interleaved,lines', 2000, 5, 0.25)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from clsim.errors import InputError
from voxlidar.cli import number

__all__ = ["register", "cmd_replay"]


def register(subparsers) -> None:
    """Add ``replay`` to an argparse subparsers object."""
    p = subparsers.add_parser(
        "replay", help="replay a measured waveform file's pulses over a scene made from its other pulses, "
                       "scored against the measurement and two baselines",
        description="Replay every pulse of a measured full-waveform file as the sensor fired it (its position, "
                    "direction, divergence; the instrument's own pulse) over a voxel scene made from the other "
                    "pulses' echoes, held out by folds: interleaved (pulse i in fold i mod K) and leave-one-"
                    "scan-line-out. Gain and time offset are fitted on training pulses only. Each pulse is "
                    "scored (Pearson r as predicted and at the best lag, energy ratio, RH25/50/75/98, canopy "
                    "cover) beside the Blair-Hofton baseline from the training echoes and the nearest training "
                    "pulse. Writes OUT/metrics.csv, OUT/summary.json, OUT/waveforms.npz and pictures.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("measured", type=Path,
                   help="a NEON record folder (return.csv, geolocation.csv; outgoing.csv and system_impulse.csv "
                        "when present) or its return.csv; or a LAS 1.3/1.4 file with waveform packets (.wdp beside): "
                        "its sensor positions are a straight, steady flight fitted to the pulses' lines; or a "
                        "HELIOS++ *_fullwave.txt (origins and directions as written)")
    p.add_argument("--scene", type=Path, default=None,
                   help="replay over this scene (.npz, e.g. from tlsvox voxelize of TLS scans in the file's frame) "
                        "instead of scenes made from the held-out folds' training pulses")
    p.add_argument("--scene-out", type=Path, default=None, metavar="PATH",
                   help="also write the scene made from every pulse of the file (.npz, for clsim simulate / survey)")
    p.add_argument("-o", "--output", type=Path, required=True, help="output folder (created; files in it replaced "
                                                                    "only when the whole run succeeds)")
    p.add_argument("--scheme", default="interleaved,lines",
                   help="held-out schemes, comma-separated: interleaved, lines")
    p.add_argument("--folds", type=number(int, lo=2), default=5, help="folds of the interleaved scheme")
    p.add_argument("--photons", type=number(int, lo=16), default=2000, help="photons per simulated pulse")
    p.add_argument("--seed", type=number(int, lo=0), default=0, help="seed (pulse i is simulated with seed + i)")
    p.add_argument("--voxel-size", type=number(lo=0, lo_open=True, unit="m"), default=0.25,
                   help="voxel size of the scenes made from the training pulses, m")
    p.add_argument("--beams-per-footprint", type=number(lo=0, lo_open=True), default=3.0,
                   help="each voxel's sums are pooled over a horizontal Gaussian holding this many training "
                        "beams (airborne pulses are too sparse for one voxel's own)")
    p.add_argument("--divergence-mrad", type=number(lo=0, lo_open=True, unit="mrad"), default=None,
                   help="beam divergence half angle at 1/e^2 (default: the reader's: NEON 0.25 mrad; LAS: the clsim "
                        "preset a clsim survey file names, else 0.11 mrad as a Leica ALS50-II; HELIOS++ text 0.25 mrad; "
                        "files do not record it)")
    p.add_argument("--wavelength-nm", type=number(lo=0, lo_open=True, unit="nm"), default=None,
                   help="the sensor's wavelength, for the scene's leaf and ground optics (default as for "
                        "--divergence-mrad: NEON 1064 nm, LAS the named clsim preset's or 1064 nm)")
    p.add_argument("--max-order", type=number(int, lo=1, hi=16), default=3, help="highest scattering order")
    p.add_argument("--no-hotspot", action="store_true",
                   help="single scattering returns through the canopy independently (a turbid medium's two-way "
                        "attenuation) instead of along its free incoming path")
    p.add_argument("--methods", default="simulation,blair_hofton,blair_hofton_samples,nearest",
                   help="methods compared, comma-separated: simulation (clsim), blair_hofton (training echoes), "
                        "blair_hofton_samples (training samples), nearest (the nearest training pulse)")
    p.add_argument("--baselines-only", action="store_true",
                   help="score only the baselines (no OpenCL device needed); the same as leaving simulation out "
                        "of --methods")
    p.add_argument("--no-plots", action="store_true", help="write the tables only")
    p.add_argument("--plot-count", type=number(int, lo=1, hi=24), default=6, help="pulses in the overlay picture")
    p.add_argument("--device", default=None,
                   help="OpenCL device ('platform:device', 'cpu', 'gpu' or a name fragment; default: "
                        "VOXLIDAR_DEVICE, PYOPENCL_CTX or the best working device)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_replay)


def cmd_replay(args) -> int:
    from clsim.replay import METHODS, Scheme, cross_validate, prepare, read_measured, write_replay
    from clsim.replay._write import output_paths
    from voxlidar.safeio import check_outputs

    schemes = [Scheme.parse(s.strip(), "--scheme").value for s in str(args.scheme).split(",") if s.strip()]
    if not schemes:
        raise InputError("--scheme is empty; give interleaved, lines or both (comma-separated)")
    chosen = [m.strip().lower() for m in str(args.methods).split(",") if m.strip()]
    unknown = [m for m in chosen if m not in METHODS]
    if unknown or not chosen:
        raise InputError(f"--methods {args.methods!r}: unknown {unknown or 'empty'}; choose from {', '.join(METHODS)}")
    methods = tuple(m for m in METHODS if m in chosen and not (args.baselines_only and m == "simulation"))
    if not methods:
        raise InputError("--baselines-only leaves no method of --methods to run; add a baseline to --methods")
    out = Path(args.output)
    if out.exists() and not out.is_dir():
        raise InputError(f"-o {str(out)!r} is a file; give a folder")
    inputs = [("measured", args.measured), ("--scene", args.scene)]
    outputs = [(f"-o ({p.name})", p) for p in output_paths(out, schemes, plots=not args.no_plots).values()]
    if args.scene_out is not None:
        if Path(args.scene_out).suffix.lower() != ".npz":
            raise InputError(f"--scene-out must end in .npz, got {str(args.scene_out)!r}")
        outputs.append(("--scene-out", args.scene_out))
    check_outputs(inputs, outputs)
    scene = None
    if args.scene is not None:
        from voxlidar.scene import Scene

        if args.baselines_only or "simulation" not in chosen:
            raise InputError("--scene is replayed by the simulation; it needs simulation in --methods and no "
                             "--baselines-only")
        scene = Scene.load(args.scene)
    measured = read_measured(args.measured, divergence_mrad=args.divergence_mrad,
                             wavelength_nm=args.wavelength_nm)
    prepared = prepare(measured)
    simulator = None
    if "simulation" in methods:
        from clsim.transport.simulator import Simulator

        simulator = Simulator(args.device)
    results = []
    for s in schemes:
        results.append(cross_validate(prepared, scheme=s, k=args.folds, photons=args.photons, seed=args.seed,
                                      voxel_size=args.voxel_size, beams_per_footprint=args.beams_per_footprint,
                                      max_order=args.max_order, hotspot=not args.no_hotspot, methods=methods,
                                      scene=scene, simulator=simulator, progress=not args.quiet))
    paths = write_replay(prepared, results, out, plots=not args.no_plots, plot_count=args.plot_count)
    if args.scene_out is not None:
        import numpy as np

        from clsim.replay import pool_sigma, scene_from_pulses

        every = np.arange(len(measured))
        whole = scene_from_pulses(prepared, every, voxel_size=args.voxel_size,
                                  pool_m=pool_sigma(prepared, every, args.beams_per_footprint))
        whole.save(args.scene_out)
        print(f"wrote the scene from all {len(measured)} pulses ({whole.n_voxels:,} voxels of {args.voxel_size:g} m, "
              f"plant area density) to {args.scene_out}")
    geo = measured.meta.get("geometry") or {}
    if "residual_x_p95_m" in geo:
        where = (f"positions rebuilt: 95 % within {geo['residual_x_p95_m']:.2f} m in x, "
                 f"{geo['residual_y_p95_m']:.2f} m in y of the stored values")
    elif "off_line_median_m" in geo:
        where = (f"sensor: a straight, steady flight fitted to the pulses' lines, {geo['off_line_median_m']:.3f} m "
                 "off them (median)")
    else:
        where = "positions as stored"
    print(f"{measured.name}: {len(measured)} pulses, {geo.get('lines', '?')} scan line(s) ({where}); pulse shape: "
          f"{prepared.shape_source}")
    for r in results:
        print(f"{r.scheme} folds ({r.settings['multi_echo_pulses']} pulses with 2+ peaks):")
        print(f"  {'method':<22} {'r':>6} {'r multi':>8} {'energy IQR':>12} {'RH50 bias':>10} {'RH98 bias':>10}")
        for m, s in r.summary.items():
            a, mu = s["all"], s["multi"] or {}
            print(f"  {m:<22} {a['r_median']:6.3f} {mu.get('r_median', float('nan')):8.3f} "
                  f"{a['energy_ratio_q25']:5.2f}-{a['energy_ratio_q75']:<5.2f} {a['rh50_bias']:+10.2f} "
                  f"{a['rh98_bias']:+10.2f}")
        if r.settings.get("uncovered_pulses"):
            where = "the given scene's grid" if scene is not None else "their fold's scene"
            print(f"  {r.settings['uncovered_pulses']} pulses lie outside {where} and are left out of every method's "
                  "scores")
    print(f"wrote {len(paths)} files to {out}/", file=sys.stdout)
    return 0
