"""Footprints of three scan patterns over a flat ground, with their known geometry.

Flies the built-in presets' scan patterns (RIEGL LMS-Q680i polygon, AHAB
Chiroptera I Palmer) and an oscillating mirror (Leica-style zigzag) along one
line, prints the swath width, line spacing and Palmer radius next to their
closed forms, and draws the footprints coloured by scan angle.  The pictures
use pulse and scan rates far below the instruments', so that single
lines and footprints stay visible.

    .venv/bin/python examples/survey_footprints.py [OUT_FOLDER]   (default out/survey)
"""

import math
import sys
from pathlib import Path

import numpy as np

from clsim.survey import ScanPattern, Trajectory, plot_footprints, survey_pulses, typical_flight


def main(out="out/survey"):
    out = Path(out)
    # rates far below the instruments' (see the presets) so that single lines and footprints show
    cases = {
        "polygon": ("riegl-lms-q680i", ScanPattern.preset("riegl-lms-q680i", pulse_rate_hz=2_000.0,
                                                            scan_rate_hz=5.0)),
        "palmer": ("ahab-chiroptera-i", ScanPattern.preset("ahab-chiroptera-i", pulse_rate_hz=2_000.0,
                                                             scan_rate_hz=1.0)),
        "mirror": ("riegl-lms-q680i", ScanPattern(kind="mirror", pulse_rate_hz=2_000.0, scan_rate_hz=5.0,
                                                  fov_deg=60.0)),
    }
    for kind, (preset, pat) in cases.items():
        H, v = typical_flight(preset)
        tr = Trajectory.line((0.0, 0.0), (1.2 * H, 0.0), altitude_m=H, speed_mps=v)
        p = survey_pulses(tr, pat, seed=1)
        y = p.target[:, 1] - p.position[:, 1]
        if kind == "palmer":
            r = np.hypot(*(p.target[:, :2] - p.position[:, :2]).T)
            print(f"{kind:>8}: across-track half width {np.abs(y).max():.2f} m "
                  f"(H tan(fov/2) = {H * math.tan(math.radians(pat.fov_deg / 2)):.2f} m); "
                  f"footprint distance from nadir {r.min():.2f}..{r.max():.2f} m "
                  f"(ellipse semi-axes {H * math.tan(math.radians(pat.along_fov_deg / 2)):.2f}, "
                  f"{H * math.tan(math.radians(pat.fov_deg / 2)):.2f} m)")
        else:
            print(f"{kind:>8}: swath {np.ptp(y):.2f} m (2 H tan(fov/2) = "
                  f"{2 * H * math.tan(math.radians(pat.fov_deg / 2)):.2f} m); line spacing "
                  f"{v / pat.scan_rate_hz:.3f} m (v / scan rate)")
        title = (f"{kind}: {preset if kind != 'mirror' else 'oscillating mirror'} geometry\nH = {H:.0f} m, "
                 f"v = {v:.0f} m/s, {pat.pulse_rate_hz / 1e3:.0f} kHz, {pat.scan_rate_hz:.0f} "
                 f"{'rotations' if kind == 'palmer' else 'lines'}/s, FOV {pat.fov_deg:.0f} deg")
        print("   wrote", plot_footprints(p, out / f"survey_footprints_{kind}.png", title=title))


if __name__ == "__main__":
    main(*sys.argv[1:])
