"""CLI sub-commands for real waveform files: ``waveforms info``, ``decompose``.

(``clsim georegister`` is :mod:`tlsvox.cli.georegister`, kept here too for old scripts.)

``register(subparsers)`` adds them to the ``clsim`` argument parser; each
handler takes the parsed namespace and returns an exit status.

Inputs by suffix: ``.las``/``.laz`` (LAS 1.3/1.4 waveform packets, ``.wdp``
beside), ``.pls`` (PulseWaves, ``.wvs`` beside), ``.csv`` (one waveform per
row, e.g. the NEON ``return.csv``; trailing zeros are padding), ``.txt``
(HELIOS++ full-waveform output, :mod:`clsim.waveforms.io.helios`).
"""

from __future__ import annotations

import csv
import io
import sys
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from voxlidar.cli import number
from voxlidar.safeio import check_figure_path, check_inputs, check_outputs, staged

__all__ = ["register", "cmd_info", "cmd_decompose", "load_waveforms"]


def register(subparsers) -> None:
    """Add ``waveforms``, ``decompose`` and ``georegister`` to an argparse subparsers object."""
    wf = subparsers.add_parser(
        "waveforms", help="inspect real full-waveform files (LAS 1.3/1.4 + .wdp, PulseWaves)",
        description="Inspect full-waveform files.")
    wsub = wf.add_subparsers(dest="waveforms_command", required=True)
    info = wsub.add_parser("info", help="summary of a waveform file",
                           description="Print format, counts, sampling, descriptors and the "
                                       "first waveform of FILE (.las/.laz/.pls/.csv).")
    info.add_argument("file", type=Path)
    info.set_defaults(func=cmd_info)

    dec = subparsers.add_parser(
        "decompose", help="Gaussian decomposition of every waveform in a file",
        description="Decompose each waveform of FILE into Gaussian echoes (matched-filter "
                    "detection with a set false-alarm rate, Levenberg-Marquardt, BIC component "
                    "count) and write one CSV row per echo: waveform index, "
                    "amplitude, location_ns, sigma_ns, their standard errors, baseline and, "
                    "when the file has geometry, x, y, z of the echo.")
    dec.add_argument("file", type=Path)
    dec.add_argument("-o", "--output", type=Path, required=True, help="echo table (.csv)")
    dec.add_argument("--plot", type=Path, metavar="PATH", help="picture of the first waveforms with their fits "
                     "(the suffix picks the format: png, pdf, svg, jpg)")
    dec.add_argument("--plot-count", type=number(int, lo=1), default=6, help="waveforms in the plot (6)")
    dec.add_argument("--dt-ns", type=number(lo=0, lo_open=True, unit="ns"), default=None,
                     help="sample spacing for CSV input (default 1 ns)")
    dec.add_argument("--min-amplitude", type=number(lo=0), default=None,
                     help="amplitude detection threshold above baseline (selects "
                          "--detection amplitude; its default is 4 noise sigma)")
    dec.add_argument("--detection", choices=("matched", "amplitude"), default=None,
                     help="matched: matched filter with the system pulse, threshold from "
                          "--false-alarm (default); amplitude: the 4-sigma amplitude rule")
    dec.add_argument("--false-alarm", type=number(lo=0, hi=1, lo_open=True, hi_open=True), default=0.01,
                     help="expected false echoes per noise-only waveform (matched; 0.01)")
    dec.add_argument("--pulse-sigma-ns", type=number(lo=0, lo_open=True, unit="ns"), default=None,
                     help="Gaussian system pulse width for the matched filter, ns (default: "
                          "from the strongest echoes)")
    dec.add_argument("--batch", action="store_true",
                     help="decompose all waveforms at once, vectorised, the fits on an "
                          "OpenCL device (much faster on large files; matched detection, "
                          "no --impulse/--min-amplitude)")
    dec.add_argument("--device", default=None,
                     help="where --batch fits: an OpenCL device ('platform:device', 'cpu', "
                          "'gpu' or a name fragment) or 'numpy' (default: VOXLIDAR_DEVICE, "
                          "PYOPENCL_CTX or the best device that builds the kernel, else numpy)")
    dec.add_argument("--impulse", type=Path,
                     help="CSV whose first column is the system impulse response; "
                          "deconvolve before fitting")
    dec.add_argument("--geolocation", type=Path,
                     help="NEON-style geolocation CSV (bin0_x..bin0_dz) for CSV input")
    dec.add_argument("--limit", type=number(int, lo=1), default=None, help="only the first N waveforms")
    dec.add_argument("--template", default=None, metavar="returns|CSV",
                     help="echoes as the instrument's own pulse shifted and scaled instead of Gaussians, so a real "
                          "system's ringing and trailing tail are part of each echo: 'returns' (the pulse of the "
                          "file's strongest narrow single returns) or a CSV whose first column is a hard target's "
                          "return (e.g. NEON's system_impulse.csv); writes location_ns, energy, extent_ns, snr per "
                          "echo (docs/waveforms.md, template decomposition)")
    dec.add_argument("--min-relative", type=number(lo=0, hi=1, hi_open=True), default=0.0,
                     help="with --template: drop echoes under this share of their waveform's strongest (0; the "
                          "instruments' own discrete returns seldom go under 0.05)")
    dec.set_defaults(func=cmd_decompose)

    from tlsvox.cli.georegister import register as register_georegister

    register_georegister(subparsers)  # the same command as `tlsvox georegister`


