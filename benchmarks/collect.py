"""Assemble docs/benchmarks.md from the sections the benchmark scripts write.

Each script in benchmarks/ writes its own section to docs/bench/<topic>.md;
this script joins them (in a fixed order, then any others) under one page, with
their links up a folder ("../img/...") made relative to docs/.

    .venv/bin/python benchmarks/collect.py
"""

from __future__ import annotations

import os
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ORDER = ["scanner", "register_classify", "voxelize", "memory", "echo_weights", "lad_terms", "leaf_angles", "clsim", "mitransient", "plot", "devices", "walk_profile", "kernel_ab", "decompose", "decompose_loop", "decompose_returns", "replay_neon", "replay_leica", "replay_oak", "pipeline", "waveform_terms", "qsm", "survey", "first_order", "helios", "million"]

HEADER = """# Benchmarks

Speed and accuracy figures, each with the command that produced it.  Ratios are
measured side by side in one run; times are medians of several runs.  Unless a
section says otherwise the machine is the project's standard one: 2 CPU cores,
24 GB, no GPU; OpenCL on the best working CPU runtime (docs/devices.md).  Re-run everything with
`make bench`, then `.venv/bin/python benchmarks/collect.py`.

"""


def main() -> int:
    parts = sorted((ROOT / "docs" / "bench").glob("*.md"))
    by_name = {p.stem: p for p in parts}
    names = []
    for n in ORDER:  # "devices" also takes its per-machine pages, devices-<machine>.md
        names += [m for m in sorted(by_name) if m == n or m.startswith(n + "-")]
    names += sorted(n for n in by_name if n not in names)
    # the pages live in docs/bench/ and link up ("../img/x.png", "../devices.md"); this page is in docs/
    text = HEADER + "\n".join(by_name[n].read_text().rstrip().replace("](../", "](") + "\n" for n in names)
    out = ROOT / "docs" / "benchmarks.md"
    tmp = out.with_suffix(".tmp")
    tmp.write_text(text)
    os.replace(tmp, out)
    print(f"wrote {out} from {len(names)} sections: {', '.join(names)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
