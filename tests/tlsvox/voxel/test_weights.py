"""Echo weights (tlsvox.voxel.weights): the rules on hand-made pulses, the beam_fraction
column through files and the scanner, and the leaf box of known LAD with pencil and
wide (7-sub-ray) beams, scored against the exact mesh leaf area."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.scan import PulseTable, Scan
from tlsvox.voxel.pulses import beams_from_scan
from tlsvox.voxel.weights import EchoWeights, full_hit_cosine
from voxlidar.materials import Material

LEAF_R = 0.267  # leaf reflectance at 1550 nm (voxlidar.materials)


def _pulses(ranges, fractions=None, refl=None, n=None):
    """One pulse per list of echo ranges along +x, all leaves; an empty list is a gap."""
    dirs, xyz, pid, rn, nr = [], [], [], [], []
    for p, rs in enumerate(ranges):
        a = 0.01 * p
        d = np.array([np.cos(a), np.sin(a), 0.0])
        dirs.append(d)
        for k, r in enumerate(rs):
            xyz.append(d * r)
            pid.append(p)
            rn.append(k + 1)
            nr.append(len(rs) if n is None else n[p])
    m = len(xyz)
    return Scan(xyz=np.array(xyz).reshape(-1, 3), pulse_id=pid, return_number=rn, number_of_returns=nr,
                truth_material=np.full(m, Material.LEAF), pose=np.eye(4),
                pulses=PulseTable(np.array(dirs), [len(r) for r in ranges]),
                beam_fraction=fractions, reflectance_db=None if refl is None else 10 * np.log10(refl),
                meta={"preset": {"wavelength_nm": 1550.0}})


def _weights(beams):
    return beams.echo_weight.round(6).tolist(), beams.tail.round(6).tolist()


def test_uniform_is_one_over_n():
    b, info = beams_from_scan(_pulses([[2.0, 3.0], [4.0], []]), echo_weights="uniform")
    assert _weights(b) == ([0.5, 0.5, 1.0], [0.0, 0.0, 1.0])
    assert info["echo_weights"] == "uniform"


def test_fraction_from_the_column_leaves_the_rest_as_tail():
    s = _pulses([[2.0, 3.0], [4.0], []], fractions=[2 / 7, 3 / 7, 1.0])
    b, info = beams_from_scan(s, echo_weights="fraction")
    assert _weights(b) == ([round(2 / 7, 6), round(3 / 7, 6), 1.0], [round(2 / 7, 6), 0.0, 1.0])
    assert info["echo_weights_source"] == "beam_fraction column"
    # auto picks fraction when the column is there, uniform when not
    assert beams_from_scan(s)[1]["echo_weights"] == "fraction"
    assert beams_from_scan(dataclasses.replace(s, beam_fraction=None))[1]["echo_weights"] == "uniform"


def test_fraction_unknown_shares_take_what_is_left_and_totals_are_capped():
    s = _pulses([[2.0, 3.0], [4.0, 5.0], [6.0, 7.0, 8.0]],
                fractions=[0.25, np.nan, 0.8, 0.7, 0.1, np.nan, np.nan])
    b, _ = beams_from_scan(s, echo_weights="fraction")
    w, tail = _weights(b)
    assert w[:2] == [0.25, 0.75] and tail[0] == 0.0
    assert w[2:4] == [0.8, 0.2] and tail[1] == 0.0  # the beam meets the near echo first
    assert w[4:] == [0.1, 0.45, 0.45] and tail[2] == 0.0


def test_fraction_from_reflectance_over_the_full_hit_reflectance():
    # spherical leaves: a full hit reads on average R * 2/3 (the mean incidence cosine of hits)
    full = LEAF_R * 2 / 3
    s = _pulses([[2.0], [3.0], [4.0, 6.0]], refl=[full, 0.25 * full, 0.5 * full, 3 * full])
    b, info = beams_from_scan(s, echo_weights="fraction", leaf_angle=_la("spherical"))
    w, tail = _weights(b)
    assert np.allclose(w, [1.0, 0.25, 0.5, 0.5], atol=1e-5)  # the far echo takes only what is left
    assert np.allclose(tail, [0.0, 0.75, 0.0], atol=1e-6)
    assert "reflectance over nominal" in info["echo_weights_source"] and "1550 nm" in info["echo_weights_source"]
    # a given nominal reflectance replaces the tabulated one
    b2, info2 = beams_from_scan(s, echo_weights="fraction", leaf_angle=_la("spherical"),
                                leaf_reflectance=2 * LEAF_R, wood_reflectance=0.4)
    assert np.allclose(b2.echo_weight[:2], [0.5, 0.125], atol=1e-5) and "given" in info2["echo_weights_source"]


def test_threshold_drops_weak_returns_as_noise():
    s = _pulses([[2.0], [3.0, 5.0]], refl=[0.4 * LEAF_R, 0.6 * LEAF_R, 0.2 * LEAF_R])
    b, info = beams_from_scan(s, echo_weights="threshold")
    # pulse 0 becomes a gap; pulse 1 keeps one echo of weight 1 (the dropped one does not count in n)
    assert b.echo_start.tolist() == [0, 0, 1]
    assert _weights(b) == ([1.0], [1.0, 0.0])
    assert info["below_threshold"] == 2


def test_rules_that_need_reflectance_say_so():
    s = _pulses([[2.0]])
    with pytest.raises(InputError, match="echo_weights='fraction'.*neither a beam_fraction column nor reflectance"):
        beams_from_scan(s, echo_weights="fraction")
    with pytest.raises(InputError, match="echo_weights='threshold'.*no reflectance"):
        beams_from_scan(s, echo_weights="threshold")
    with pytest.raises(InputError, match="echo_weights='fractoin' is not known; choose one of: auto, uniform"):
        beams_from_scan(s, echo_weights="fractoin")


def _la(kind):
    from voxlidar.leaf_orientation import LeafAngle

    return LeafAngle(kind)


@pytest.mark.parametrize("theta", [0.0, 0.5, 1.2, 1.5])
def test_full_hit_cosine_known_values(theta):
    assert full_hit_cosine("spherical", [theta])[0] == pytest.approx(2 / 3, abs=1e-4)
    assert full_hit_cosine("horizontal", [theta])[0] == pytest.approx(max(np.cos(theta), 1e-3), rel=1e-6)


def test_beam_fraction_column_checked_and_kept_in_las(tmp_path):
    with pytest.raises(InputError, match="beam_fraction must lie in \\[0, 1\\]"):
        Scan(xyz=np.ones((2, 3)), beam_fraction=[0.5, 1.5])
    s = _pulses([[2.0, 3.0], [4.0]], fractions=[2 / 7, np.nan, 1.0])
    s.write(tmp_path / "f.laz")
    back = Scan.read(tmp_path / "f.laz")
    assert np.allclose(back.beam_fraction, s.beam_fraction, equal_nan=True)
    assert Scan.read(_write_plain(tmp_path)).beam_fraction is None


def _write_plain(tmp_path):
    Scan(xyz=np.ones((3, 3)), name="plain").write(tmp_path / "plain.las")
    return tmp_path / "plain.las"


def test_echo_weights_choice_members():
    assert [m.value for m in EchoWeights] == ["auto", "uniform", "fraction", "threshold", "geometric"]


# ---- the leaf box of known LAD (benchmarks/bench_echo_weights.py makes the table of docs/voxelize.md)

# the fixture ``bench`` (benchmarks/bench_echo_weights.py) is in conftest.py


@pytest.fixture(scope="module")
def box(bench):
    return bench.leaf_box()


@pytest.fixture(scope="module")
def scans(bench, box):
    return {n: bench.scan_box(box, n, 0.1) for n in (1, 7)}


def test_scanner_records_the_sub_ray_share(scans):
    for n, ss in scans.items():
        f = ss[0].beam_fraction
        assert f is not None and np.all((f > 0) & (f <= 1))
        assert np.allclose(f * n, np.round(f * n), atol=1e-6)  # whole sub-rays
        per_pulse = np.bincount(ss[0].pulse_id, weights=f)
        assert per_pulse.max() <= 1 + 1e-6
        if n == 1:
            assert np.all(f == 1)
    assert np.mean(scans[7][0].beam_fraction < 1) > 0.3  # most wide-beam echoes are partial hits


def test_pencil_beams_are_unbiased_with_every_share_rule(bench, box, scans):
    uni = bench.score(box, scans[1], "uniform")
    frac = bench.score(box, scans[1], "fraction")
    # pencil beams: 1/n and the sub-ray share are the same weights
    assert frac["mean"] == pytest.approx(uni["mean"], rel=1e-9)
    assert abs(uni["mean"] - uni["true"]) < 3 * uni["se"], uni


def test_wide_beam_fraction_removes_the_partial_hit_bias(bench, box, scans):
    uni = bench.score(box, scans[7], "uniform")
    frac = bench.score(box, scans[7], "fraction")
    # measured +42.6 % with 1/n, -2.7 % with the share (SE of the mean 0.6-0.8 %)
    assert uni["error"] > 0.3 and (uni["mean"] - uni["true"]) > 20 * uni["se"], uni
    assert abs(frac["error"]) < 0.05, frac


def test_wide_beam_fraction_within_monte_carlo_error_when_every_echo_is_detected(bench, box):
    """The -2.7 % left above is the scanner's detection floor: weak partial echoes
    (one sub-ray on an oblique leaf, under -20 dB) are lost and their share goes
    on as tail.  With the floor removed the rule is unbiased (measured -1.0 %)."""
    ss = bench.scan_box(box, 7, 0.1, min_reflectance_db=-60.0)
    frac = bench.score(box, ss, "fraction")
    assert abs(frac["mean"] - frac["true"]) < 3 * frac["se"] + 0.005 * frac["true"], frac


def test_reflectance_rules_are_biased_low_as_documented(bench, box, scans):
    """Reflectance confounds the incidence angle with the intercepted share: a full
    hit on an oblique leaf reads low, so the clipped reflectance share (-18 % with
    7 sub-rays, -25 % with pencil beams) and the paper's threshold (-53 %, -39 %)
    underestimate.  The table in docs/voxelize.md holds these numbers."""
    for n, lo, hi in ((1, -0.32, -0.17), (7, -0.26, -0.11)):
        r = bench.score(box, scans[n], "fraction (reflectance)")
        assert lo < r["error"] < hi, (n, r)
    for n, lo, hi in ((1, -0.46, -0.31), (7, -0.60, -0.45)):
        r = bench.score(box, scans[n], "threshold")
        assert lo < r["error"] < hi, (n, r)


# ---- geometric weights: the expected share from the beam's footprint (tlsvox.voxel.footprint)


def _stripped(ss):
    """A multi-return export with nothing but returns: no share column, reflectance or intensity."""
    return [dataclasses.replace(s, beam_fraction=None, reflectance_db=None, intensity=None) for s in ss]


def test_footprint_model_reproduces_the_scanners_shares(scans):
    """With the box's true LAD, the model's weight of a return of an n-return pulse is the scanner's
    own mean sub-ray share (an independent ray caster against the mesh): measured 0.771 / 0.448 / 0.315
    against 0.769 / 0.444 / 0.316 for n = 1, 2, 3 on the first scan."""
    from tlsvox.voxel.footprint import LadField
    from voxlidar.leaf_orientation import LeafAngle

    field = LadField(np.array([-1.0, -1.0, 1.0]), 0.1, np.full((20, 20, 20), 1.5))
    for s in scans[7]:
        model, info = beams_from_scan(_stripped([s])[0], leaf_angle=LeafAngle("spherical"), echo_weights="geometric",
                                      lad_field=field)
        truth, _ = beams_from_scan(s, leaf_angle=LeafAngle("spherical"), echo_weights="fraction")
        n = np.diff(model.echo_start)
        per_echo = np.repeat(n, n)
        for k in (1, 2, 3):
            m = per_echo == k
            assert abs(model.echo_weight[m].mean() - truth.echo_weight[m].mean()) < 0.03, (s.name, k)
        hist = info["echo_weights_model"]["returns_per_pulse"]
        assert np.allclose(hist["model"], hist["scan"], atol=0.03), hist


def test_geometric_weights_hold_the_leaf_box_without_reflectance(bench, box, scans):
    """The issue's known answer: a wide multi-return beam, no intensity.  1/n reads +42.6 %; the geometric
    weights -1.1 % (on three boxes and two detection floors -2.0 to +3.4 %; the share column: -2.7 %);
    SE of the mean 0.6 %."""
    stripped = _stripped(scans[7])
    uni = bench.score(box, stripped, "uniform")
    geo = bench.score(box, stripped, "geometric")
    assert uni["error"] > 0.3, uni
    assert abs(geo["error"]) < 0.05, geo
    assert "footprint" in geo["source"]


def test_geometric_weights_are_seeded_stated_and_wood_takes_the_rest(bench, box, scans):
    from tlsvox import voxelize

    stripped = _stripped(scans[7])
    kw = dict(voxel_size=0.5, leaf_angle="spherical", ground=None, bounds=bench.BOUNDS, echo_weights="geometric",
              progress=False)
    a, b = voxelize(stripped, **kw), voxelize(stripped, **kw)
    assert np.array_equal(a.lad.lad, b.lad.lad)  # the same seed, the same weights
    info = a.scene.meta["scans"][0]
    assert info["echo_weights"] == "geometric" and info["echo_weights_rounds"] == 2
    assert info["echo_weights_model"]["rule"] == "geometric" and "footprint" in info["echo_weights_source"]


def test_geometric_wood_and_ground_returns_take_what_the_leaves_left():
    from tlsvox.voxel.footprint import FootprintModel, LadField, footprint_fractions
    from tlsvox.voxel.trace import EchoKind

    model = FootprintModel(n_subrays=7, beam_radius=0.005)
    field = LadField(np.zeros(3), 0.5, np.full((4, 4, 4), 1.0))
    pulse = np.array([0, 0, 1, 2, 2])
    ranges = np.array([0.5, 1.5, 0.7, 0.4, 1.9])
    kinds = np.array([EchoKind.LEAF, EchoKind.WOOD, EchoKind.LEAF, EchoKind.LEAF, EchoKind.OTHER], np.uint8)
    dirs = np.tile([1.0, 0.0, 0.0], (3, 1))
    frac, meta = footprint_fractions(pulse, ranges, kinds, np.array([0.0, 1.0, 1.0]), dirs, model, field)
    assert np.all(np.isnan(frac[[1, 4]])) and np.all((frac[[0, 2, 3]] > 0) & (frac[[0, 2, 3]] <= 1))
    assert meta["rule"] == "geometric"
