"""Read point clouds of any common format into a :class:`~tlsvox.scan.Scan`.

LAS/LAZ go through :func:`tlsvox.readers.las.read_las` (laspy + lazrs, extra bytes and sidecar
files); PLY, PCD and the text formats XYZ / XYZI / PTS go through Open3D's
tensor I/O, which keeps per-point attributes such as ``intensity`` or
``reflectance``.  Pulse-grouped text exports (``x y z time return_index
return_count`` with miss rows: ``.txt``, ``.csv``, ``.asc``, or an ``.xyz``
that reads as one) go through :func:`tlsvox.readers.pulse_text.read_pulse_text`,
so their miss rows become pulses without echo, never echoes.  Every reader ends
in :func:`check_scan`, so a caller gets
one clear error for the cases that make a scan useless: no points, a single
point, NaN coordinates, or no reflectance/intensity when one is needed.

Examples
--------
>>> import numpy as np
>>> from tlsvox.scan import Scan
>>> check_scan(Scan(xyz=np.zeros((1, 3)), name="lonely"))
Traceback (most recent call last):
...
voxlidar.errors.InputError: scan 'lonely': has 1 point(s) but at least 2 are needed; ...
"""

from __future__ import annotations

import enum
import os
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError, ScanFileError
from tlsvox.scan import Scan
from voxlidar.safeio import describe_kind, file_kind

__all__ = ["ScanFormat", "check_scan", "read_any", "read_open3d", "scan_format"]


class ScanFormat(enum.Enum):
    """Point-cloud file formats :func:`read_any` understands."""

    LAS = "las"
    LAZ = "laz"
    PLY = "ply"
    PCD = "pcd"
    XYZ = "xyz"
    XYZI = "xyzi"
    PTS = "pts"
    PULSES = "pulses"  #: pulse-grouped text (tlsvox.readers.pulse_text); suffixes .txt, .csv, .asc

    @classmethod
    def parse(cls, value: str | ScanFormat) -> ScanFormat:
        """The format named by ``value`` (a member, a name or a file suffix)."""
        if isinstance(value, cls):
            return value
        key = str(value).lower().lstrip(".")
        key = _PULSE_SUFFIXES.get(key, key)
        try:
            return cls(key)
        except ValueError as err:
            valid = ", ".join(m.value for m in cls)
            raise InputError(
                f"format={value!r} is not a point-cloud format tlsvox reads; "
                f"expected one of: {valid} (or give a file with one of these suffixes)"
            ) from err

    @classmethod
    def from_path(cls, path: str | os.PathLike) -> ScanFormat:
        suffix = Path(path).suffix
        if not suffix:
            valid = ", ".join("." + m.value for m in cls)
            raise InputError(
                f"path={str(path)!r} has no file suffix; expected one of {valid}, "
                "or pass format= explicitly"
            )
        return cls.parse(suffix)


_PULSE_SUFFIXES = {"txt": "pulses", "csv": "pulses", "asc": "pulses"}

# per-point attribute names found in PLY/PCD exports (CloudCompare prefixes
# scalar fields with "scalar_") -> Scan field
_ATTRIBUTE_ALIASES = {
    "reflectance_db": "reflectance_db",
    "reflectance": "reflectance_db",  # RIEGL's "Reflectance" is in dB
    "intensity": "intensity",
    "intensities": "intensity",
    "return_number": "return_number",
    "number_of_returns": "number_of_returns",
    "pulse_id": "pulse_id",
    "truth_material": "truth_material",
}


def check_scan(scan: Scan, *, min_points: int = 2, require_reflectance: bool = False,
               source: str | None = None) -> Scan:
    """Check that a scan can be used, and return it unchanged.

    Parameters
    ----------
    scan : Scan
    min_points : int, default 2
        Fewest points accepted.  A scan with a single point has no geometry
        (no neighbourhood, no extent): registration and classification need
        many more, and pass their own minimum.
    require_reflectance : bool, default False
        If True, the scan must carry ``reflectance_db`` or ``intensity``.
    source : str, optional
        File the scan came from, named in error messages.

    Raises
    ------
    InputError
        Too few points, non-finite coordinates, or no reflectance/intensity
        when ``require_reflectance``.
    """
    where = f"scan {scan.name!r}" + (f" ({source})" if source else "")
    n = len(scan)
    if n == 0:
        raise InputError(f"{where}: has no points; check the export (empty file or all points filtered)")
    if n < min_points:
        raise InputError(
            f"{where}: has {n} point(s) but at least {min_points} are needed; "
            "a single-point scan has no geometry to register or classify"
        )
    if not np.all(np.isfinite(scan.xyz)):  # Scan checks this too; kept for mutated scans
        raise InputError(f"{where}: NaN or inf coordinates; remove those points first")
    if require_reflectance:
        have_db = scan.reflectance_db is not None and np.any(np.isfinite(scan.reflectance_db))
        have_i = scan.intensity is not None and np.any(scan.intensity > 0)
        if not (have_db or have_i):
            raise InputError(
                f"{where}: has neither reflectance (extra dimension 'reflectance_db' or "
                "'Reflectance', dB) nor non-zero intensity, but reflectance is needed "
                "(classification, target detection); re-export the scan with reflectance, "
                "or register it without targets (method='fpfh')"
            )
    return scan


