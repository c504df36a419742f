"""Reading scans: every file format a scan comes in, by suffix and by content, to a :class:`~tlsvox.scan.Scan`.

:func:`read_any` is the one entry point (``tlsvox voxelize``, ``register``
and ``classify`` read through it). It picks the reader from the file's
suffix and, for text, from its first lines (:func:`scan_format`):

==================  ================================================  ==============================
module              files                                             reader
==================  ================================================  ==============================
:mod:`.las`         LAS/LAZ with the ``.pulses.npz`` and              :func:`read_las` (also
                    ``.pose.json`` sidecars                           :meth:`Scan.read`)
:mod:`.formats`     PLY, PCD, XYZ, XYZI, PTS (Open3D's tensor I/O)     :func:`read_open3d`
:mod:`.pulse_text`  pulse-grouped multi-return text (``x y z time     :func:`read_pulse_text`
                    return_index return_count`` with miss rows)
==================  ================================================  ==============================

Every reader ends in :func:`check_scan`: one clear error for a scan that no
later step could use (no points, one point, NaN coordinates, no reflectance
or intensity where one is needed). The modules import :mod:`tlsvox.scan`;
:mod:`tlsvox.scan` imports none of them at import time (no circle).
"""

from tlsvox.readers.formats import ScanFormat, check_scan, read_any, read_open3d, scan_format
from tlsvox.readers.las import read_las, read_pose_sidecar
from tlsvox.readers.pulse_text import looks_pulse_grouped, pulse_ids_from_time, read_pulse_text

__all__ = ["ScanFormat", "check_scan", "looks_pulse_grouped", "pulse_ids_from_time", "read_any", "read_las",
           "read_open3d", "read_pose_sidecar", "read_pulse_text", "scan_format"]
