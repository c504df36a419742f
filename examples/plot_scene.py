"""A 50 m x 50 m plot of 30 synthetic trees (6 distinct trees, 5 of each), with
their known leaf area, the memory shared bricks save, and one pulse over it.

Prints the plot's leaf area next to the sum of its trees' (the known answer),
the brick pool shared against copied, and the waveform of one pulse from the
shared plot and from the copied scene (same seed: identical); draws the
canopy seen from above.  With a scene file (``tlsvox voxelize`` output at
0.5 m voxels) it stands that scanned tree in the middle of the plot too.

    .venv/bin/python examples/plot_scene.py [OUT_FOLDER] [SCANNED_TREE.npz]   (default out/plot)
"""

import math
import sys
from pathlib import Path

import numpy as np

from clsim import Sensor, Simulator
from clsim.scenes import make_plot, plot_canopy


def main(out="out/plot", scanned=None):
    out = Path(out)
    plot = make_plot(50.0, 30, seed=0, voxel_size=0.5)
    if scanned:
        plot.add_tree(scanned, 25.0, 25.0, snap="brick")
    tab = plot.table()
    known = math.fsum(tab["leaf_area_m2"])
    print(f"{plot}")
    print(f"leaf area: plot {plot.total_leaf_area():.6f} m2, sum of its {len(tab)} trees {known:.6f} m2, "
          f"copied scene {plot.to_scene().total_leaf_area():.6f} m2")
    mem = plot.memory()
    print(f"brick pool: shared {mem['pool_bytes'] / 2**20:.2f} MiB ({mem['bricks']} bricks, "
          f"{mem['merged_bricks']} merged where crowns meet), copied {mem['copied_pool_bytes'] / 2**20:.2f} MiB "
          f"({mem['occupied_cells']} bricks): {mem['copied_pool_bytes'] / mem['pool_bytes']:.2f} x")
    i = int(np.argmax(tab["height_m"]))
    target = (float(tab["x_m"][i]), float(tab["y_m"][i]))
    sim, sensor = Simulator(), Sensor.preset("ahab-chiroptera-i")
    a = sim.run(plot, sensor, photons=50_000, seed=3, target=target)
    b = sim.run(plot.to_scene(), sensor, photons=50_000, seed=3, target=target)
    e, se = a.energy(kind="vegetation")
    print(f"one pulse on {tab['name'][i]} ({tab['height_m'][i]:.1f} m) at {target}: vegetation energy "
          f"{e:.4g} +- {se:.2g}; shared and copied waveforms identical: "
          f"{bool(np.array_equal(a.fine_batches, b.fine_batches))}")
    print("wrote", plot_canopy(plot, out / "plot_canopy.png", footprints=[target]))


if __name__ == "__main__":
    main(*sys.argv[1:])