def scan_format(path: Path, format=None) -> ScanFormat:
    """The format of a point-cloud file: ``format`` when given, else its content
    (LAS/LAZ, PLY and PCD by their first bytes; XYZ, XYZI and PTS text by their
    first lines, whichever of the three the suffix says; an ``.xyz`` whose rows read as
    pulse-grouped, see `tlsvox.readers.pulse_text.looks_pulse_grouped`), else
    its suffix."""
    kind = file_kind(path) if format is None and path.is_file() else None  # the content decides, not the name
    if kind == "las":
        return ScanFormat.LAS
    if kind == "ply":
        return ScanFormat.PLY
    if kind == "pcd":
        return ScanFormat.PCD
    fmt = ScanFormat.from_path(path) if format is None else ScanFormat.parse(format)
    if kind == "text" and format is None and fmt in _TEXT_FORMATS:
        fmt = _text_layout(path) or fmt
    if fmt is ScanFormat.XYZ and kind == "text" and format is None:
        from tlsvox.readers.pulse_text import looks_pulse_grouped

        if looks_pulse_grouped(path):  # x y z time return_index return_count: its miss rows must not be echoes
            return ScanFormat.PULSES
    if kind is not None and kind != "empty" and fmt in (ScanFormat.LAS, ScanFormat.LAZ):
        raise InputError(f"{path} is not a LAS/LAZ file: it is {describe_kind(kind)} (a LAS file starts with "
                         "'LASF'); check the file, or give it the suffix of what it holds")
    return fmt


_TEXT_FORMATS = (ScanFormat.XYZ, ScanFormat.XYZI, ScanFormat.PTS)


def _text_layout(path: Path) -> ScanFormat | None:
    """XYZ, XYZI or PTS from a text file's first lines (a PTS starts with its point count);
    None when they do not say."""
    with open(path, "rb") as fh:
        lines = [ln.split() for ln in fh.read(4096).decode("utf-8", "replace").splitlines() if ln.strip()]
    if len(lines) < 2:
        return None
    first, second = lines[0], lines[1]
    if len(first) == 1 and first[0].isdigit() and len(second) >= 3:
        return ScanFormat.PTS
    try:
        [float(v) for v in first]
    except ValueError:
        return None
    return {3: ScanFormat.XYZ, 4: ScanFormat.XYZI}.get(len(first))


def _read_text(path: Path, fmt: ScanFormat, *, scan_id: int, name: str | None) -> Scan:
    """XYZ (x y z), XYZI (x y z intensity) or PTS (a count line, then x y z [intensity [r g b]]), in float64."""
    import warnings

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # an empty file: the check below says it in one line
            rows = np.loadtxt(path, skiprows=1 if fmt is ScanFormat.PTS else 0, ndmin=2, dtype=np.float64,
                              comments="#")
    except ValueError as err:
        raise InputError(f"scan file {str(path)!r} is not {fmt.value.upper()} text (rows of numbers): "
                         f"{str(err).splitlines()[0]}; check the file") from None
    if rows.size == 0 or rows.shape[1] < 3:
        raise InputError(f"scan file {str(path)!r} holds no points that could be read as {fmt.value.upper()} "
                         "(rows of at least x y z); check that the file is such a point cloud")
    fields = {}
    if fmt is not ScanFormat.XYZ and rows.shape[1] >= 4 and np.any(rows[:, 3] > 0):
        fields["intensity"] = rows[:, 3]
    return Scan(xyz=rows[:, :3], scan_id=scan_id, name=name or path.stem, **fields)


