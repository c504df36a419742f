"""Never lose an input: check a command's outputs before it writes anything.

Every command that writes files calls :func:`check_outputs` first, with its
inputs (and the sidecar files it reads beside them) and its outputs (and the
sidecars it will write).  An output that resolves, through symbolic links,
hard links and ``..``, to an input or to another output of the same command
is refused in one line that names both and the fix; so is an output in a
folder that cannot be written.  Nothing has been written at that point.

Examples
--------
>>> import tempfile, pathlib
>>> d = pathlib.Path(tempfile.mkdtemp())
>>> (d / "scene.npz").write_bytes(b"x")
1
>>> check_outputs([("scene", d / "scene.npz")], [("-o", d / "wf.npz")])
>>> try:
...     check_outputs([("scene", d / "scene.npz")], [("-o", d / "sub" / ".." / "scene.npz")])
... except OutputConflictError as err:
...     print("is the same file as the input scene" in str(err), "nothing was written" in str(err))
True True
"""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

from voxlidar.errors import InputError, VoxlidarError

__all__ = ["FIGURE_FORMATS", "FigurePathError", "OutputConflictError", "atomic_write", "check_figure_path",
           "check_distinct", "check_inputs", "check_outputs", "describe_kind", "file_kind", "finish_figure",
           "json_text", "open_npz", "save_figure", "staged", "write_npz"]


class OutputConflictError(VoxlidarError, ValueError):
    """An output would overwrite an input or another output, or cannot be written."""


def _key(path: Path) -> tuple:
    """Identity of a path: (device, inode) when it exists, else its resolved text."""
    real = Path(os.path.realpath(path))
    try:
        st = real.stat()
        return ("inode", st.st_dev, st.st_ino)
    except OSError:
        return ("path", str(real))


#: magic bytes of the file kinds voxlidar reads, and what each is
MAGIC = ((b"LASF", "las", "a LAS/LAZ file"), (b"PK\x03\x04", "npz", "a NumPy NPZ (zip) file"),
         (b"VOXEL SPACE", "vox", "an AMAPVox .vox file"), (b"ply", "ply", "a PLY file"),
         (b"PulseWavesPulse", "pls", "a PulseWaves .pls file"), (b"\x93NUMPY", "npy", "a NumPy .npy file"),
         (b"# .PCD", "pcd", "a PCD point cloud"), (b"VERSION ", "pcd", "a PCD point cloud"))


def file_kind(path) -> str:
    """What a file is by its first bytes, not its name: ``las``, ``npz``, ``vox``, ``ply``,
    ``pls``, ``npy``, ``pcd``, ``empty``, ``text`` or ``unknown``.

    >>> import tempfile
    >>> p = Path(tempfile.mkdtemp()) / "scan.txt"
    >>> _ = p.write_bytes(b"LASF" + bytes(400))
    >>> file_kind(p)
    'las'
    """
    with open(path, "rb") as fh:
        head = fh.read(64)
    if not head:
        return "empty"
    for magic, kind, _ in MAGIC:
        if head.startswith(magic):
            return kind
    try:
        head.decode("utf-8")
    except UnicodeDecodeError:
        return "unknown"
    return "text"


def describe_kind(kind: str) -> str:
    """Words for a :func:`file_kind` result, for error messages."""
    names = {k: words for _, k, words in MAGIC}
    return names.get(kind, {"empty": "empty (0 bytes)", "text": "a text file",
                            "unknown": "of an unknown kind"}.get(kind, kind))


def check_inputs(inputs) -> None:
    """Refuse optional input files that are missing or are folders: one line that names the option.

    Parameters
    ----------
    inputs : iterable of (label, path)
        ``None`` paths (options not given) are skipped.
    """
    for label, path in inputs:
        if path is None:
            continue
        path = Path(path)
        if not path.exists():
            raise InputError(f"{label} {path} does not exist; check the path")
        if path.is_dir():
            raise InputError(f"{label} {path} is a folder; give a file")


def check_distinct(label: str, paths) -> None:
    """Refuse one file given twice (symlinks and ``..`` resolved): a slip of the shell, not two inputs."""
    seen = {}
    for p in paths:
        key = _key(Path(p))
        if key in seen:
            raise InputError(f"{p} is given twice (also as {seen[key]}); give each {label} once")
        seen[key] = p


def check_outputs(inputs, outputs) -> None:
    """Refuse outputs that would replace an input, or each other, or cannot be written.

    Parameters
    ----------
    inputs : iterable of (label, path)
        What the command reads, sidecars included; a sidecar that does not
        exist is still protected (an output of that name would shadow it).
    outputs : iterable of (label, path)
        What it will write, sidecars included; ``None`` paths are skipped.

    Raises
    ------
    OutputConflictError
        One line naming the output, what it collides with, and the fix.
    """
    seen_in = {}
    for label, path in inputs:
        if path is not None:
            seen_in.setdefault(_key(Path(path)), (label, path))
    seen_out = {}
    for label, path in outputs:
        if path is None:
            continue
        path = Path(path)
        key = _key(path)
        if key in seen_in:
            in_label, in_path = seen_in[key]
            raise OutputConflictError(
                f"{label} {path} is the same file as the input {in_label} {in_path}; "
                "nothing was written: choose another output name")
        if key in seen_out:
            other_label, other = seen_out[key]
            raise OutputConflictError(
                f"{label} {path} is the same file as {other_label} {other}; "
                "nothing was written: give each output its own name")
        seen_out[key] = (label, path)
        folder = Path(os.path.realpath(path)).parent
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
        if not folder.is_dir():
            raise OutputConflictError(
                f"{label} {path}: {folder} is a file, not a folder; nothing was written: "
                "choose an output in a folder")
        if not os.access(folder, os.W_OK | os.X_OK):
            raise OutputConflictError(
                f"{label} {path}: the folder {folder} cannot be written (permission denied); "
                "nothing was written: choose a writable folder")
        if path.is_dir():
            raise OutputConflictError(f"{label} {path} is a folder; nothing was written: give a file name")


