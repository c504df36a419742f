"""Measured airborne pulses as a replay needs them: samples, range axis, beam, sensor.

A :class:`MeasuredPulses` holds N recorded return waveforms on one sample
clock, with each record's range axis (the position of sample 0 and the
displacement per sample along the beam), the sensor position at emission,
the scan line of each pulse, and the instrument's own pulse where the file
has one (outgoing waveforms, a system impulse response).

:func:`read_neon` reads the NEON CSV records (``return.csv``,
``outgoing.csv``, ``system_impulse.csv``, ``geolocation.csv``).  Their x and y
are stored to 7 significant digits (0.1 m and 1 m) while pulses lie about
0.4 m apart, so the positions are rebuilt from the scan geometry
(:func:`rebuild_positions`): every pulse's line passes through the scanner,
which moves little during one scan line.

Examples
--------
A scanner at (0, 0, 1000) m, one line of 40 pulses fanned across y, their
sample-0 positions rounded to 0.1 m in x and 1 m in y as NEON stores them
(y up to 0.5 m off); rebuilt, every position is within 0.1 m:

>>> import numpy as np
>>> d = np.stack([np.full(40, 0.001), np.linspace(-0.02, 0.02, 40), np.full(40, -0.149)], 1)
>>> s = (1000.0 - np.linspace(20, 30, 40)) / 0.149            # ns from the scanner to sample 0
>>> p = np.array([0.0, 0.0, 1000.0]) + s[:, None] * d
>>> q = np.c_[np.round(p[:, 0], 1), np.round(p[:, 1]), p[:, 2]]
>>> fit = rebuild_positions(q, d, np.zeros(40, int))
>>> float(np.abs(q - p)[:, 1].max().round(1)), bool(np.abs(fit.bin0 - p)[:, :2].max() < 0.1)
(0.5, True)
>>> (fit.scanner[0].round(0) + 0.0).tolist()
[0.0, 0.0, 1000.0]
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clsim.errors import InputError
from clsim.sensor import C_M_PER_NS, Sensor

__all__ = ["MeasuredPulses", "GeometryFit", "HELIOS_DEFAULTS", "common_point", "read_helios_pulses", "read_las_pulses",
           "read_measured", "read_neon", "rebuild_positions",
           "scan_lines", "straight_trajectory"]

#: NEON's stored precision of x and y (7 significant digits at UTM magnitudes), metres.
NEON_ROUNDING_M = (0.1, 1.0)


@dataclass
class MeasuredPulses:
    """Recorded return waveforms with the geometry to replay them.

    Attributes
    ----------
    samples : (N, S) float64, counts
        Return waveforms, padded at the end; ``valid`` says which samples were recorded.
    valid : (N, S) bool
        False for padding and for no-data fill between digitised segments.
    dt_ns : float
        Sample spacing, ns.
    bin0 : (N, 3) float64, metres
        Position of each record's sample 0 on its beam.
    step : (N, 3) float64, metres per sample
        Displacement along the beam (away from the sensor) per sample.
    origin : (N, 3) float64, metres
        Sensor position at emission (on the beam's line).
    line : (N,) int64
        Scan line of each pulse (0-based, in file order).
    outgoing : (N, M) float64, counts, optional
        The emitted pulse as recorded (padded with NaN).
    impulse : (K,) float64, optional
        The system impulse response: the return of a hard target, baseline removed.
    divergence_mrad : float
        Beam divergence half angle at 1/e^2, mrad (the sensor's specification).
    wavelength_nm : float
    name : str
    meta : dict
        What was rebuilt or assumed (``geometry``: the fit's residuals).
    """

    samples: np.ndarray
    valid: np.ndarray
    dt_ns: float
    bin0: np.ndarray
    step: np.ndarray
    origin: np.ndarray
    line: np.ndarray
    outgoing: np.ndarray | None = None
    impulse: np.ndarray | None = None
    divergence_mrad: float = 0.25
    wavelength_nm: float = 1064.0
    name: str = "measured"
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.samples = np.asarray(self.samples, dtype=np.float64)
        if self.samples.ndim != 2 or self.samples.shape[1] < 4:
            raise InputError(f"{self.name}: samples must be (pulses, samples) with at least 4 samples, got "
                             f"shape {self.samples.shape}")
        n = len(self.samples)
        self.valid = np.asarray(self.valid, dtype=bool).reshape(self.samples.shape)
        for name in ("bin0", "step", "origin"):
            a = np.asarray(getattr(self, name), dtype=np.float64)
            if a.shape != (n, 3) or not np.all(np.isfinite(a)):
                raise InputError(f"{self.name}: {name} must be ({n}, 3) finite metres, got shape {a.shape}; the "
                                 "file needs each pulse's geometry (origin and direction) to be replayed")
            setattr(self, name, a)
        if np.any(np.linalg.norm(self.step, axis=1) <= 0):
            raise InputError(f"{self.name}: some pulses have a zero displacement per sample (no beam direction)")
        self.line = np.asarray(self.line, dtype=np.int64).reshape(n)
        if not self.dt_ns > 0:
            raise InputError(f"{self.name}: dt_ns must be > 0, got {self.dt_ns!r}")

    def __len__(self) -> int:
        return len(self.samples)

    @property
    def n_samples(self) -> np.ndarray:
        """(N,) samples recorded per pulse (last valid sample + 1)."""
        last = np.where(self.valid.any(axis=1), self.samples.shape[1] - 1 - np.argmax(self.valid[:, ::-1], axis=1), -1)
        return last + 1

    @property
    def direction(self) -> np.ndarray:
        """(N, 3) unit beam directions."""
        return self.step / np.linalg.norm(self.step, axis=1, keepdims=True)

    @property
    def metres_per_sample(self) -> np.ndarray:
        """(N,) range per sample along the beam, metres."""
        return np.linalg.norm(self.step, axis=1)

    def positions(self, i: int) -> np.ndarray:
        """(S, 3) positions of pulse ``i``'s samples, metres."""
        k = np.arange(self.samples.shape[1])
        return self.bin0[i] + k[:, None] * self.step[i]

    def range0(self) -> np.ndarray:
        """(N,) distance from the sensor to each record's sample 0, metres."""
        return np.linalg.norm(self.bin0 - self.origin, axis=1)

    def time0_ns(self) -> np.ndarray:
        """(N,) round-trip time of sample 0 in vacuum nanoseconds (the simulator's clock)."""
        return 2.0 * self.range0() / C_M_PER_NS

    def sample_time_ns(self) -> np.ndarray:
        """(N,) round-trip time per sample in vacuum nanoseconds (the simulator's clock)."""
        return 2.0 * self.metres_per_sample / C_M_PER_NS

    def subset(self, index) -> MeasuredPulses:
        """The pulses at ``index`` (an index array or a boolean mask)."""
        idx = np.asarray(index)
        return MeasuredPulses(
            samples=self.samples[idx], valid=self.valid[idx], dt_ns=self.dt_ns, bin0=self.bin0[idx],
            step=self.step[idx], origin=self.origin[idx], line=self.line[idx],
            outgoing=None if self.outgoing is None else self.outgoing[idx], impulse=self.impulse,
            divergence_mrad=self.divergence_mrad, wavelength_nm=self.wavelength_nm, name=self.name,
            meta=dict(self.meta))


@dataclass(frozen=True)
class GeometryFit:
    """Positions rebuilt from the scan geometry (:func:`rebuild_positions`).

    Attributes
    ----------
    bin0 : (N, 3) float64, metres; each record's sample 0, rebuilt
    origin : (N, 3) float64, metres; the scanner at each pulse's emission
    scanner : (L, 3) float64, metres; the scanner at the middle of each line
    velocity : (L,) float64, metres per pulse along x within each line
    residual : (N, 2) float64, metres; stored minus rebuilt x and y
    """

    bin0: np.ndarray
    origin: np.ndarray
    scanner: np.ndarray
    velocity: np.ndarray
    residual: np.ndarray


def scan_lines(direction_y) -> np.ndarray:
    """(N,) scan line of each pulse, from the across-track component of its direction.

    An oscillating mirror sweeps the beam back and forth: a line ends where
    the sweep turns (the component's first difference changes sign) or jumps.
    """
    d = np.asarray(direction_y, dtype=np.float64).reshape(-1)
    n = d.size
    line = np.zeros(n, dtype=np.int64)
    if n < 3:
        return line
    diff = np.diff(d)
    typical = np.median(np.abs(diff[diff != 0])) if np.any(diff != 0) else 0.0
    current, start, sign = 0, 0, 0.0
    for i in range(1, n):
        step = diff[i - 1]
        jump = typical > 0 and abs(step) > 20 * typical
        turned = sign != 0 and step != 0 and np.sign(step) != sign
        if (jump or turned) and i - start >= 2:
            current += 1
            start = i
            sign = 0.0
        elif step != 0:
            sign = np.sign(step)
        line[i] = current
    return line


def rebuild_positions(bin0, step, line, *, rounding=NEON_ROUNDING_M) -> GeometryFit:
    """Rebuild x and y of rounded sample-0 positions from the beams' common scanner.

    Every pulse's line passes through the scanner: ``bin0_i = S_i + s_i step_i``
    with ``S_i`` the scanner at emission and ``s_i`` the time of flight to the
    record's start in samples.  ``z`` and ``step`` are kept at full precision,
    so ``s_i = (z_i - S_z) / step_z,i``, and x and y follow from
    ``S_x, S_y, S_z`` and the scanner's along-track (x) drift within the line:
    a linear least-squares fit per line, each axis weighted by its rounding.

    Parameters
    ----------
    bin0 : (N, 3) float, metres
        Stored sample-0 positions (x and y rounded, z exact).
    step : (N, 3) float, metres per sample
        Displacement along the beam per sample (exact).
    line : (N,) int
        Scan line of each pulse (:func:`scan_lines`).
    rounding : (float, float), metres
        Rounding step of the stored x and y.

    Returns
    -------
    GeometryFit
    """
    p = np.asarray(bin0, dtype=np.float64).reshape(-1, 3)
    d = np.asarray(step, dtype=np.float64).reshape(-1, 3)
    ln = np.asarray(line, dtype=np.int64).reshape(-1)
    if len(d) != len(p) or len(ln) != len(p):
        raise InputError(f"bin0 ({len(p)}), step ({len(d)}) and line ({len(ln)}) need one row per pulse")
    if np.any(d[:, 2] >= 0):
        raise InputError("rebuild_positions needs downward beams (step z < 0): an airborne sensor above the scene")
    out = p.copy()
    origin = np.zeros_like(p)
    lines = np.unique(ln)
    scanner = np.zeros((len(lines), 3))
    velocity = np.zeros(len(lines))
    wx, wy = 1.0 / rounding[0], 1.0 / rounding[1]
    for j, L in enumerate(lines):
        m = np.flatnonzero(ln == L)
        if len(m) < 4:
            raise InputError(f"scan line {int(L)} has {len(m)} pulses; rebuilding its scanner position needs at "
                             "least 4")
        rx, ry = d[m, 0] / d[m, 2], d[m, 1] / d[m, 2]
        k = np.arange(len(m)) - 0.5 * (len(m) - 1)
        nm = len(m)
        # x_i = Sx + v k_i + (z_i - Sz) rx_i ;  y_i = Sy + (z_i - Sz) ry_i ; unknowns Sx, Sy, Sz, v
        A = np.zeros((2 * nm, 4))
        b = np.zeros(2 * nm)
        A[:nm, 0], A[:nm, 2], A[:nm, 3] = wx, -wx * rx, wx * k
        b[:nm] = wx * (p[m, 0] - p[m, 2] * rx)
        A[nm:, 1], A[nm:, 2] = wy, -wy * ry
        b[nm:] = wy * (p[m, 1] - p[m, 2] * ry)
        sol, *_ = np.linalg.lstsq(A, b, rcond=None)
        sx, sy, sz, v = sol
        out[m, 0] = sx + v * k + (p[m, 2] - sz) * rx
        out[m, 1] = sy + (p[m, 2] - sz) * ry
        origin[m] = np.c_[sx + v * k, np.full(nm, sy), np.full(nm, sz)]
        scanner[j] = (sx, sy, sz)
        velocity[j] = v
    return GeometryFit(bin0=out, origin=origin, scanner=scanner, velocity=velocity,
                       residual=p[:, :2] - out[:, :2])


def _csv_matrix(path: Path) -> np.ndarray:
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as err:
        raise InputError(f"cannot read {str(path)!r}: {err.strerror or err}") from err
    body = rows[1:] if rows and rows[0] and not _is_number(rows[0][0]) else rows
    try:
        width = max(len(r) for r in body)
        return np.array([[float(v) if v.strip() else 0.0 for v in r] + [0.0] * (width - len(r)) for r in body])
    except ValueError as err:
        raise InputError(f"{path.name}: a value is not a number ({err}); one record per row, numbers only") from None


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def _trimmed(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows padded with trailing zeros -> (values, valid), zeros inside a record also invalid."""
    valid = rows != 0
    return np.where(valid, rows, 0.0), valid


def read_neon(folder, *, divergence_mrad: float = 0.25, wavelength_nm: float = 1064.0) -> MeasuredPulses:
    """Read NEON full-waveform records exported as CSV (the waveformlidar layout).

    Parameters
    ----------
    folder : str or path
        Holds ``return.csv`` (one record per row, trailing zeros padding),
        ``geolocation.csv`` (``bin0_x .. bin0_dz`` per pulse) and, optional,
        ``outgoing.csv`` and ``system_impulse.csv``.
    divergence_mrad : float
        Beam divergence half angle at 1/e^2 (NEON's Optech Gemini: 0.25 mrad,
        the narrow setting; Kampe et al. 2010).
    wavelength_nm : float
        NEON's Optech Gemini: 1064 nm.

    Returns
    -------
    MeasuredPulses
        With positions rebuilt from the scan geometry (``meta["geometry"]``).

    Raises
    ------
    InputError
        A missing file or column, a row count that differs between the files.
    """
    folder = Path(folder)
    ret, geo = folder / "return.csv", folder / "geolocation.csv"
    for p in (ret, geo):
        if not p.is_file():
            raise InputError(f"{str(p)!r} does not exist: a NEON record folder holds return.csv and geolocation.csv "
                             "(and optionally outgoing.csv, system_impulse.csv)")
    samples, valid = _trimmed(_csv_matrix(ret))
    with open(geo, newline="") as fh:
        rows = list(csv.DictReader(fh))
    need = ["bin0_x", "bin0_y", "bin0_z", "bin0_dx", "bin0_dy", "bin0_dz"]
    if not rows or any(k not in rows[0] for k in need):
        raise InputError(f"{geo.name}: needs the columns {need} (sample-0 position and its change per ns); the "
                         "records cannot be placed without them")
    if len(rows) != len(samples):
        raise InputError(f"{geo.name} has {len(rows)} rows for {len(samples)} records in {ret.name}: one row per record")
    g = np.array([[float(r[k]) for k in need] for r in rows])
    step = g[:, 3:]
    line = scan_lines(step[:, 1] / np.linalg.norm(step, axis=1))
    fit = rebuild_positions(g[:, :3], step, line)
    outgoing = None
    if (folder / "outgoing.csv").is_file():
        o, ov = _trimmed(_csv_matrix(folder / "outgoing.csv"))
        if len(o) == len(samples):
            outgoing = np.where(ov, o, np.nan)
    impulse = None
    if (folder / "system_impulse.csv").is_file():
        imp = _csv_matrix(folder / "system_impulse.csv")[:, 0]
        imp = imp[: np.flatnonzero(imp)[-1] + 1] if np.any(imp) else imp
        impulse = imp - np.median(imp[:4])
    res = np.abs(fit.residual)
    return MeasuredPulses(
        samples=samples, valid=valid, dt_ns=1.0, bin0=fit.bin0, step=step, origin=fit.origin, line=line,
        outgoing=outgoing, impulse=impulse, divergence_mrad=divergence_mrad, wavelength_nm=wavelength_nm,
        name=folder.name,
        meta=dict(source="NEON CSV", geometry=dict(
            rebuilt=True, lines=int(line.max() + 1), scanner_z_m=fit.scanner[:, 2].round(2).tolist(),
            residual_x_max_m=float(res[:, 0].max()), residual_y_max_m=float(res[:, 1].max()),
            residual_x_p95_m=float(np.percentile(res[:, 0], 95)),
            residual_y_p95_m=float(np.percentile(res[:, 1], 95)))))


def common_point(points, directions) -> np.ndarray:
    """(3,) the point nearest, in least squares, to the lines through ``points`` along ``directions``.

    Every pulse of one scan line leaves the scanner: where a file gives each
    pulse's line but not its origin, the lines' common point is the scanner.

    >>> d = np.array([[0.1, 0, -1], [-0.1, 0.05, -1], [0, -0.1, -1]])
    >>> (common_point(np.array([0.0, 0, 1000]) + 9000 * d, d).round(6) + 0.0).tolist()
    [0.0, 0.0, 1000.0]
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    proj = np.eye(3)[None] - u[:, :, None] * u[:, None, :]  # (I - u u^T) per line
    A = proj.sum(axis=0)
    b = np.einsum("nij,nj->i", proj, p)
    if np.linalg.cond(A) > 1e12:
        raise InputError("the pulses' lines are (nearly) parallel: their common point, the scanner, cannot be found")
    return np.linalg.solve(A, b)


def straight_trajectory(points, directions, times) -> tuple[np.ndarray, np.ndarray]:
    """The straight, steady flight ``S(t) = S0 + v t`` nearest, in least squares, to every pulse's line.

    Pulse ``i`` left the sensor at ``S(t_i)`` along its line through
    ``points[i]``: the perpendicular distances of ``S(t_i)`` from the lines are
    linear in ``S0`` and ``v``.

    Returns ``S0`` (3,) metres and ``v`` (3,) metres per unit of ``times``.

    >>> t = np.linspace(0, 1, 50)
    >>> d = np.c_[0.1 * np.sin(40 * t), 0.1 * np.cos(33 * t), -np.ones(50)]
    >>> truth = np.array([0.0, 0, 1000]) + t[:, None] * [60.0, 0, 0]
    >>> S0, v = straight_trajectory(truth + 5000 * d, d, t)
    >>> (S0.round(3) + 0.0).tolist(), (v.round(3) + 0.0).tolist()  # + 0.0: no negative zeros
    ([0.0, 0.0, 1000.0], [60.0, 0.0, 0.0])
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    u = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    t = np.asarray(times, dtype=np.float64).reshape(-1)
    proj = np.eye(3)[None] - u[:, :, None] * u[:, None, :]
    A = np.concatenate([proj, proj * t[:, None, None]], axis=2).reshape(-1, 6)  # rows: (I - uu^T)[S0, v t]
    b = np.einsum("nij,nj->ni", proj, p).reshape(-1)
    sol, _, rank, _ = np.linalg.lstsq(A, b, rcond=None)
    if rank < 6:
        raise InputError("the pulses' lines and times do not fix a flight (too few pulses, or all parallel)")
    return sol[:3], sol[3:]


#: What a LAS file does not say, for a file that names no clsim preset: Leica's ALS50-II.
LAS_DEFAULTS = {"divergence_mrad": 0.11, "wavelength_nm": 1064.0}


def _sensor_defaults(path) -> tuple[dict, str]:
    """Divergence and wavelength for a LAS file: the clsim preset its system identifier names
    (``clsim NAME``, as ``clsim survey`` writes), else :data:`LAS_DEFAULTS`; and where they came from."""
    import laspy

    try:
        with laspy.open(path) as f:
            ident = str(f.header.system_identifier).strip("\x00 ")
    except Exception:  # noqa: BLE001 - the waveform reader says what is wrong with the file
        ident = ""
    if ident.startswith("clsim "):
        try:
            sensor = Sensor.preset(ident.split()[1])
        except Exception:  # noqa: BLE001 - an unknown name: the defaults
            sensor = None
        if sensor is not None:
            return ({"divergence_mrad": float(sensor.divergence_mrad), "wavelength_nm": float(sensor.wavelength_nm)},
                    f"the file's system identifier names clsim's preset {sensor.name}")
    return dict(LAS_DEFAULTS), "not in the file: Leica ALS50-II values assumed (0.11 mrad, 1064 nm)"


def read_las_pulses(path, *, divergence_mrad: float | None = None, wavelength_nm: float | None = None) -> MeasuredPulses:
    """Pulses of a LAS 1.3/1.4 file with waveform packets, one per GPS time (the first point's packet).

    The file gives each waveform's sample 0 and its line (the points'
    parametric ``x(t), y(t), z(t)``) but not the sensor's position: a straight
    flight at a steady speed is fitted to the lines and the GPS times
    (:func:`straight_trajectory`), and each pulse's origin is the point of its
    own line nearest to the sensor at its time.  Scan lines: the runs of pulses
    between gaps in time.  Files without an outgoing
    pulse or impulse response get the pulse estimated from their own strongest
    single returns when they are prepared (:func:`clsim.replay.prepare`).

    Parameters
    ----------
    path : str or path
        ``.las`` with its ``.wdp`` beside (or waveforms in the file).
    divergence_mrad : float, optional
        Beam divergence half angle at 1/e^2.  Not in a LAS file: by default
        the clsim preset the file's system identifier names (``clsim NAME``,
        a ``clsim survey`` file), else Leica's ALS50-II, 0.22 mrad full angle
        at 1/e^2: state yours.
    wavelength_nm : float, optional
        As ``divergence_mrad`` (the ALS50-II: 1064 nm).

    Returns
    -------
    MeasuredPulses
        ``meta["sensor"]`` says where the divergence and wavelength came
        from; ``meta["returns_ns"]``: per pulse, the times (ns from its sample 0) of
        the file's discrete returns; ``meta["geometry"]``: the scanners found.
    """
    from clsim.waveforms.io import read_las_waveforms

    las = read_las_waveforms(path)
    defaults, said = _sensor_defaults(path)
    if divergence_mrad is None:
        divergence_mrad = defaults["divergence_mrad"]
    if wavelength_nm is None:
        wavelength_nm = defaults["wavelength_nm"]
    has = np.flatnonzero(las.packet >= 0)
    if not has.size:
        raise InputError(f"{Path(path).name}: no point has a waveform packet; nothing to replay")
    times = las.gps_time[has]
    order = np.lexsort((las.return_number[has], times))
    has, times = has[order], times[order]
    first = np.r_[True, np.diff(times) != 0]
    group = np.cumsum(first) - 1
    heads = has[first]
    n = len(heads)
    specs = {int(las.packet_descriptor[las.packet[i]]) for i in heads}
    spacing = {las.descriptors[k].spacing_ps for k in specs}
    if len(spacing) != 1:
        raise InputError(f"{Path(path).name}: the waveforms use {len(spacing)} sample spacings {sorted(spacing)} ps; "
                         "a replay needs one sample clock")
    dt_ns = spacing.pop() / 1000.0
    width = max(las.descriptors[k].n_samples for k in specs)
    samples = np.zeros((n, width))
    valid = np.zeros((n, width), dtype=bool)
    bin0 = np.zeros((n, 3))
    per_ns = np.zeros((n, 3))
    for j, i in enumerate(heads):
        y = las.samples(int(i), volts=False).astype(np.float64)
        samples[j, : y.size] = y
        valid[j, : y.size] = True
        bin0[j], per_ns[j] = las.waveform_origin(int(i))
    returns = [[] for _ in range(n)]
    for g, i in zip(group, has):
        # the return's time from the head pulse's sample 0 (points of one pulse may carry their own packets)
        o, d = las.waveform_origin(int(i))
        returns[g].append(float(las.return_location_ps[i]) / 1000.0 + float((o - bin0[g]) @ d / (d @ d)))
    step = per_ns * dt_ns
    unit = step / np.linalg.norm(step, axis=1, keepdims=True)
    t = las.gps_time[heads] - las.gps_time[heads].min()
    gaps = np.diff(t)
    line = np.r_[0, np.cumsum(gaps > 20 * np.median(gaps))] if n > 1 else np.zeros(1, np.int64)
    S0, v = straight_trajectory(bin0, unit, t)
    S = S0 + t[:, None] * v
    s = np.einsum("ij,ij->i", bin0 - S, unit)
    origin = bin0 - s[:, None] * unit
    miss = np.linalg.norm(np.cross(S - bin0, unit), axis=1)
    return MeasuredPulses(
        samples=samples, valid=valid, dt_ns=dt_ns, bin0=bin0, step=step, origin=origin, line=line,
        divergence_mrad=divergence_mrad, wavelength_nm=wavelength_nm, name=Path(path).stem,
        meta=dict(source="LAS waveform packets", returns_ns=[np.array(r) for r in returns],
                  sensor={"divergence_mrad": float(divergence_mrad), "wavelength_nm": float(wavelength_nm),
                          "defaults": said},
                  geometry=dict(rebuilt=True, lines=int(line.max() + 1),
                                scanner_height_m=float(np.median(S[:, 2] - bin0[:, 2])),
                                speed_m_s=float(np.linalg.norm(v)),
                                note="sensor positions: a straight, steady flight fitted to the pulses' lines",
                                off_line_median_m=float(np.median(miss)), off_line_max_m=float(miss.max()))))


#: a HELIOS++ full-waveform text file states neither: its shared case's beam (0.25 mrad half angle) and 1064 nm
HELIOS_DEFAULTS = {"divergence_mrad": 0.25, "wavelength_nm": 1064.0}


def read_helios_pulses(path, *, divergence_mrad=None, wavelength_nm=None) -> MeasuredPulses:
    """Measured pulses from a HELIOS++ full-waveform text file (``*_fullwave.txt``).

    HELIOS++ writes each pulse's beam origin and direction and its samples on a one-way time axis
    (``distance / c``), so a sample ``k`` lies at ``origin + c (t_min + k dt) direction``: the
    geometry is the file's own, nothing is rebuilt.  The sample spacing in the round-trip time the
    replay simulates is twice the file's; scan lines are split where the GPS time jumps (20 times
    the median spacing); the divergence and wavelength, which the file does not state, default to
    :data:`HELIOS_DEFAULTS` (``meta["sensor"]`` says so).
    """
    from clsim.waveforms.io.helios import C_M_PER_NS, read_helios_fullwave

    fw = read_helios_fullwave(path)
    n = len(fw)
    if not n:
        raise InputError(f"{Path(path).name}: no pulse in the file; nothing to replay")
    dt = fw.dt_ns
    if np.any(dt <= 0) or np.ptp(dt) > 1e-6 * float(dt.max()):
        raise InputError(f"{Path(path).name}: the pulses' sample spacings differ ({float(dt.min()):g} to "
                         f"{float(dt.max()):g} ns) or a pulse has one sample; a replay needs one sample clock")
    said = {k: v is None for k, v in (("divergence_mrad", divergence_mrad), ("wavelength_nm", wavelength_nm))}
    divergence_mrad = HELIOS_DEFAULTS["divergence_mrad"] if divergence_mrad is None else divergence_mrad
    wavelength_nm = HELIOS_DEFAULTS["wavelength_nm"] if wavelength_nm is None else wavelength_nm
    one_way = float(np.median(dt))
    width = max(len(w) for w in fw.samples)
    samples = np.zeros((n, width))
    valid = np.zeros((n, width), dtype=bool)
    for i, w in enumerate(fw.samples):
        samples[i, :len(w)] = w
        valid[i, :len(w)] = True
    d = fw.direction
    bin0 = fw.origin + (C_M_PER_NS * fw.min_time_ns)[:, None] * d
    step = C_M_PER_NS * one_way * d
    t = fw.gps_time - fw.gps_time.min()
    gaps = np.diff(t)
    line = np.r_[0, np.cumsum(gaps > 20 * np.median(gaps))] if n > 1 else np.zeros(1, np.int64)
    return MeasuredPulses(
        samples=samples, valid=valid, dt_ns=2.0 * one_way, bin0=bin0, step=step, origin=fw.origin.copy(),
        line=np.asarray(line, dtype=np.int64), divergence_mrad=float(divergence_mrad), wavelength_nm=float(wavelength_nm),
        name=Path(path).stem,
        meta=dict(source="HELIOS++ full waveform (text)", returns_ns=[np.array([]) for _ in range(n)],
                  sensor={"divergence_mrad": float(divergence_mrad), "wavelength_nm": float(wavelength_nm),
                          "defaults": "HELIOS++'s file states neither: "
                                      + ", ".join(k for k, v in said.items() if v) + " from HELIOS_DEFAULTS"
                          if any(said.values()) else "given"},
                  geometry=dict(rebuilt=False, lines=int(np.max(line) + 1),
                                note="beam origins and directions as HELIOS++ wrote them; its one-way time axis "
                                     "doubled to the round trip")))


def read_measured(path, *, divergence_mrad=None, wavelength_nm=None) -> MeasuredPulses:
    """The measured pulses of ``path``: a NEON record folder (or its ``return.csv``), a LAS file with
    waveform packets (``.wdp`` beside) or a HELIOS++ full-waveform text file (``.txt``);
    ``divergence_mrad`` (half angle at 1/e^2) else each reader's default."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{str(path)!r} does not exist")
    kwargs = {k: float(v) for k, v in (("divergence_mrad", divergence_mrad), ("wavelength_nm", wavelength_nm))
              if v is not None}
    if path.is_file() and path.suffix.lower() in (".las", ".laz"):
        if path.suffix.lower() == ".laz":
            raise InputError(f"{path.name}: LASzip files do not carry the waveform packets; give the .las with its "
                             ".wdp beside")
        return read_las_pulses(path, **kwargs)
    if path.is_file() and path.suffix.lower() == ".txt":
        return read_helios_pulses(path, **kwargs)
    if path.is_file() and path.suffix.lower() == ".pls":
        raise InputError(f"{path.name}: replays read NEON record folders and LAS waveform packets; PulseWaves "
                         "is not read as pulses yet (decompose it with clsim decompose)")
    folder = path if path.is_dir() else path.parent
    if not (folder / "return.csv").is_file():
        raise InputError(f"{str(folder)!r} holds no return.csv: pass a NEON record folder (return.csv, "
                         "geolocation.csv), a LAS file with waveform packets or a HELIOS++ *_fullwave.txt")
    return read_neon(folder, **kwargs)
