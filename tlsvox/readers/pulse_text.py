"""Pulse-grouped multi-return exports: echoes grouped into pulses by their time.

Simulators and many processing tools write one row per echo with the time
of its pulse, its return index and the pulse's return count; the echoes of a
pulse share its time.  Pulses that returned nothing are written as *miss
rows*: a row whose return count or index is 0, whose coordinates are NaN, or
a point placed far along the beam (beyond ``miss_range``).  A miss row is a
pulse without echo (a gap, which leaf area density needs), never an echo.
In a pulse that has echoes too (other simulators write one for a partly
intercepted pulse, numbered past its echoes and counted in its return count),
the miss row is the beam's *tail*: the share of the pulse that went on, one of
its ``n`` targets, so each echo removes ``1/n`` and ``1/n`` flies on.

- :func:`read_pulse_text`: ASCII ``x y z time return_index return_count``
  (whitespace or commas; an optional header line names the columns, and may
  add ``reflectance_db``, ``intensity`` or ``beam_fraction``) into a
  :class:`~tlsvox.scan.Scan` with its full pulse table;
- HELIOS++ point output (``legNNN_points.xyz``: ``x y z intensity echo_width
  return_number number_of_returns fullwave_index hit_object_id classification
  gps_time``, 11 columns, no header; the layout of HELIOS++'s
  ``DirectMeasurementWriteStrategy``): the same reader, its pulses grouped by
  the full-waveform index (one per pulse, shared with its
  ``*_fullwave.txt`` line). HELIOS++ writes no rows for pulses that hit
  nothing, so such a scan comes without a pulse table, its echoes in the
  scanner's frame (translated by ``origin``, its pose that translation):
  ``voxelize`` rebuilds the empty pulses from the angular grid (``tlsvox
  voxelize --angular-grid``) and says so when none is given;
- :func:`pulse_ids_from_time`: the pulse of every echo from its time, checked
  against the return numbers; :meth:`Scan.read <tlsvox.scan.Scan.read>` uses
  it for LAS/LAZ files without a ``pulse_id`` dimension whose pulses are
  grouped by GPS time.

Examples
--------
>>> import tempfile, pathlib
>>> p = pathlib.Path(tempfile.mkdtemp()) / "sim.txt"
>>> _ = p.write_text("1 0 0 0.1 1 2\\n3 0 0 0.1 2 2\\n0 5e6 0 0.2 0 0\\n")
>>> scan = read_pulse_text(p)
>>> len(scan), len(scan.pulses), scan.pulses.n_echoes.tolist()
(2, 2, [2, 0])
"""

from __future__ import annotations

import os
import re
import warnings
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError, ScanFileError
from tlsvox.scan import PulseTable, Scan

__all__ = ["COLUMNS", "DEFAULT_MISS_RANGE_M", "HELIOS_COLUMNS", "looks_pulse_grouped", "pulse_ids_from_time",
           "read_pulse_text"]

#: the columns of a file without a header line, in order
COLUMNS = ("x", "y", "z", "time", "return_index", "return_count")
#: HELIOS++'s point output, in order (no header line; 11 columns)
HELIOS_COLUMNS = ("x", "y", "z", "intensity", "echo_width", "return_index", "return_count", "fullwave_index",
                  "hit_object_id", "classification", "time")
#: a row farther than this from the scanner is a miss (no scanner records echoes 10 km away)
DEFAULT_MISS_RANGE_M = 10_000.0

_ALIASES = {
    "x": "x", "y": "y", "z": "z",
    "time": "time", "gps_time": "time", "gpstime": "time", "t": "time", "timestamp": "time",
    "return_index": "return_index", "return_number": "return_index", "returnnumber": "return_index",
    "echo_index": "return_index", "return": "return_index",
    "return_count": "return_count", "number_of_returns": "return_count", "numberofreturns": "return_count",
    "n_returns": "return_count", "returns": "return_count", "echo_count": "return_count",
    "reflectance_db": "reflectance_db", "reflectance": "reflectance_db", "intensity": "intensity",
    "beam_fraction": "beam_fraction", "fraction": "beam_fraction",
    "fullwave_index": "fullwave_index", "fullwaveindex": "fullwave_index",
}


def _header(line: str) -> list[str] | None:
    """Column names of a header line (``# x y z ...`` too), or None for a data line."""
    text = line.strip().lstrip("#/").strip()
    tokens = [t for t in re.split(r"[,\s;]+", text) if t]
    if not tokens:
        return None
    try:
        [float(t) for t in tokens]
        return None
    except ValueError:
        return [t.lower() for t in tokens]


