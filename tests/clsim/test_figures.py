"""clsim.figures: pictures carry titles, axis labels with units and legends; the format follows the suffix."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.figures import plot_waveforms
from clsim.sensor import C_M_PER_NS


def _curves():
    t = np.arange(2380.0, 2420.0, 0.25)
    return [("mesh", t, np.exp(-0.5 * ((t - 2395.0) / 2.0) ** 2)),
            ("voxels", t, 0.8 * np.exp(-0.5 * ((t - 2396.0) / 2.0) ** 2))]


def test_waveform_picture_has_title_units_and_legend(tmp_path):
    out = plot_waveforms(_curves(), tmp_path / "wf.svg", ground_time_ns=2400.0, title="leaf-on, nadir")
    svg = out.read_text()
    for text in ("leaf-on, nadir", "height above ground (m)", "received power", "mesh", "voxels"):
        assert text in svg, text
    out = plot_waveforms(_curves(), tmp_path / "wf.pdf", title="t")
    assert out.read_bytes()[:4] == b"%PDF"


def test_height_axis_places_the_peak_at_its_height(tmp_path):
    """The peak 5 ns before the ground return stands c * 5 ns / 2 = 0.75 m above the ground."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.arange(2380.0, 2420.0, 0.25)
    w = np.exp(-0.5 * ((t - 2395.0) / 1.0) ** 2)
    opened = set(plt.get_fignums())
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(plt, "close", lambda fig=None: None)  # keep the figure to read its line back
        plot_waveforms([("one", t, w)], tmp_path / "h.png", ground_time_ns=2400.0)
    fig = plt.figure([n for n in plt.get_fignums() if n not in opened][0])
    x, y = fig.axes[0].lines[0].get_data()
    assert y[np.argmax(x)] == pytest.approx(5.0 * C_M_PER_NS / 2.0)
    plt.close(fig)