# ----------------------------------------------------------------- input ---

class _Waveforms:
    """Waveforms of a file: samples, sample spacing, optional geometry per waveform."""

    def __init__(self, kind, waves, dt_ns, geometry, meta, pulse_id=None, gps_time=None, volts=None):
        self.kind = kind
        self.waves = waves  # list of 1-D arrays
        self.dt_ns = dt_ns  # list of float
        self.geometry = geometry  # list of (origin, direction per ns) or None
        self.meta = meta
        self.pulse_id = list(range(len(waves))) if pulse_id is None else pulse_id  # the file's pulse of each
        self.gps_time = [float("nan")] * len(waves) if gps_time is None else gps_time  # s; NaN: none
        # digitiser calibration per waveform, (gain, offset): volts = offset + gain * counts; None: none
        self.volts = [None] * len(waves) if volts is None else volts


def _read_csv_rows(path: Path) -> list:
    """One array per row of numbers; the first row may be a header; trailing empty cells are padding."""
    text = path.read_text()
    rows = list(csv.reader(io.StringIO(text)))
    out = []
    for k, r in enumerate(rows):
        cells = list(r)
        while cells and cells[-1].strip() == "":
            cells.pop()
        if not cells:
            continue
        vals = []
        for j, v in enumerate(cells):
            try:
                vals.append(float(v))
            except ValueError:
                vals = None
                bad = (j, v)
                break
        if vals is None:
            if k == 0:
                continue  # the header
            j, v = bad
            raise InputError(f"{path.name}: row {k + 1}, column {j + 1} is {v.strip()[:20]!r}, not a number; one "
                             "waveform per row, numbers only (a header row is allowed)")
        out.append(np.array(vals))
    if not out:
        raise InputError(f"{path.name}: no numeric rows")
    return out