def _first_lines(path: Path, n: int) -> list[str]:
    out = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            if line.strip():
                out.append(line)
            if len(out) >= n:
                break
    return out


def looks_pulse_grouped(path: str | os.PathLike) -> bool:
    """True when a text file reads as a pulse-grouped export.

    Either a header line names the return columns, or every one of the first
    200 rows has six numbers with whole return index and count,
    ``0 <= index <= count <= 31``, and times that never decrease (a colour
    ``x y z r g b`` file fails the last two).
    """
    lines = _first_lines(Path(path), 201)
    if not lines:
        return False
    names = _header(lines[0])
    if names is not None:
        mapped = {_ALIASES.get(n) for n in names}
        return {"return_index", "return_count"} <= mapped
    try:
        parsed = [[float(v) for v in re.split(r"[,\s;]+", ln.strip()) if v] for ln in lines[:200]]
    except ValueError:
        return False
    widths = {len(r) for r in parsed}
    if len(widths) > 1:  # rows of a pulse layout, some cut short: the reader names them
        return len(parsed[0]) in (6, len(HELIOS_COLUMNS))
    rows = np.array(parsed)
    if rows.ndim != 2 or rows.shape[1] not in (6, len(HELIOS_COLUMNS)):
        return False
    if rows.shape[1] == len(HELIOS_COLUMNS):  # HELIOS++: pulses by their full-waveform index
        idx, cnt, t = rows[:, 5], rows[:, 6], rows[:, 7]
        return bool(np.all(t == np.round(t)) and np.all(idx == np.round(idx)) and np.all(cnt == np.round(cnt))
                    and np.all((idx >= 1) & (idx <= cnt) & (cnt <= 31)))
    idx, cnt, t = rows[:, 4], rows[:, 5], rows[:, 3]
    whole = np.all(idx == np.round(idx)) and np.all(cnt == np.round(cnt))
    return bool(whole and np.all((idx >= 0) & (idx <= cnt) & (cnt <= 31)) and np.all(np.diff(t) >= 0))


def pulse_ids_from_time(time, return_index, return_count, *, where: str = "the file") -> np.ndarray:
    """Pulse row (0..P-1, in time order) of every echo, from its pulse's time.

    Parameters
    ----------
    time : (N,) float
        Time of each echo's pulse (GPS time); the echoes of one pulse share it.
    return_index, return_count : (N,) int
        1-based echo index within its pulse, and the pulse's echo count.
    where : str
        Names the source in error messages.

    Returns
    -------
    (N,) int64

    Raises
    ------
    InputError
        A time is not finite, the echoes of one time disagree on their
        return count, or two of them have the same return index (then the
        times do not group pulses).
    """
    t = np.asarray(time, dtype=np.float64)
    idx = np.asarray(return_index, dtype=np.int64)
    cnt = np.asarray(return_count, dtype=np.int64)
    if not np.all(np.isfinite(t)):
        raise InputError(f"{where}: {int((~np.isfinite(t)).sum())} rows have a time that is not a number; "
                         "every echo needs its pulse's time")
    uniq, pid = np.unique(t, return_inverse=True)
    if len(t) == 0:
        return pid.astype(np.int64)
    lo = np.full(len(uniq), np.iinfo(np.int64).max)
    hi = np.full(len(uniq), -1)
    np.minimum.at(lo, pid, cnt)
    np.maximum.at(hi, pid, cnt)
    bad = np.nonzero(lo != hi)[0]
    if len(bad):
        raise InputError(f"{where}: the echoes of the pulse at time {float(uniq[bad[0]])!r} disagree on the return count "
                         f"({lo[bad[0]]} and {hi[bad[0]]}); {len(bad)} pulses are inconsistent: the times do not "
                         "group the echoes into pulses")
    key = pid * 256 + np.clip(idx, 0, 255)
    if len(np.unique(key)) != len(key):
        dup = np.nonzero(np.bincount(key.astype(np.int64) - key.min()) > 1)[0][0] + key.min()
        raise InputError(f"{where}: two echoes of the pulse at time {float(uniq[dup // 256])!r} both have return index "
                         f"{dup % 256}: the times do not group the echoes into pulses (a time per pulse expected)")
    return pid.astype(np.int64)


