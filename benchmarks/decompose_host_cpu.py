"""CPU of decompose_batch's host steps on NEON x40 (20,000 waveforms).

The chunks run one after another in the calling thread (no pool), so that the host
steps' CPU (``time.thread_time``) is apart from the OpenCL runtime's threads
(``time.process_time``: all). Prints the medians of ``--calls`` calls. To compare two
trees, run it in each by turns, each its own process, under the benchmark lock::

    for r in 1 2 3; do for t in BASE_TREE THIS_TREE; do
      (cd $t && PYTHONPATH=$t flock /tmp/voxlidar-bench.lock python \\
         THIS_TREE/benchmarks/decompose_host_cpu.py); done; done
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import os
import sys
import time
from pathlib import Path

import numpy as np


class _Inline:
    """A stand-in for ThreadPoolExecutor that runs every chunk in the calling thread."""

    def __init__(self, max_workers=None):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def map(self, f, it):
        return [f(x) for x in it]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=5)
    ap.add_argument("--copies", type=int, default=40, help="NEON's 500 waveforms repeated")
    default = (Path(os.environ["VOXLIDAR_SHARED_DATA"]) if os.environ.get("VOXLIDAR_SHARED_DATA")
               else Path(__file__).resolve().parents[2] / "shared" / "data")
    ap.add_argument("--data", default=str(default / "neon-harvard-waveforms" / "return.csv"),
                    help="NEON's return.csv (default: ../shared/data, or $VOXLIDAR_SHARED_DATA)")
    args = ap.parse_args(argv)
    sys.path.insert(0, os.getcwd())
    cf.ThreadPoolExecutor = _Inline
    from clsim.waveforms.decompose import decompose_batch

    rows = np.loadtxt(args.data, delimiter=",", skiprows=1)
    neon = [r[:np.flatnonzero(r)[-1] + 1] for r in rows]
    waves = neon * args.copies
    decompose_batch(neon)  # builds the kernels
    v = []
    for _ in range(args.calls):
        t0, c0, h0 = time.perf_counter(), time.process_time(), time.thread_time()
        decompose_batch(waves)
        v.append((time.perf_counter() - t0, time.process_time() - c0, time.thread_time() - h0))
    w, c, h = np.median(np.array(v), axis=0)
    print(f"{os.getcwd()}: wall {w:.3f} s  process cpu {c:.3f} s  host-thread cpu {h:.3f} s"
          f"  ({len(waves)} waveforms, load {os.getloadavg()[0]:.2f})")


if __name__ == "__main__":
    main()
