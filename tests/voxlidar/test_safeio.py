"""voxlidar.safeio: NPZ files and figures written atomically, read with one clear error."""

from __future__ import annotations

import numpy as np
import pytest

from voxlidar.errors import InputError
from voxlidar.safeio import FigurePathError, finish_figure, open_npz, write_npz


def test_npz_round_trip_and_no_temporary_left(tmp_path):
    a = {"x": np.arange(5.0), "name": np.str_("oak")}
    out = write_npz(tmp_path / "sub" / "a.npz", a)
    assert sorted(p.name for p in out.parent.iterdir()) == ["a.npz"]
    with open_npz(out, "scene") as z:
        assert z["x"].tolist() == [0.0, 1.0, 2.0, 3.0, 4.0] and str(z["name"]) == "oak"


def test_unreadable_npz_is_one_error_naming_the_file(tmp_path):
    bad = tmp_path / "bad.npz"
    bad.write_text("not a zip")
    with pytest.raises(InputError, match=r"bad.npz' is not a readable NPZ plot file"):
        open_npz(bad, "plot")


def test_finish_figure_writes_by_suffix_and_closes(tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    out = finish_figure(fig, tmp_path / "f.svg", caption="seed 1\nphotons 100")
    assert out.read_text().lstrip().startswith("<?xml") and not plt.fignum_exists(fig.number)
    fig, _ = plt.subplots()
    with pytest.raises(FigurePathError, match=r"\.tiff"):
        finish_figure(fig, tmp_path / "f.tiff")
    assert not plt.fignum_exists(fig.number) and not (tmp_path / "f.tiff").exists()