def load_waveforms(path: Path, *, dt_ns=None, geolocation=None) -> _Waveforms:
    """Load every waveform of a LAS/LAZ, PulseWaves or CSV file."""
    path = Path(path)
    suffix = path.suffix.lower()
    if not path.is_file():
        raise InputError(f"input file {str(path)!r} does not exist")
    from voxlidar.safeio import describe_kind, file_kind

    kind = file_kind(path)  # the content decides, not the name
    if kind == "las":
        suffix = ".las" if suffix not in (".las", ".laz") else suffix
    elif kind == "pls":
        suffix = ".pls"
    elif suffix in (".las", ".laz", ".pls"):
        raise InputError(f"{path.name} is not a {'LAS/LAZ' if suffix != '.pls' else 'PulseWaves'} file: it is "
                         f"{describe_kind(kind)}; check the file")
    if suffix in (".las", ".laz"):
        from clsim.waveforms.io import read_las_waveforms

        w = read_las_waveforms(path)
        first = np.full(w.n_packets, -1)
        valid = np.flatnonzero(w.packet >= 0)
        first[w.packet[valid][::-1]] = valid[::-1]
        waves, dts, geo, gps, volts = [], [], [], [], []
        for p in range(w.n_packets):
            i = int(first[p])
            d = w.descriptor_of_point(i)
            waves.append(w.samples(i, volts=False).astype(np.float64))
            dts.append(d.spacing_ps / 1000.0)
            volts.append((float(d.gain), float(d.offset)) if d.gain != 0 else None)
            geo.append(w.waveform_origin(i))
            gps.append(float(w.gps_time[i]))
        meta = dict(points=len(w), packets=w.n_packets,
                    descriptors={k: vars(v) for k, v in w.descriptors.items()},
                    multi_return_points=int(np.sum(w.number_of_returns > 1)))
        return _Waveforms("LAS waveform packets", waves, dts, geo, meta, pulse_id=list(range(w.n_packets)),
                          gps_time=gps, volts=volts)
    if suffix == ".pls":
        from clsim.waveforms.io import read_pulsewaves

        pw = read_pulsewaves(path)
        segs = [s for s in pw.segments if s.kind == "returning"]
        waves = [s.samples.astype(np.float64) for s in segs]
        dts = [s.sample_units_ns for s in segs]
        geo = [pw.segment_origin(s) for s in segs]
        meta = dict(pulses=len(pw), system=pw.header["system"],
                    outgoing=[len(s.samples) for s in pw.segments if s.kind == "outgoing"],
                    returning=[len(s.samples) for s in segs],
                    returning_pulse=[s.pulse for s in segs])
        return _Waveforms("PulseWaves", waves, dts, geo, meta, pulse_id=[int(s.pulse) for s in segs],
                          gps_time=[float(pw.gps_time[s.pulse]) for s in segs])
    if suffix == ".csv":
        rows = _read_csv_rows(path)
        waves = []
        for r in rows:
            nz = np.flatnonzero(r != 0)
            waves.append(r[:nz[-1] + 1] if nz.size else r[:0])
        dt = 1.0 if dt_ns is None else float(dt_ns)
        geo = [None] * len(waves)
        if geolocation is not None:
            geo = _neon_geolocation(Path(geolocation), len(waves))
        return _Waveforms("CSV (one waveform per row)", waves, [dt] * len(waves), geo,
                          dict(rows=len(waves)))
    if suffix == ".txt":
        from clsim.waveforms.io.helios import read_helios_fullwave

        fw = read_helios_fullwave(path)
        return _Waveforms("HELIOS++ full waveform (text)", list(fw.samples), fw.dt_ns.tolist(),
                          [fw.sample_geometry(i) for i in range(len(fw))],
                          dict(pulses=len(fw), time_axis="one-way travel time (HELIOS++)"),
                          pulse_id=fw.index.tolist(), gps_time=fw.gps_time.tolist())
    raise InputError(f"{path.name}: unknown waveform file type {suffix!r}; expected .las, "
                     ".laz, .pls, .csv or .txt (HELIOS++ full waveform)")


def _neon_geolocation(path: Path, n: int) -> list:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    need = ["bin0_x", "bin0_y", "bin0_z", "bin0_dx", "bin0_dy", "bin0_dz"]
    if not rows or any(k not in rows[0] for k in need):
        raise InputError(f"{path.name}: geolocation CSV needs columns {need}")
    if len(rows) != n:
        raise InputError(f"{path.name}: {len(rows)} geolocation rows for {n} waveforms")
    return [(np.array([float(r[k]) for k in need[:3]]),
             np.array([float(r[k]) for k in need[3:]])) for r in rows]


# -------------------------------------------------------------- handlers ---

def cmd_info(args) -> int:
    wf = load_waveforms(args.file)
    out = sys.stdout
    lens = [w.size for w in wf.waves]
    print(f"file: {args.file}", file=out)
    print(f"format: {wf.kind}", file=out)
    for k, v in wf.meta.items():
        if isinstance(v, list) and len(v) > 12:
            v = f"{v[:12]} ... ({len(v)} values)"
        print(f"{k}: {v}", file=out)
    print(f"waveforms: {len(wf.waves)}", file=out)
    if lens:
        print(f"samples per waveform: min {min(lens)} max {max(lens)}", file=out)
        print(f"sample spacing: {sorted(set(wf.dt_ns))} ns", file=out)
        first = wf.waves[0][:16]
        shown = (first.astype(np.int64).tolist() if np.array_equal(first, np.round(first))
                 else [float(f"{v:.4g}") for v in first])
        print(f"first waveform (first 16 samples): {shown}", file=out)
    return 0


