"""Registered scans on disk: the merged cloud with its transforms, and reading them back.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError
from tlsvox.scan import Scan, las_data
from voxlidar.safeio import json_text, staged


def write_registered(path: str | os.PathLike, scans: list[Scan], *,
                     results: list | None = None, transforms_path: str | os.PathLike | None = None,
                     labels: list | None = None) -> tuple[Path, Path]:
    """Write registered scans merged into one LAS/LAZ, and a JSON of their transforms.

    Parameters
    ----------
    path : path-like, ``.las`` or ``.laz``
        Merged cloud in the reference frame: LAS 1.4 point format 6,
        ``point_source_id`` = scan id, extra bytes ``reflectance_db``,
        ``pulse_id``, ``truth_material`` (when every scan has it).
    scans : list of Scan
        Each with ``pose`` set (see :func:`register_scans`).
    results : list of RegistrationResult or None, optional
        Their fit figures go into the JSON.
    transforms_path : path-like, optional
        Defaults to ``path`` with suffix ``.transforms.json``.
    labels : list of (N_i,) uint8, optional
        Per-scan classes (:class:`tlsvox.classify.PointClass`) written to the
        LAS ``classification`` field.

    Returns
    -------
    (las_path, json_path)

    Both files are written to temporary names and renamed only once both are
    complete.
    """
    path = Path(path)
    if path.suffix.lower() not in (".las", ".laz"):
        raise InputError(f"output {str(path)!r} must end in .las or .laz")
    if transforms_path is None:
        transforms_path = path.with_suffix(".transforms.json")
    transforms_path = Path(transforms_path)
    for s in scans:
        if s.pose is None:
            raise InputError(f"scan {s.name!r} has no pose; register the scans first")
    las = las_data(scans, np.concatenate([s.world_xyz() for s in scans]) if scans else np.zeros((0, 3)),
                   classification=labels)
    doc = {"format": "tlsvox-registration-1", "frame": "reference scanner frame" if scans else "",
           "scans": []}
    results = results if results is not None else [None] * len(scans)
    for s, r in zip(scans, results):
        entry = {"name": s.name, "scan_id": int(s.scan_id), "n_points": len(s),
                 "pose": np.asarray(s.pose).tolist()}
        if r is not None:
            entry["registration"] = r.to_dict()
        doc["scans"].append(entry)
    with staged([path, transforms_path]) as tmp:     # both or neither (Ctrl-C included)
        las.write(str(tmp[path]))
        tmp[transforms_path].write_text(json_text(doc, indent=1))
    return path, transforms_path


def read_transforms(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Scan name -> 4x4 pose from a JSON written by :func:`write_registered`."""
    doc = json.loads(Path(path).read_text())
    return {e["name"]: np.asarray(e["pose"], dtype=np.float64) for e in doc["scans"]}
