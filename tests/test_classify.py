"""Classification: two-Gaussian fit, thresholds, geometric refinement, scoring vs truth."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.classify import (PointClass, classify_scan, fit_two_gaussians, leaf_wood_threshold,
                             linearity, refine_geometric, score)
from tlsvox.errors import InputError
from tlsvox.materials import Material
from tlsvox.scan import Scan


def test_em_recovers_a_known_mixture(rng):
    n0, n1 = 30000, 10000
    x = np.concatenate([rng.normal(0.18, 0.05, n0), rng.normal(0.33, 0.06, n1)])
    mix = fit_two_gaussians(x)
    # ML estimates: standard errors ~ sigma/sqrt(n) ~ 0.0005; allow 10 of them
    np.testing.assert_allclose(mix.means, [0.18, 0.33], atol=0.005)
    np.testing.assert_allclose(mix.sigmas, [0.05, 0.06], atol=0.005)
    np.testing.assert_allclose(mix.weights, [0.75, 0.25], atol=0.02)


def test_thresholds_midway_and_equal_posterior(rng):
    x = np.concatenate([rng.normal(0.2, 0.04, 30000), rng.normal(0.4, 0.04, 10000)])
    mix = fit_two_gaussians(x)
    assert leaf_wood_threshold(mix, rule="midway") == pytest.approx(mix.means.mean())
    # equal sigmas: t = midpoint + s^2 ln(w0/w1) / (m1 - m0), shifted towards the rarer class
    s = mix.sigmas.mean()
    expect = mix.means.mean() + s**2 * np.log(mix.weights[0] / mix.weights[1]) / np.diff(mix.means)[0]
    assert leaf_wood_threshold(mix, rule="equal_posterior") == pytest.approx(expect, abs=2e-3)
    assert leaf_wood_threshold(mix, rule="equal_posterior") > mix.means.mean()
    with pytest.raises(InputError, match="midway, equal_posterior"):
        leaf_wood_threshold(mix, rule="otsu")


def test_score_confusion_matrix():
    truth = np.array([Material.LEAF] * 4 + [Material.BARK] * 3 + [Material.GROUND])
    labels = np.array([PointClass.LEAF, PointClass.LEAF, PointClass.WOOD, PointClass.NOISE,
                       PointClass.WOOD, PointClass.WOOD, PointClass.LEAF, PointClass.GROUND])
    sc = score(labels, truth)
    assert sc.recall["leaf"] == pytest.approx(2 / 4)
    assert sc.precision["leaf"] == pytest.approx(2 / 3)
    assert sc.recall["wood"] == pytest.approx(2 / 3)
    assert sc.precision["wood"] == pytest.approx(2 / 3)
    assert sc.confusion.sum() == len(truth)
    assert "| leaf |" in sc.table()


def test_linearity_and_refinement_move_branch_edges_only(rng):
    # a thin branch (radius 1 cm, 2 m long, ~5 mm point spacing: 20 neighbours
    # span ~10 cm, several diameters) and a leaf cluster
    t = rng.uniform(0, 2, 400)
    ph = rng.uniform(0, 2 * np.pi, 400)
    branch = np.column_stack([t, 0.01 * np.cos(ph), 0.01 * np.sin(ph)])
    blob = rng.normal(size=(2000, 3)) * 0.3 + [1.0, 1.5, 0.0]
    xyz = np.vstack([branch, blob])
    lin = linearity(xyz, k=20)
    assert np.median(lin[:400]) > 0.9 and np.median(lin[400:]) < 0.5
    labels = np.full(len(xyz), PointClass.LEAF, np.uint8)
    labels[:400] = PointClass.WOOD
    edge = rng.choice(400, 60, replace=False)  # dark partial hits on the branch edge
    labels[edge] = PointClass.LEAF
    new, moved = refine_geometric(xyz, labels)
    assert np.all(new[edge] == PointClass.WOOD)
    assert np.all(new[400:] == PointClass.LEAF)  # the leaf cluster is untouched
    assert moved == 60


@pytest.fixture(scope="module")
def synthetic_scan():
    from tlsvox.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.synthetic import TreeParams, make_tree

    tree = make_tree(TreeParams(height=8.0, crown_base=2.0, crown_radius=3.0, total_leaf_area=60.0,
                                trunk_radius=0.15), seed=3)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=0.12, azimuth_step_deg=0.12)
    return simulate_scan(tree, pose=paper_scan_poses(tree)[1], preset=preset, seed=2, name="near",
                         progress=False)


def test_classify_synthetic_scan_against_truth(synthetic_scan):
    s = synthetic_scan
    plain = classify_scan(s)
    refined = classify_scan(s, refine=True)
    sp, sr = score(plain.labels, s.truth_material), score(refined.labels, s.truth_material)
    print("\nplain\n" + sp.table() + "\nrefined\n" + sr.table())
    # retro-reflectors read above 0 dB: no Lambertian echo can; the ground is a plane
    assert sp.recall["target"] == 1.0 and sp.precision["target"] == 1.0
    assert sp.recall["ground"] > 0.99 and sp.precision["ground"] > 0.99
    # two peaks: leaf darker than bark, the threshold between them
    m0, m1 = plain.mixture.means
    assert m0 < plain.leaf_wood_threshold < m1
    # the paper's noise rule: every truth leaf below 50 % of 0.267 is lost as noise,
    # so leaf recall cannot exceed the fraction of leaf echoes above it
    leaf = s.truth_material == Material.LEAF
    above = np.mean(plain.reflectance[leaf] >= plain.noise_threshold)
    assert sp.recall["leaf"] <= above + 1e-12
    # refinement moves branch-edge echoes to wood: wood recall rises, leaf precision does not drop
    assert refined.moved_to_wood > 0
    assert sr.recall["wood"] > sp.recall["wood"]
    assert sr.precision["leaf"] >= sp.precision["leaf"]


def test_classify_bad_input(rng):
    xyz = rng.normal(size=(100, 3))
    with pytest.raises(InputError, match="neither reflectance"):
        classify_scan(Scan(xyz=xyz, name="noref"))
    with pytest.raises(InputError, match="1 point"):
        classify_scan(Scan(xyz=xyz[:1], reflectance_db=[-3.0]))
    with pytest.raises(InputError, match="rule"):
        classify_scan(Scan(xyz=xyz, reflectance_db=rng.uniform(-8, -2, 100)), rule="kmeans")
    with pytest.raises(InputError, match="all values are equal"):
        fit_two_gaussians(np.full(100, 0.3))


def test_pictures_fig3_and_fig5e(synthetic_scan, tmp_path):
    from tlsvox.plots_classify import plot_reflectance_histograms, render_classified

    c = classify_scan(synthetic_scan, refine=True)
    png = plot_reflectance_histograms([c], tmp_path / "fig3.png", truth=[synthetic_scan.truth_material])
    assert png.stat().st_size > 10_000
    backend = render_classified(synthetic_scan.xyz, c.labels, tmp_path / "fig5e.png", backend="matplotlib",
                                width=400, height=400)
    assert backend == "matplotlib" and (tmp_path / "fig5e.png").stat().st_size > 5_000
