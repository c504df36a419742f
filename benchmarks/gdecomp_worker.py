"""Run gdecomp (PyPI 1.0.6) on waveforms; launched by bench_decompose.py in gdecomp's own
virtual environment (it needs only NumPy and gdecomp, not this project).

    python gdecomp_worker.py DATA.npz scan START     # one JSON line per waveform from START
    python gdecomp_worker.py DATA.npz time REPEATS   # times the waveforms not in `skip`

DATA.npz holds ``flat`` (all baseline-free samples), ``offsets`` (N + 1), ``thr`` (N,)
and ``skip`` (indices not to run). In scan mode a line is written before and after each
waveform (flushed), so the parent sees which waveform hangs or crashes.
"""

from __future__ import annotations

import json
import sys
import time

import gdecomp
import numpy as np


def main() -> int:
    data = np.load(sys.argv[1])
    flat, off, thr = data["flat"], data["offsets"], data["thr"]
    skip = set(data["skip"].tolist())
    n = off.size - 1
    waves = [np.ascontiguousarray(flat[off[i]:off[i + 1]]) for i in range(n)]
    if sys.argv[2] == "scan":
        for i in range(int(sys.argv[3]), n):
            if i in skip:
                continue
            sys.stdout.write(json.dumps({"start": i}) + "\n")
            sys.stdout.flush()
            p = gdecomp.GaussianDecomposition(waves[i], float(thr[i]))
            sys.stdout.write(json.dumps({"i": i, "p": [float(v) for v in p]}) + "\n")
            sys.stdout.flush()
        return 0
    todo = [i for i in range(n) if i not in skip]
    times = []
    for _ in range(int(sys.argv[3])):
        t0 = time.perf_counter()
        for i in todo:
            gdecomp.GaussianDecomposition(waves[i], float(thr[i]))
        times.append(time.perf_counter() - t0)
    sys.stdout.write(json.dumps({"n": len(todo), "times": times}) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
