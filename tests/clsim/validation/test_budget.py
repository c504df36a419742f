"""clsim.validation.budget: waveform scores against known transformations of a reference."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.sensor import C_M_PER_NS
from clsim.validation.budget import budget_table, default_pulses, waveform_metrics


class _Result:
    """The part of a SimulationResult the budget reads: a waveform and energies by kind."""

    def __init__(self, t, w, energies):
        self.time_ns, self.waveform, self._e = t, w, energies

    def energy(self, kind=None):
        return self._e[kind or "total"], 0.01 * self._e[kind or "total"]


def _reference():
    t = np.arange(2300.0, 2450.0, 0.25)
    w = np.exp(-0.5 * ((t - 2380.0) / 3.0) ** 2) + 2.0 * np.exp(-0.5 * ((t - 2400.0) / 2.0) ** 2)
    return _Result(t, w, {"total": 3.0, "vegetation": 1.0, "ground": 2.0})


def test_a_waveform_against_itself_scores_perfectly():
    ref = _reference()
    m = waveform_metrics(ref, ref, ground_time_ns=2400.0)
    assert m["r"] == pytest.approx(1.0) and m["nrmse"] == 0.0
    assert m["total"] == m["vegetation"] == m["ground"] == 1.0
    assert m["drh50"] == m["drh98"] == 0.0
    assert m["veg_ground"] == m["ref_veg_ground"] == 0.5


def test_scaled_and_shifted_waveforms_give_the_known_ratios_and_heights():
    ref = _reference()
    doubled = _Result(ref.time_ns, 2.0 * ref.waveform, {k: 2.0 * v for k, v in ref._e.items()})
    m = waveform_metrics(doubled, ref, ground_time_ns=2400.0)
    assert m["r"] == pytest.approx(1.0) and m["total"] == pytest.approx(2.0)
    # the same returns 1 ns later: every relative height drops by c * 1 ns / 2 (two-way travel)
    dt = 1.0
    later = _Result(ref.time_ns + dt, ref.waveform, ref._e)
    m = waveform_metrics(later, ref, ground_time_ns=2400.0)
    expected = -dt * C_M_PER_NS / 2.0
    assert m["drh50"] == pytest.approx(expected, abs=0.01) and m["drh98"] == pytest.approx(expected, abs=0.01)


def test_budget_table_has_one_row_per_result():
    ref = _reference()
    row = {"pulse": "nadir-centre", "model": "b", **waveform_metrics(ref, ref, ground_time_ns=2400.0)}
    table = budget_table([row, row]).splitlines()
    assert len(table) == 4 and table[2].startswith("| nadir-centre | b | 1.000 | 0.000 |")


def test_default_pulses_aim_at_the_crown():
    p = default_pulses(crown_center=(10.0, -5.0), crown_radius=4.0, off_nadir_deg=15.0)
    assert [q.name for q in p] == ["nadir-centre", "nadir-edge", "oblique-centre", "oblique-edge"]
    assert tuple(p[0].target) == (10.0, -5.0)
    assert tuple(p[1].target) == (13.0, -5.0)  # three quarters of the crown radius out
    assert p[2].off_nadir_deg == p[3].off_nadir_deg == 15.0 and p[0].off_nadir_deg == 0.0