def read_open3d(path: str | os.PathLike, *, format: str | ScanFormat | None = None,
                scan_id: int = 0, name: str | None = None) -> Scan:
    """Read a PLY or PCD file with Open3D, or XYZ, XYZI or PTS text, into a :class:`Scan`.

    Coordinates are taken as the scanner frame.  Attributes named
    ``reflectance_db``/``reflectance`` (dB), ``intensity``, ``return_number``,
    ``number_of_returns``, ``pulse_id`` and ``truth_material`` are kept
    (a ``scalar_`` prefix, as CloudCompare writes, is ignored).  NaN points are
    *not* dropped silently: they raise :class:`InputError`.

    Parameters
    ----------
    path : path-like
    format : str or ScanFormat, optional
        Overrides the format taken from the suffix.
    scan_id : int, default 0
    name : str, optional
        Defaults to the file stem.

    Returns
    -------
    Scan
    """
    import open3d as o3d

    path = Path(path)
    fmt = scan_format(path, format)
    if fmt in (ScanFormat.LAS, ScanFormat.LAZ, ScanFormat.PULSES):
        raise InputError(f"format={fmt.value!r}: read it with read_any")
    if not path.exists():
        raise ScanFileError(f"scan file {str(path)!r} does not exist")
    if path.stat().st_size == 0:
        raise InputError(f"scan file {str(path)!r} is empty (0 bytes); re-export the scan")
    if fmt in _TEXT_FORMATS:
        return _read_text(path, fmt, scan_id=scan_id, name=name)
    with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
        pc = o3d.t.io.read_point_cloud(str(path), format=fmt.value, remove_nan_points=False,
                                       remove_infinite_points=False)
        if "positions" not in pc.point or pc.point.positions.shape[0] == 0:
            raise InputError(
                f"scan file {str(path)!r} holds no points that Open3D could read as "
                f"{fmt.value.upper()}; check that the file is a {fmt.value.upper()} point cloud"
            )
        xyz = pc.point.positions.numpy().astype(np.float64)
    fields = {}
    for key in pc.point:
        if key == "positions":
            continue
        norm = key.lower()
        norm = norm[len("scalar_"):] if norm.startswith("scalar_") else norm
        target = _ATTRIBUTE_ALIASES.get(norm)
        if target is not None and target not in fields:
            fields[target] = pc.point[key].numpy().reshape(-1)
    if "intensity" in fields and not np.any(fields["intensity"] > 0):
        del fields["intensity"]
    return Scan(xyz=xyz, scan_id=scan_id, name=name or path.stem, **fields)


def read_any(path: str | os.PathLike, *, format: str | ScanFormat | None = None,
             require_reflectance: bool = False, min_points: int = 2,
             scan_id: int | None = None, origin=None) -> Scan:
    """Read a scan from LAS, LAZ, PLY, PCD, XYZ, XYZI, PTS or pulse-grouped text.

    Parameters
    ----------
    path : path-like
    format : str or ScanFormat, optional
        Overrides the format taken from the file suffix.
    require_reflectance : bool, default False
        Fail unless the scan carries reflectance (dB) or non-zero intensity.
    min_points : int, default 2
        Fewest points accepted (see :func:`check_scan`).
    scan_id : int, optional
        Overrides the scan id stored in the file.
    origin : (3,) float, metres, optional
        Pulse-grouped text and LAS/LAZ without a pose: the scanner's
        position in the file's coordinates (default 0, 0, 0), e.g. a
        HELIOS++ leg's scanner position.

    Returns
    -------
    Scan
        Points in the scanner frame (the file's coordinates).

    Raises
    ------
    ScanFileError
        The file does not exist.
    InputError
        Unknown format, unreadable or empty file, NaN coordinates, too few
        points, or no reflectance when ``require_reflectance``.
    """
    path = Path(path)
    fmt = scan_format(path, format)
    if origin is not None and fmt not in (ScanFormat.PULSES, ScanFormat.LAS, ScanFormat.LAZ):
        raise InputError(f"origin= is for pulse-grouped text and LAS/LAZ files; {path} is {fmt.value.upper()} (its "
                         "points are taken in the scanner's frame)")
    if fmt in (ScanFormat.LAS, ScanFormat.LAZ):
        scan = Scan.read(path, scan_id=scan_id, origin=origin)
    elif fmt is ScanFormat.PULSES:
        from tlsvox.readers.pulse_text import read_pulse_text

        scan = read_pulse_text(path, origin=(0.0, 0.0, 0.0) if origin is None else origin,
                               scan_id=0 if scan_id is None else scan_id)
        if scan_id is not None:
            scan.scan_id = scan_id
    else:
        scan = read_open3d(path, format=fmt, scan_id=0 if scan_id is None else scan_id)
    return check_scan(scan, min_points=min_points, require_reflectance=require_reflectance,
                      source=str(path))