def cmd_decompose(args) -> int:

    from clsim.waveforms.decompose import decompose, echo_positions

    if args.output.suffix.lower() != ".csv":
        raise InputError(f"--output must be a .csv file; got {str(args.output)!r}")
    check_outputs([("file", args.file), ("file (waveform packets)", Path(args.file).with_suffix(".wdp")),
                   ("--geolocation", args.geolocation), ("--impulse", args.impulse)],
                  [("-o", args.output), ("--plot", args.plot)])
    check_figure_path("--plot", args.plot)
    check_inputs([("--impulse", args.impulse), ("--geolocation", args.geolocation)])
    if args.batch and (args.impulse is not None or args.min_amplitude is not None or args.detection == "amplitude"):
        raise InputError("--batch uses matched-filter detection on the recorded samples; "
                         "drop --impulse, --min-amplitude and --detection amplitude")
    if args.device is not None and not args.batch:
        raise InputError("--device chooses where --batch fits; add --batch or drop --device")
    if args.template is not None:
        clash = [f for f, v in (("--batch", args.batch), ("--impulse", args.impulse), ("--plot", args.plot),
                                ("--min-amplitude", args.min_amplitude), ("--detection", args.detection),
                                ("--pulse-sigma-ns", args.pulse_sigma_ns)) if v]
        if clash:
            raise InputError(f"--template decomposes with the instrument's pulse; drop {', '.join(clash)}")
    elif args.min_relative:
        raise InputError("--min-relative needs --template (it drops weak template echoes)")
    wf = load_waveforms(args.file, dt_ns=args.dt_ns, geolocation=args.geolocation)
    if args.template is not None:
        return _decompose_template(wf, args)
    impulse = None
    if args.impulse is not None:
        try:
            impulse = np.array([r[0] for r in _read_csv_rows(Path(args.impulse))])
        except InputError as err:
            raise InputError(f"--impulse {err}") from None
        if not (np.all(np.isfinite(impulse)) and impulse.sum() > 0):
            raise InputError(f"--impulse {args.impulse}: the impulse response must be finite with a positive sum")
    n = len(wf.waves) if args.limit is None else min(len(wf.waves), int(args.limit))
    results = []
    iterator = range(n)
    if n > 200:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="decompose", unit="waveform")
    if args.batch:
        results = _decompose_batched(wf, n, args)
        iterator = ()
    for i in iterator:
        y = wf.waves[i]
        if y.size < 4:
            results.append(None)
            continue
        results.append(decompose(y, dt_ns=wf.dt_ns[i], min_amplitude=args.min_amplitude,
                                 impulse=impulse, detection=args.detection,
                                 false_alarm=args.false_alarm,
                                 pulse_sigma_ns=args.pulse_sigma_ns))
    header = ["waveform", "pulse_id", "gps_time", "echo", "amplitude", "location_ns", "sigma_ns", "amplitude_se",
              "location_se_ns", "sigma_se_ns", "baseline", "amplitude_v", "baseline_v", "x", "y", "z"]

    def write(tmp):
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            for i, c in enumerate(results):
                if c is None:
                    continue
                geo = wf.geometry[i]
                xyz = (echo_positions(c.location_ns, origin=geo[0], direction=geo[1])
                       if geo is not None else np.full((len(c), 3), np.nan))
                cal = wf.volts[i]
                for k in range(len(c)):
                    t = wf.gps_time[i]
                    # volts: the digitiser's gain scales an amplitude above the baseline; the offset is in the baseline
                    v = ([f"{cal[0] * c.amplitude[k]:.6g}", f"{cal[1] + cal[0] * c.baseline:.6g}"] if cal is not None
                         else ["", ""])
                    w.writerow([i, wf.pulse_id[i], f"{t:.6f}" if np.isfinite(t) else "", k]
                               + [f"{getattr(c, col)[k]:.6g}" for col in c.COLUMNS]
                               + [f"{c.baseline:.6g}"] + v
                               + [("" if not np.isfinite(xv) else f"{xv:.4f}") for xv in xyz[k]])

    from clsim.figures import plot_decomposition

    with staged([args.output, args.plot]) as tmp:  # the table and its picture: both or neither
        write(tmp[args.output])
        if args.plot is not None:
            plot_decomposition(tmp[args.plot], wf, results, int(args.plot_count), Path(args.file).name)
    n_echo = sum(len(c) for c in results if c is not None)
    print(f"{n} waveforms, {n_echo} echoes -> {args.output}" + (f"; plot -> {args.plot}" if args.plot else ""))
    return 0


