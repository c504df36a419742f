"""What the benchmark scripts share: medians of timed runs, the machine and load
line of a page, and writing each script's page (docs/bench/<topic>.md).

    from _bench import machine_line, median_time, write_page   # benchmarks/ is the script's folder
"""

from __future__ import annotations

import os
import platform
import statistics
import time
from pathlib import Path

__all__ = ["machine_line", "median_time", "with_leaves", "write_page", "write_section"]


def with_leaves(tree, centers, normals, rng):
    """``tree`` with its leaves rebuilt at ``centers`` facing ``normals`` (same count, size and total
    area; bark, targets and ground kept): the benchmarks' variants of the synthetic oak."""
    import numpy as np

    from tlsvox.truth._mesh import leaf_mesh, polygon_area_factor
    from tlsvox.truth.synthetic import SyntheticTree
    from voxlidar.materials import Material

    p = tree.params
    scale = np.sqrt(p.total_leaf_area / (len(centers) * polygon_area_factor() * 0.25 * p.leaf_length * p.leaf_width))
    lv, lt = leaf_mesh(centers, normals, p.leaf_length * scale, p.leaf_width * scale, rng)
    keep = tree.material != Material.LEAF
    tris = tree.triangles[keep]
    used = np.unique(tris)
    remap = np.full(len(tree.vertices), -1)
    remap[used] = np.arange(len(used))
    return SyntheticTree(vertices=np.concatenate([tree.vertices[used], lv]),
                         triangles=np.concatenate([remap[tris], lt + len(used)]).astype(np.int64),
                         material=np.concatenate([tree.material[keep], np.full(len(lt), Material.LEAF, np.uint8)]),
                         leaf_normals=normals, leaf_centers=centers, cylinders=tree.cylinders, targets=tree.targets,
                         ground_z=tree.ground_z, crown_center=tree.crown_center, params=p, seed=tree.seed)


def median_time(fn, repeats: int):
    """Call ``fn()`` ``repeats`` times: (median seconds, the last result)."""
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def machine_line(load_before, load_after=None) -> str:
    """``Machine: ..., N CPU(s) shared with other work, Python ...; load average ... before: ...; after: ...``."""
    text = (f"Machine: {platform.machine()}, {os.cpu_count()} CPU(s) shared with other work, Python "
            f"{platform.python_version()}. Load average (1, 5, 15 min) before: "
            f"{', '.join(f'{v:.2f}' for v in load_before)}")
    if load_after is not None:
        text += f"; after: {', '.join(f'{v:.2f}' for v in load_after)}"
    return text + "."


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