def _plain(obj):
    """``obj`` with NumPy values made Python ones and non-finite floats made None."""
    import math

    if isinstance(obj, dict):
        return {str(k): _plain(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_plain(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, (str, bytes)):  # NumPy arrays and scalars
        return _plain(obj.tolist())
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def json_text(obj, *, indent=None) -> str:
    """Standard JSON (RFC 8259) for ``obj``: NaN and infinities become ``null``
    (Python's ``json`` would write ``NaN``/``Infinity``, which other readers
    reject), NumPy values plain numbers.

    >>> json_text({"fitness": float("nan"), "range": float("inf"), "n": 3})
    '{"fitness": null, "range": null, "n": 3}'
    """
    import json

    return json.dumps(_plain(obj), indent=indent, allow_nan=False)


FIGURE_FORMATS = ("png", "pdf", "svg", "jpg", "jpeg")


class FigurePathError(VoxlidarError, ValueError):
    """A picture's file name ends in a format that cannot be written."""


def check_figure_path(label: str, path, formats=FIGURE_FORMATS) -> None:
    """Refuse, before any work, a picture name whose suffix is not one of ``formats``."""
    if path is None:
        return
    fmt = Path(path).suffix.lower().lstrip(".")
    if fmt not in formats:
        raise FigurePathError(f"{label} {path}: unknown picture format {Path(path).suffix!r}; nothing was "
                              f"written: end the name in one of {', '.join('.' + f for f in formats)}")


def save_figure(fig, path, *, dpi: int = 110) -> Path:
    """Write a Matplotlib figure in the format its file name says (png, pdf, svg,
    jpg), atomically: a temporary file renamed when complete.  Another suffix is
    one clear error, not a PNG under a misleading name."""
    path = Path(path)
    check_figure_path("picture", path)
    fmt = path.suffix.lower().lstrip(".")
    return atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, format="jpeg" if fmt == "jpg" else fmt))


def finish_figure(fig, path, *, caption: str | None = None, dpi: int = 110) -> Path:
    """Lay out a Matplotlib figure (tight), write it (:func:`save_figure`: format by
    suffix, atomically) and close it; ``caption`` goes in small grey type under the axes."""
    import matplotlib.pyplot as plt

    if caption:
        lines = caption.count("\n") + 1
        fig.tight_layout(rect=(0, 0.035 * lines, 1, 1))
        fig.text(0.01, 0.01, caption, fontsize=6.5, ha="left", va="bottom", color="0.25")
    else:
        fig.tight_layout()
    try:
        return save_figure(fig, path, dpi=dpi)
    finally:
        plt.close(fig)


def atomic_write(path: str | os.PathLike, write) -> Path:
    """Call ``write(tmp_path)`` then rename the temporary file onto ``path``.

    A crash half-way leaves the destination untouched (never a half file).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def write_npz(path: str | os.PathLike, arrays: dict) -> Path:
    """Write ``arrays`` (name -> array) as one compressed NPZ, atomically (:func:`atomic_write`).

    >>> import tempfile, numpy as np
    >>> p = write_npz(Path(tempfile.mkdtemp()) / "a.npz", {"x": np.arange(3)})
    >>> with open_npz(p, "test") as z:
    ...     z["x"].tolist()
    [0, 1, 2]
    """
    import numpy as np

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    return atomic_write(path, write)


def open_npz(path: str | os.PathLike, what: str):
    """``np.load(path)`` of an NPZ (no pickles), or one :class:`InputError` naming
    the file as not a readable NPZ ``what`` file (``what``: "scene", "plot", ...)."""
    import numpy as np

    try:
        return np.load(path, allow_pickle=False)
    except Exception as err:  # noqa: BLE001 - re-raised with the file named
        raise InputError(f"{str(path)!r} is not a readable NPZ {what} file: {err}") from err


@contextlib.contextmanager
def staged(paths):
    """Write several outputs all or none: yields ``{path: temporary path}``.

    The caller writes each output to its temporary path (same folder, same
    suffix, so format-by-suffix writers still work).  When the block ends
    without error every temporary file is renamed onto its output; on an
    error or Ctrl-C they are all removed and no output appears.  ``None``
    paths are skipped (map to ``None``).

    >>> import tempfile
    >>> d = Path(tempfile.mkdtemp())
    >>> with staged([d / "a.txt", d / "b.txt", None]) as tmp:
    ...     _ = tmp[d / "a.txt"].write_text("a")
    ...     _ = tmp[d / "b.txt"].write_text("b")
    >>> sorted(p.name for p in d.iterdir())
    ['a.txt', 'b.txt']
    """
    tmp = {}
    for p in paths:
        if p is None:
            continue
        p = Path(p)
        p.parent.mkdir(parents=True, exist_ok=True)
        tmp[p] = p.with_name(f".{p.stem}.staged-{os.getpid()}{p.suffix}")
    view = {**tmp, None: None}
    view.update({str(k): v for k, v in tmp.items()})
    try:
        yield view
        for final, t in tmp.items():
            if not t.exists():
                raise VoxlidarError(f"internal: {final} was not written")
        for final, t in tmp.items():
            os.replace(t, final)
    finally:
        for t in tmp.values():
            if t.exists():
                t.unlink()
