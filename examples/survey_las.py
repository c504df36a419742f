"""A flight line over a plot of analytic trees, written as LAS 1.4 with waveforms.

No Monte Carlo here (one simulated pulse takes about a second): each pulse's
waveform is a sum of Gaussian echoes, the sensor's pulse width, at the ranges
where its beam axis meets the crown tops (spheroids, seeded positions and
sizes) and the ground (z = 0), plus seeded noise.  The pulses are written
with :func:`clsim.survey.write_survey_las` (waveform packets in a ``.wdp``,
returns from the batched decomposition as the points), read back with
:func:`clsim.survey.read_survey_las`, and drawn as a radargram and a point
cloud.  It prints how far the read-back waveforms, returns and sample
positions lie from what went in.

    .venv/bin/python examples/survey_las.py [OUT_FOLDER] [--pictures IMG_FOLDER]

(default out/survey_las; pictures beside the LAS unless --pictures).
"""

import sys
from pathlib import Path

import numpy as np

from clsim import Sensor
from clsim.sensor import C_M_PER_NS
from clsim.survey import (
    ScanPattern,
    Trajectory,
    plot_point_cloud,
    plot_radargram,
    read_survey_las,
    survey_pulses,
    write_survey_las,
)


def forest(seed=3, n=25, size=80.0):
    """Crown spheroids: centre (x, y), crown radius, crown top height, crown depth."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-size / 2, size / 2, (n, 2))
    xy[: n // 3, 1] *= 0.1                                   # a third of them near the track
    radius = rng.uniform(2.0, 5.0, n)
    top = rng.uniform(12.0, 25.0, n)
    return xy, radius, top, 0.8 * top


def crown_hit(pulses, trees):
    """Range of the first crown surface along each beam axis (inf where none)."""
    xy, rad, top, depth = trees
    best = np.full(len(pulses), np.inf)
    for (cx, cy), a, zt, dd in zip(xy, rad, top, depth):
        c = np.array([cx, cy, zt - dd / 2])
        scale = np.array([a, a, dd / 2])                  # spheroid -> unit sphere
        o = (pulses.position - c) / scale
        d = pulses.direction / scale
        qa, qb, qc = (d * d).sum(1), 2 * (o * d).sum(1), (o * o).sum(1) - 1.0
        disc = qb * qb - 4 * qa * qc
        r = np.where(disc >= 0, (-qb - np.sqrt(np.maximum(disc, 0))) / (2 * qa), np.inf)
        best = np.minimum(best, np.where(r > 0, r, np.inf))
    return best


def main(out="out/survey_las", pictures=None, length_m=90.0):
    out = Path(out)
    pictures = Path(pictures) if pictures else out
    sensor = Sensor.preset("riegl-lms-q680i")
    # rates below the instrument's so that the picture shows single scan lines
    pat = ScanPattern(kind="polygon", pulse_rate_hz=20_000.0, scan_rate_hz=50.0, fov_deg=30.0)
    tr = Trajectory.line((-length_m / 2, 0.0), (length_m / 2, 0.0), altitude_m=200.0, speed_mps=50.0)
    pulses = survey_pulses(tr, pat, sensor, seed=1)
    bin_ns, n_bins, sig = 1.0, 300, sensor.pulse_sigma_ns
    t0 = 2.0 * (pulses.range_m - 40.0) / C_M_PER_NS        # records start 40 m before the ground
    t = t0[:, None] + bin_ns * np.arange(n_bins)
    r_crown = crown_hit(pulses, forest())
    hit = np.isfinite(r_crown)
    t_crown = np.where(hit, 2.0 * r_crown / C_M_PER_NS, 0.0)
    t_ground = 2.0 * pulses.range_m / C_M_PER_NS
    a_ground = np.where(hit, 0.35, 1.0) * 1e-6                # energy fraction / ns
    w = (a_ground[:, None] * np.exp(-0.5 * ((t - t_ground[:, None]) / sig) ** 2)
         + np.where(hit, 0.6e-6, 0.0)[:, None] * np.exp(-0.5 * ((t - t_crown[:, None]) / sig) ** 2))
    w += np.random.default_rng(7).normal(0.0, 5e-9, w.shape)  # seeded noise
    las, wdp = write_survey_las(out / "line.las", pulses, w, t0_ns=t0, bin_ns=bin_ns, sensor=sensor)
    s = read_survey_las(las)
    print(f"{len(pulses):,} pulses, {n_bins} bins -> {las} ({las.stat().st_size / 1e6:.1f} MB), "
          f"{wdp.name} ({wdp.stat().st_size / 1e6:.1f} MB)")
    print(f"waveforms read back: max |error| {np.abs(s.waveforms - w).max():.3g} "
          f"(quantisation step {s.gain:.3g}, 16 bits)")
    origin = pulses.position + (0.5 * C_M_PER_NS * t0)[:, None] * pulses.direction
    print(f"first-sample positions: max |error| {np.abs(s.origin - origin).max() * 1e3:.2f} mm")
    ret = s.returns
    hw = s.withheld.sum()
    print(f"{ret.sum():,} returns, {np.bincount(s.number_of_returns[ret])[1:].tolist()} points in "
          f"pulses of 1, 2, ... returns, {hw} pulses without a return")
    last = ret & (s.return_number == s.number_of_returns)
    print(f"last returns on the ground: median |z| {np.median(np.abs(s.xyz[last, 2])) * 1e3:.1f} mm")
    plot_radargram(s, pictures / "survey_radargram.png")
    plot_point_cloud(s, pictures / "survey_point_cloud.png")
    return s


if __name__ == "__main__":
    args = sys.argv[1:]
    pics = None
    if "--pictures" in args:
        k = args.index("--pictures")
        pics = args[k + 1]
        del args[k:k + 2]
    main(*(args[:1] or ["out/survey_las"]), pictures=pics)