def read_pulse_text(path: str | os.PathLike, *, origin=(0.0, 0.0, 0.0), miss_range: float = DEFAULT_MISS_RANGE_M,
                    scan_id: int = 0, name: str | None = None) -> Scan:
    """Read an ASCII pulse-grouped export (one row per echo, miss rows for empty pulses).

    Parameters
    ----------
    path : path-like
        Rows ``x y z time return_index return_count`` (whitespace or commas);
        an optional first line names the columns (``# x y z gps_time
        return_number number_of_returns reflectance_db``: any order, and
        ``reflectance_db``, ``intensity`` and ``beam_fraction`` are kept).
        ``#`` and ``//`` lines after it are comments.
    origin : (3,) float, metres
        The scanner's position in the file's coordinates (every beam starts
        there).
    miss_range : float, metres
        Rows farther from ``origin`` are misses (default 10 km).
    scan_id : int
    name : str, optional
        Default: the file stem.

    Returns
    -------
    Scan
        Echoes in the file's coordinates, ``pulse_id`` and a pulse table with
        every pulse (its direction from its nearest echo, or from its miss
        row) in time order.  A ``NAME.pose.json`` sidecar beside the file
        gives its pose, name and scan id.

    Raises
    ------
    ScanFileError
        The file does not exist.
    InputError
        Malformed rows (one line naming the row and what is wrong), a miss
        row without a direction, or echoes whose times do not group pulses.
    """
    from tlsvox.readers.las import read_pose_sidecar

    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise ScanFileError(f"scan file {where!r} does not exist")
    lines = _first_lines(path, 1)
    if not lines:
        raise InputError(f"scan file {where!r} is empty; expected rows of x y z time return_index return_count")
    o = np.asarray(origin, dtype=np.float64).reshape(-1)
    if o.shape != (3,) or not np.all(np.isfinite(o)):
        raise InputError(f"origin={origin!r} must be the scanner's x, y, z in the file's coordinates (3 numbers)")
    if not (np.isfinite(miss_range) and miss_range > 0):
        raise InputError(f"miss_range={miss_range!r} must be a distance > 0 in metres")
    names = _header(lines[0])
    skip = 0
    if names is not None:
        skip = 1
        cols = [_ALIASES.get(n, n) for n in names]
        missing = [c for c in COLUMNS if c not in cols]
        if missing:
            raise InputError(f"{where}: the header names {names} but not {missing}; a pulse-grouped file needs "
                             f"the columns {' '.join(COLUMNS)}")
    else:
        cols = list(COLUMNS)
        if len(re.split(r"[,\s;]+", lines[0].strip())) == len(HELIOS_COLUMNS):
            cols = list(HELIOS_COLUMNS)
    delimiter = "," if "," in (_first_lines(path, 2)[-1]) else None
    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="loadtxt: input contained no data")  # said below, in words
            data = np.loadtxt(path, delimiter=delimiter, comments=("#", "//"), skiprows=skip, ndmin=2,
                              dtype=np.float64)
    except ValueError as err:
        why = str(err).split("; use `usecols`")[0]  # numpy's advice is about its own call, not the user's file
        raise InputError(f"{where}: not a pulse-grouped text file ({' '.join(cols)}): {why}; fix or drop that row "
                         "(a truncated export?)") from None
    if data.size == 0:
        raise InputError(f"{where}: no rows after the header; expected rows of {' '.join(cols)}")
    if data.shape[1] != len(cols):
        raise InputError(f"{where}: rows have {data.shape[1]} columns but {len(cols)} are expected "
                         f"({' '.join(cols)}); add a header line naming the columns")
    c = {name: data[:, i] for i, name in enumerate(cols) if name in _ALIASES.values()}
    xyz = np.column_stack([c["x"], c["y"], c["z"]])
    idx, cnt, t = c["return_index"], c["return_count"], c["time"]
    grouping = "time"
    if "fullwave_index" in c:  # HELIOS++: one full-waveform index per pulse, the truer key than a rounded time
        t, grouping = c["fullwave_index"], "fullwave_index"
    for label, v in (("return_index", idx), ("return_count", cnt)):
        bad = ~np.isfinite(v) | (v != np.round(v)) | (v < 0) | (v > 255)
        if bad.any():
            row = int(np.nonzero(bad)[0][0])
            raise InputError(f"{where}: row {row + 1 + skip}: {label}={float(v[row])!r} must be a whole number 0..255")
    finite = np.all(np.isfinite(xyz), axis=1)
    rng = np.full(len(xyz), np.inf)
    rng[finite] = np.linalg.norm(xyz[finite] - o, axis=1)
    miss = (cnt == 0) | (idx == 0) | ~finite | (rng > miss_range)
    bad = ~miss & (idx > cnt) & (cnt > 0)  # a miss row may carry any index (some tools number it past the echoes)
    if bad.any():
        row = int(np.nonzero(bad)[0][0])
        raise InputError(f"{where}: row {row + 1 + skip}: return_index {int(idx[row])} is above its "
                         f"return_count {int(cnt[row])}")
    undirected = miss & (~finite | (rng == 0))
    if undirected.any():
        row = int(np.nonzero(undirected)[0][0])
        raise InputError(f"{where}: {int(undirected.sum())} miss rows (pulses without echo) have no coordinates, "
                         f"so their beam direction is unknown (first: row {row + 1 + skip}); export misses as a "
                         "point far along the beam, or drop them and rebuild the empty pulses from the angular "
                         "grid (tlsvox voxelize --angular-grid)")
    zero = ~miss & (rng == 0)
    if zero.any():
        raise InputError(f"{where}: {int(zero.sum())} echoes sit at the scanner origin {o.tolist()}; "
                         "check origin= (CLI --scan-origin)")
    if not np.all(np.isfinite(t)):
        raise InputError(f"{where}: {int((~np.isfinite(t)).sum())} rows have a time that is not a number; "
                         "every row needs its pulse's time")
    times, pid = np.unique(t, return_inverse=True)
    p = len(times)
    n_miss = np.bincount(pid[miss], minlength=p)
    n_echo = np.bincount(pid[~miss], minlength=p)
    tail = (n_miss > 0) & (n_echo > 0)  # a partly intercepted pulse: its miss row is the share that went on
    twice = np.nonzero(n_miss > 1)[0]
    if len(twice):
        raise InputError(f"{where}: the pulse at time {float(times[twice[0]])!r} has {n_miss[twice[0]]} miss rows; "
                         "one per pulse expected")
    pulse_ids_from_time(t[~miss], idx[~miss], cnt[~miss], where=where)  # the echoes of a time agree
    # a pulse's direction: its nearest echo, or its miss row
    order = np.lexsort((rng, pid))
    first = np.full(p, -1)
    first[pid[order][::-1]] = order[::-1]
    v = xyz[first] - o
    direction = v / np.linalg.norm(v, axis=1, keepdims=True)
    count = np.zeros(p, np.int64)
    np.maximum.at(count, pid[~miss], cnt[~miss].astype(np.int64))
    count = np.maximum(count, n_echo + tail)  # the tail counts as one of the pulse's targets
    echo = ~miss
    extra = {k: c[k][echo] for k in ("reflectance_db", "intensity", "beam_fraction") if k in c}
    doc = read_pose_sidecar(path)
    if cols == list(HELIOS_COLUMNS) and not miss.any():
        return _without_empty_pulses(xyz[echo] - o, o, idx[echo], np.maximum(cnt[echo], idx[echo]), pid[echo],
                                     extra, doc, scan_id, name or path.stem, where)
    n_of = np.maximum(np.maximum(cnt[echo], idx[echo]), count[pid[echo]])  # with its tail, if it has one
    return Scan(xyz=xyz[echo], return_number=idx[echo], number_of_returns=n_of,
                pulse_id=pid[echo], pulses=PulseTable(direction, np.minimum(count, 255), origin=o),
                pose=doc.get("pose"), pose_true=doc.get("pose_true"),
                scan_id=int(doc.get("scan_id", scan_id)), name=doc.get("name", name or path.stem),
                meta={**(doc.get("meta") or {}), "pulse_grouping": grouping,
                      "miss_rows": int(miss.sum()), "tail_rows": int(tail.sum()), "source": where,
                      **({"layout": "HELIOS++ point output"} if cols == list(HELIOS_COLUMNS) else {})}, **extra)


def _without_empty_pulses(xyz, origin, index, count, pid, extra, doc, scan_id, name, where) -> Scan:
    """A scan whose file recorded no pulse that missed (HELIOS++ writes none): echoes in the scanner's frame
    (translated by ``origin``), pulses by ``pid``, and no pulse table, so that voxelize rebuilds the empty
    pulses from the scanner's angular grid (``--angular-grid``), or says it needs one."""
    pose = doc.get("pose")
    if pose is None:
        pose = np.eye(4)
        pose[:3, 3] = origin
    return Scan(xyz=xyz, return_number=index, number_of_returns=count, pulse_id=pid, pulses=None, pose=pose,
                pose_true=doc.get("pose_true"), scan_id=int(doc.get("scan_id", scan_id)), name=doc.get("name", name),
                meta={**(doc.get("meta") or {}), "pulse_grouping": "fullwave_index", "miss_rows": 0,
                      "source": where, "layout": "HELIOS++ point output",
                      "empty_pulses": "none recorded (HELIOS++ writes no row for a pulse that hit nothing): "
                                      "rebuilt from the angular grid (--angular-grid)"}, **extra)
