"""LAS/LAZ scans with their sidecar files (pulse table, pose): the reader behind :meth:`Scan.read`."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError, ScanFileError
from tlsvox.scan import CLASSIFY_MARK, PulseTable, Scan, sidecar_paths
from voxlidar.safeio import describe_kind, file_kind

__all__ = ["read_las", "read_pose_sidecar"]


def read_las(path: str | os.PathLike, *, scan_id: int | None = None, cls=Scan, origin=None) -> Scan:
    """Read a LAS/LAZ scan and its sidecar files (when present).

    Reflectance comes from the ``reflectance_db`` extra dimension (tlsvox
    and RIEGL exports; RIEGL's ``Reflectance`` is accepted too); without
    one, ``intensity`` is kept when the file has non-zero intensities.
    Echoes belong to pulses by the ``pulse_id`` extra dimension; without
    one, by GPS time when the times group them (each time's echoes agree
    on their return count and have distinct return numbers:
    ``meta["pulse_grouping"] = "gps_time"``), else they are grouped
    later by ray (:func:`tlsvox.voxel.pulses.group_pulses`). ``cls``: the
    class made (:class:`~tlsvox.scan.Scan` or a subclass).

    HELIOS++'s LAS output (extra bytes ``fullwaveIndex``, ``hitObjectId``,
    ``echo_width``, ``heliosAmplitude``) has its pulses by ``fullwaveIndex``
    and no row for a pulse that hit nothing; its coordinates are the
    world's.  ``origin`` (3,), the scanner's position in the file's
    coordinates (CLI ``--scan-origin``), puts the echoes in the scanner's
    frame, translated by it (the scan's pose, unless a sidecar gives one).
    """
    import laspy

    path = Path(path)
    if not path.exists():
        raise ScanFileError(f"scan file {str(path)!r} does not exist")
    if path.stat().st_size == 0:
        raise InputError(f"scan file {str(path)!r} is empty (0 bytes); re-export the scan")
    kind = file_kind(path)
    if kind != "las":
        raise InputError(f"{str(path)!r} is not a LAS/LAZ file: it is {describe_kind(kind)} (a LAS file starts "
                         "with 'LASF')")
    try:
        las = laspy.read(str(path))
    except Exception as err:  # noqa: BLE001 - re-raised with the file named
        raise InputError(f"{str(path)!r} is not a readable LAS/LAZ file: {err}") from err
    xyz = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])
    dims = {d.lower(): d for d in las.point_format.dimension_names}
    refl = None
    for key in ("reflectance_db", "reflectance"):
        if key in dims:
            refl = np.asarray(las[dims[key]], dtype=np.float32)
            break
    intensity = None
    if "intensity" in dims:
        inten = np.asarray(las.intensity)
        if inten.size and inten.max() > 0:
            intensity = inten
    pulse_id = np.asarray(las["pulse_id"], dtype=np.int64) if "pulse_id" in dims else None
    truth = np.asarray(las["truth_material"]) if "truth_material" in dims else None
    codes = np.asarray(las.classification) if "classification" in dims else None
    fraction = np.asarray(las["beam_fraction"], dtype=np.float32) if "beam_fraction" in dims else None
    pulses_path, pose_path = sidecar_paths(path)
    pulses = PulseTable.load(pulses_path) if pulses_path.exists() else None
    doc = read_pose_sidecar(path)
    pose, pose_true = doc.get("pose"), doc.get("pose_true")
    name, meta = doc.get("name", path.stem), dict(doc.get("meta") or {})
    if pose_path.exists():
        sid = int(doc.get("scan_id", 0))
    else:
        sid = int(np.asarray(las.point_source_id)[0]) if len(las.points) else 0
    if origin is not None:
        if pose is not None:
            raise InputError(f"a scan origin (--scan-origin, origin=) was given for {str(path)!r}, which has a pose "
                             f"({pose_path.name}): its echoes are in its scanner's frame already; drop the origin")
        o = np.asarray(origin, dtype=np.float64).reshape(-1)
        if o.shape != (3,) or not np.all(np.isfinite(o)):
            raise InputError(f"origin={origin!r} must be the scanner's x, y, z in the file's coordinates (3 numbers)")
        xyz = xyz - o
        if pose is None:
            pose = np.eye(4)
            pose[:3, 3] = o
    if pulse_id is None and "fullwaveindex" in dims:  # HELIOS++: one full-waveform index per pulse
        _, pulse_id = np.unique(np.asarray(las[dims["fullwaveindex"]], dtype=np.int64), return_inverse=True)
        meta.update(pulse_grouping="fullwave_index", layout="HELIOS++ LAS output",
                    empty_pulses="none recorded (HELIOS++ writes no point for a pulse that hit nothing): rebuilt "
                                 "from the angular grid (--angular-grid)")
        if "hitobjectid" in dims:
            meta["hit_object_ids"] = sorted(int(v) for v in np.unique(np.asarray(las[dims["hitobjectid"]])))
    if pulse_id is None and "gps_time" in dims and len(las.points):
        # pulses grouped by GPS time (other tools' multi-return exports); not when the times do not group
        from tlsvox.readers.pulse_text import pulse_ids_from_time

        try:
            pulse_id = pulse_ids_from_time(las.gps_time, las.return_number, las.number_of_returns)
            meta["pulse_grouping"] = "gps_time"
        except InputError:
            pulse_id = None
    return cls(
        xyz=xyz,
        reflectance_db=refl,
        intensity=intensity,
        return_number=np.asarray(las.return_number),
        number_of_returns=np.asarray(las.number_of_returns),
        pulse_id=pulse_id,
        truth_material=truth,
        # only codes tlsvox classify wrote (PointClass); other tools' codes mean other things
        classification=codes if meta.get("classes") == CLASSIFY_MARK else None,
        beam_fraction=fraction,
        pose=pose,
        pose_true=pose_true,
        pulses=pulses,
        scan_id=sid if scan_id is None else scan_id,
        name=name,
        meta=meta,
    )


def read_pose_sidecar(path: str | os.PathLike) -> dict:
    """The ``NAME.pose.json`` beside a scan file as a dict (empty when there is none)."""
    pose_path = sidecar_paths(path)[1]
    if not pose_path.exists():
        return {}
    try:
        return json.loads(pose_path.read_text())
    except (ValueError, OSError) as err:
        raise InputError(f"{pose_path} is not a readable pose JSON ({err}); fix or remove it") from None