def _decompose_template(wf, args) -> int:
    """``clsim decompose --template``: one CSV row per template echo."""
    from clsim.waveforms.decompose import echo_positions, noise_level
    from clsim.waveforms.decompose._template import decompose_template, template_from_returns

    n = len(wf.waves) if args.limit is None else min(len(wf.waves), int(args.limit))
    waves = [np.asarray(wf.waves[i], dtype=np.float64) for i in range(n)]
    if str(args.template).lower() == "returns":
        template = template_from_returns(waves)
        source = "the file's strongest narrow single returns"
    else:
        path = Path(args.template)
        check_inputs([("--template", path)])
        try:
            template = np.array([r[0] for r in _read_csv_rows(path)], dtype=np.float64)
        except InputError as err:
            raise InputError(f"--template {err}") from None
        if template.size < 3 or not np.all(np.isfinite(template)):
            raise InputError(f"--template {path}: its first column must hold a hard target's return (3 or more "
                             "finite samples)")
        template = template - noise_level(template)[0]  # its baseline off
        source = str(path)
    dts = {float(wf.dt_ns[i]) for i in range(n)}
    if len(dts) != 1:
        raise InputError(f"--template needs one sample spacing; the file's waveforms have {sorted(dts)} ns")
    table = decompose_template(waves, template, dt_ns=dts.pop(), false_alarm=args.false_alarm,
                               min_relative=args.min_relative)
    header = ["waveform", "pulse_id", "gps_time", "echo", "amplitude", "location_ns", "energy", "extent_ns", "snr",
              "baseline", "x", "y", "z"]

    def write(tmp):
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(header)
            first = np.searchsorted(table.waveform, table.waveform)  # sorted by waveform: its first echo's row
            rank = np.arange(len(table.waveform)) - first
            for j, i in enumerate(table.waveform):
                geo = wf.geometry[i]
                xyz = (echo_positions(table.location_ns[j: j + 1], origin=geo[0], direction=geo[1])[0]
                       if geo is not None else np.full(3, np.nan))
                t = wf.gps_time[i]
                w.writerow([int(i), wf.pulse_id[i], f"{t:.6f}" if np.isfinite(t) else "", int(rank[j]),
                            f"{table.amplitude[j]:.6g}", f"{table.location_ns[j]:.6g}", f"{table.energy[j]:.6g}",
                            f"{table.extent_ns[j]:.6g}", f"{table.snr[j]:.6g}", f"{table.baseline[i]:.6g}"]
                           + [("" if not np.isfinite(v) else f"{v:.4f}") for v in xyz])

    with staged([args.output]) as tmp:
        write(tmp[args.output])
    print(f"{n} waveforms, {len(table.waveform)} template echoes (template: {source}) -> {args.output}")
    return 0


def _decompose_batched(wf, n: int, args) -> list:
    """Components per waveform (None under 4 samples) from ``decompose_batch``, one call
    per sample spacing."""
    from clsim.waveforms.decompose import decompose_batch

    results = [None] * n
    usable = [i for i in range(n) if wf.waves[i].size >= 4]
    for dt in sorted({float(wf.dt_ns[i]) for i in usable}):
        idx = [i for i in usable if float(wf.dt_ns[i]) == dt]
        table = decompose_batch([wf.waves[i] for i in idx], dt_ns=dt,
                                false_alarm=args.false_alarm,
                                pulse_sigma_ns=args.pulse_sigma_ns, device=args.device)
        for k, i in enumerate(idx):
            results[i] = table[k]
    return results
