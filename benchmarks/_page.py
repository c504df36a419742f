"""Writing the benchmark pages: each script's section of docs/bench/<topic>.md.

    from _page import write_page, write_section     # benchmarks/ is the script's folder
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["write_page", "write_section"]


def write_page(out, lines, *, echo: bool = False) -> Path:
    """Write ``lines`` (one string a line) to ``out``, atomically; print them when
    ``echo``, then the file's name."""
    from voxlidar.safeio import atomic_write

    out = Path(out)
    text = "\n".join(lines).rstrip("\n") + "\n"
    atomic_write(out, lambda tmp: Path(tmp).write_text(text))
    if echo:
        print(text)
    print(f"wrote {out}")
    return out


def write_section(path, title: str, body: str) -> Path:
    """Replace (or append) the ``## title`` section of a markdown page, atomically."""
    from voxlidar.safeio import atomic_write

    path = Path(path)
    text = path.read_text() if path.exists() else "# Voxelisation benchmarks\n\nWritten by benchmarks/bench_*.py.\n"
    head = f"## {title}\n"
    if head in text:
        start = text.index(head)
        nxt = text.find("\n## ", start + len(head))
        text = text[:start] + text[nxt + 1:] if nxt >= 0 else text[:start]
    text = text.rstrip() + "\n\n" + head + body.rstrip() + "\n"
    return atomic_write(path, lambda tmp: Path(tmp).write_text(text))
