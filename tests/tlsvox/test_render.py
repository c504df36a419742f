"""tlsvox.render: headless pictures (the matplotlib fallback checked pixel by pixel)."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.render import colormap, reflectance_colors, render


def test_colormap_ends_and_clipping():
    c = colormap([0.0, 0.5, 1.0, 7.0], vmin=0.0, vmax=1.0, name="gray")
    assert c.shape == (4, 3)
    assert np.allclose(c[0], 0.0) and np.allclose(c[2], 1.0) and np.allclose(c[3], 1.0)
    assert reflectance_colors([np.nan, -20.0]).tolist()[0] == reflectance_colors([-20.0]).tolist()[0]


def test_matplotlib_render_puts_the_points_in_the_middle(tmp_path):
    rng = np.random.default_rng(0)
    pts = rng.normal(scale=0.2, size=(2000, 3))
    red = np.tile([1.0, 0.0, 0.0], (len(pts), 1))
    path = tmp_path / "pts.png"
    used = render([(pts, red)], path, eye=(0.0, -10.0, 0.0), center=(0.0, 0.0, 0.0), width=400, height=300,
                  backend="matplotlib", title="a red blob")
    assert used == "matplotlib"
    import matplotlib.image as mpimg

    img = mpimg.imread(path)[..., :3]
    h, w = img.shape[:2]
    redness = (img[..., 0] > 0.6) & (img[..., 1] < 0.4) & (img[..., 2] < 0.4)
    ys, xs = np.nonzero(redness)
    assert len(xs) > 50
    assert abs(xs.mean() / w - 0.5) < 0.15 and abs(ys.mean() / h - 0.5) < 0.2
    assert not redness[: h // 10, : w // 10].any()  # a white corner


def test_render_refuses_an_unknown_backend(tmp_path):
    with pytest.raises(Exception, match="backend"):
        render([], tmp_path / "x.png", eye=(0, -1, 0), center=(0, 0, 0), backend="povray")


def test_title_and_colour_scale_are_added_around_the_picture(tmp_path):
    import matplotlib.image as mpimg

    pts = np.random.default_rng(1).normal(size=(500, 3))
    kw = dict(eye=(0.0, -10.0, 0.0), center=(0.0, 0.0, 0.0), width=400, height=300, backend="matplotlib")
    render([(pts, colormap(pts[:, 2]))], tmp_path / "plain.png", **kw)
    render([(pts, colormap(pts[:, 2]))], tmp_path / "dressed.png", title="heights",
           colorbar=("viridis", -3.0, 3.0, "height z (m)"), **kw)
    plain, dressed = mpimg.imread(tmp_path / "plain.png"), mpimg.imread(tmp_path / "dressed.png")
    assert dressed.shape[0] == plain.shape[0] + 50 and dressed.shape[1] == plain.shape[1] + 110
