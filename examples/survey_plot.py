"""An airborne survey over a plot of 30 trees, end to end, with its four pictures.

The default plot (``clsim.scenes.make_plot(seed=0)``: 50 m x 50 m, 30 synthetic
trees of 6 models, 0.5 m voxels) is flown by the RIEGL LMS-Q680i preset along
x through the plot's middle, its field of view narrowed so the swath spans the
plot and its pulse and scan rates lowered (scan lines 2 m apart) so that
``--pulses`` pulses cover every tree.  The pulses run in batches on a local Dask cluster (``--workers 0``: a
plain loop), resumable: run the same command again after an interruption and
only the missing batches are computed.  The waveforms are written as LAS 1.4
with waveform packets and decomposed returns, then read back for the pictures:

- ``survey_plot_canopy.png``: the plot from above with the pulses' ground targets;
- ``survey_plot_footprints.png``: the footprints of the flight line;
- ``survey_plot_radargram.png``: the waveforms along the line against height;
- ``survey_plot_points.png``: the simulated point cloud.

    python examples/survey_plot.py OUT [--pulses 20000] [--photons 200] [--workers 2]

takes about a minute on 2 cores with the defaults.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

PRESET = "riegl-lms-q680i"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out", help="output folder (plot, batches, LAS, pictures)")
    ap.add_argument("--pulses", type=int, default=20_000)
    ap.add_argument("--photons", type=int, default=200, help="photons per pulse")
    ap.add_argument("--workers", type=int, default=2, help="Dask workers (0: a plain loop)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    from clsim import Sensor
    from clsim.scenes import make_plot, plot_canopy
    from clsim.survey import (
        SurveyJob,
        centre_line,
        load_survey,
        plot_footprints,
        plot_point_cloud,
        plot_radargram,
        read_survey_las,
        run_survey,
        write_survey_las,
    )

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    plot_path = out / "plot.npz"
    if not plot_path.exists():
        make_plot(seed=0, voxel_size=0.5).save(plot_path)
    from clsim.scenes import PlotScene

    plot = PlotScene.load(plot_path)
    print(f"plot: {len(plot.table())} trees, leaf area {plot.total_leaf_area():,.0f} m2")

    # the line crosses the whole plot with --pulses pulses: the pulse rate scaled down from the
    # instrument's 266 kHz (scan lines 2 m apart), so that a quick run covers every tree
    line = centre_line(plot.origin_xy, plot.origin_xy + [plot.width_m, plot.length_m], PRESET, count=args.pulses,
                       fill=True, line_spacing_m=2.0)
    (H, v), fov, rate = line.flight, line.fov_deg, line.pattern.pulse_rate_hz
    sensor = Sensor.preset(PRESET)
    job = SurveyJob(scene_path=str(plot_path), trajectory=line.trajectory, pattern=line.pattern, sensor=sensor,
                    photons=args.photons, first=line.first, count=args.pulses, batch_size=1000, seed=args.seed)
    run = run_survey(job, out / "survey", workers=args.workers, direct=args.workers == 0)
    print(f"survey: {run.pulses:,} pulses, {run.computed} batches computed, {run.skipped} already on disk")

    wf = load_survey(out / "survey")
    pulses = job.pulses()
    las, wdp = write_survey_las(out / "survey.las", pulses, wf.waveform, t0_ns=wf.t0_ns, bin_ns=wf.bin_ns,
                                sensor=sensor)
    survey = read_survey_las(las)
    n_ret = int(np.count_nonzero(~survey.withheld))
    print(f"LAS: {las} ({n_ret:,} returns) and {wdp.name}")

    caption = (f"{PRESET} at {H:.0f} m, {v:.0f} m/s, field of view {fov:.1f} deg, {rate / 1e3:.0f} kHz, "
               f"{v / 2:.0f} lines/s; {args.photons} photons per pulse, seed {args.seed}")
    plot_canopy(plot, out / "survey_plot_canopy.png", footprints=pulses.target[:, :2],
                title=f"plot of {len(plot.table())} trees and the {len(pulses):,} pulses' ground targets")
    plot_footprints(pulses, out / "survey_plot_footprints.png",
                    title=f"footprints of the flight line ({len(pulses):,} pulses, polygon scanner, lines 2 m apart)")
    plot_radargram(survey, out / "survey_plot_radargram.png", caption=caption,
                   title="simulated waveforms along the flight line (pulses nearest nadir)")
    plot_point_cloud(survey, out / "survey_plot_points.png", caption=caption,
                     title="simulated point cloud (decomposed returns)")
    print(f"pictures in {out}; {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
