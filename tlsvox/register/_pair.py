"""Registering scans: one pair (:func:`register_pair`), or all to a reference.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError, RegistrationError
from tlsvox.readers import check_scan
from tlsvox.register._features import consensus_groups, feature_matches, fpfh_features, ransac_transform
from tlsvox.register._icp import coincidence, fitness_scores, off_ground, refine_icp
from tlsvox.register._targets import detect_targets, match_targets
from tlsvox.register._transforms import MAX_TILT_DEG, apply_transform, pose_error, true_relative_transform
from tlsvox.register.settings import RegisterSettings
from tlsvox.scan import Scan
from voxlidar.choices import Choice

#: fewest points a scan needs to be registered at all
MIN_POINTS = 50


class RegistrationMethod(Choice):
    """How the coarse alignment is found (ICP refines every one of them)."""

    AUTO = "auto"  #: targets when both scans show >= 3 common ones, else FPFH
    TARGETS = "targets"  #: retro-reflective targets only (fails without them)
    FPFH = "fpfh"  #: FPFH features + RANSAC, no targets
    ICP = "icp"  #: ICP alone from the given ``init``


@dataclass
class RegistrationResult:
    """Outcome of registering one source scan to a reference scan.

    Attributes
    ----------
    transform : (4, 4) float64
        Reference-from-source: maps the source scanner frame into the
        reference frame.
    method : str
        Coarse stage used: ``targets``, ``fpfh`` or ``icp``.
    fitness : float
        Fraction of source points (voxel down-sampled) with a reference point
        within ``fitness_distance_m`` after the transform.
    fitness_off_plane : float
        The same after removing the source's dominant plane (the ground).
    inlier_rmse_m : float
    target_pairs : (M, 2) int or None
        Source/reference target indices used.
    target_rmse_m : float or None
        RMSE of the matched target centres after the *final* transform.
    stages : list of dict
        ICP per-scale figures.
    seconds : float
    error_vs_truth : dict or None
        ``rotation_deg``, ``translation_m`` when both scans know ``pose_true``.
    settings : dict
        The run's :class:`~tlsvox.register.settings.RegisterSettings`, as
        ``to_dict`` gives them.
    """

    source: str
    reference: str
    transform: np.ndarray
    method: str
    fitness: float
    fitness_off_plane: float
    inlier_rmse_m: float
    fitness_distance_m: float
    target_pairs: np.ndarray | None = None
    target_rmse_m: float | None = None
    n_targets: tuple[int, int] | None = None
    stages: list = field(default_factory=list)
    hypothesis_groups: list | None = None
    seconds: float = 0.0
    error_vs_truth: dict | None = None
    coincidence: dict | None = None
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = {k: getattr(self, k) for k in ("source", "reference", "method", "fitness",
                                           "fitness_off_plane", "inlier_rmse_m",
                                           "fitness_distance_m", "target_rmse_m", "stages", "hypothesis_groups",
                                           "seconds", "error_vs_truth", "coincidence", "settings")}
        d["transform"] = np.asarray(self.transform).tolist()
        d["target_pairs"] = None if self.target_pairs is None else np.asarray(self.target_pairs).tolist()
        d["n_targets"] = None if self.n_targets is None else list(self.n_targets)
        return d


def register_pair(source: Scan, reference: Scan, settings: RegisterSettings | None = None, *, init=None,
                  **kwargs) -> RegistrationResult:
    """Register ``source`` onto ``reference`` (both in their scanner frames).

    The stages: the coarse alignment by targets (:func:`coarse_by_targets`)
    or by features (:func:`coarse_by_features`, which finishes and tests
    each hypothesis), or the given ``init``; then ICP and the acceptance test
    (:func:`finish`).  Their settings come from ``settings``
    (:class:`~tlsvox.register.settings.RegisterSettings`, in four groups),
    any of whose fields a keyword argument replaces (``register_pair(a, b,
    method="fpfh")``); ``RegistrationResult.settings`` records them in full.

    Parameters
    ----------
    source, reference : Scan
    settings : RegisterSettings, optional
        Every setting below, grouped (default: the defaults).
    method : {'auto', 'targets', 'fpfh', 'icp'}
        Coarse stage; ``auto`` uses targets when >= 3 match, else FPFH.
    init : (4, 4) float, optional
        Start for ``method='icp'``.
    voxel_sizes : sequence of float, metres
        ICP scales, coarse to fine; the finest also scores the fitness.
    global_voxel_m : float, default 0.3
        Voxel of the FPFH + RANSAC stage.
    min_fitness : float, default 0.25
        Least accepted fitness (the larger of source->reference and
        reference->source, at the finest voxel within 2.5 voxels), on all
        points *and* off the dominant plane.  Necessary, not sufficient: a
        crown laid on another crown, or one half of a crown turned onto the
        other, also scores 0.34-0.43 (default tree), hence the coincidence
        test.
    target_tolerance_m : float, default 0.03
    target_shape, target_radius_m, min_target_reflectance_db
        See :func:`detect_targets`.
    icp_after_targets : bool, default False
        Refine a target fit with ICP.  Off by default: target centres fit to
        millimetres, while ICP on foliage is biased by mixed echoes (partial
        hits averaged along the beam) that differ between viewpoints
        (measured: 0.08 deg / 18 mm on the synthetic pair).
    n_hypotheses : int, default 5
        Best distinct RANSAC peaks kept, each refined by coarse ICP; those
        that converge together (within ``consensus_rot_deg`` and
        ``consensus_trans_m``) form a group.  Groups are finished by ICP and
        tested (fitness, coincidence) in turn, largest first; the first that
        passes is the answer.  In foliage 1 % of the feature matches are
        right, and a structural peak (half a turn of a round crown) scores as
        many inliers as the true one: on the small test tree the true peak
        ranks 4th-5th.
    min_consensus : int, default 1
        Least group size tried.  Independent hypotheses (disjoint halves of
        the matches) were tried as the acceptance test and dropped: the two
        halves of a crown, a non-overlapping pair, reproduce the same wrong
        peak, and on the small tree the halves rarely both find the true one.
    ransac_samples : int, default 200000
        Minimal samples per RANSAC run.
    min_coincidence_ratio : float, default 2.0
        Least ratio of coincident points (within ``coincidence_m``) to the
        chance level (see :func:`coincidence`): at 2, at least half of the
        coincidences are due to the registration.  Measured on the default
        tree: 7.8-8.0 for the true alignment, 1.1-1.3 for wrong ones.
    coincidence_m : float, default 0.015
    levelled : bool, default True
        Scanners are levelled (within :data:`MAX_TILT_DEG`): RANSAC fits yaw
        + translation (ICP recovers the residual tilt), and target matches
        that tilt by more are rejected (upside-down fits of symmetric
        layouts).  False: RANSAC fits full rotations from 3 matches, which
        needs far more right matches.
    seed : int, default 0
        Seeds the split of the matches, the RANSAC samples, the ground-plane
        RANSAC and the coincidence sample: the same seed, the same result.

    Returns
    -------
    RegistrationResult

    Raises
    ------
    RegistrationError
        No transform found, or one whose fitness is below ``min_fitness``
        (the figures are in the message and in ``err.figures``).
    InputError
        Bad scans or options.
    """
    t0 = time.perf_counter()
    st = RegisterSettings.from_kwargs(settings, **kwargs)
    m = RegistrationMethod.parse(st.coarse.method, "method")
    for s in (source, reference):
        check_scan(s, min_points=MIN_POINTS)
    min_fitness = st.acceptance.min_fitness
    if not (isinstance(min_fitness, int | float) and 0.0 < min_fitness <= 1.0):
        raise InputError(f"min_fitness={min_fitness!r} must lie in (0, 1]")
    try:
        voxel_sizes = tuple(float(v) for v in st.icp.voxel_sizes)
    except (TypeError, ValueError):
        voxel_sizes = (-1.0,)
    if not voxel_sizes or any(not v > 0 for v in voxel_sizes):
        raise InputError(f"voxel_sizes={st.icp.voxel_sizes!r} must be positive lengths in metres, coarse to fine")
    if m is RegistrationMethod.ICP and init is None:
        raise InputError("method='icp' needs init= (a 4x4 start transform); or use method='auto'")
    pairs, n_targets, centres, used, T0 = None, None, None, m.value, None
    if m in (RegistrationMethod.AUTO, RegistrationMethod.TARGETS):
        pairs, T0, n_targets, centres = coarse_by_targets(source, reference, st)
        if T0 is not None:
            used = "targets"
        elif m is RegistrationMethod.TARGETS:
            raise RegistrationError(
                f"{source.name!r} -> {reference.name!r}: no 3 targets in common "
                f"(targets found: {n_targets if n_targets else 'no reflectance to find them'}); "
                "use method='fpfh' or 'auto'", {"n_targets": n_targets})
    if T0 is None and m in (RegistrationMethod.AUTO, RegistrationMethod.FPFH):
        return coarse_by_features(source, reference, st, voxel_sizes, t0)
    if T0 is None:
        T0 = np.asarray(init, dtype=np.float64)
        if T0.shape != (4, 4) or not np.all(np.isfinite(T0)):
            raise InputError(f"init must be a finite 4x4 matrix, got shape {T0.shape}")
        used = "icp"
    return finish(source, reference, T0, used, st, voxel_sizes, t0,
                  refine=not (used == "targets" and not st.targets.icp_after_targets),
                  extra=dict(target_pairs=pairs, n_targets=n_targets, target_centres=centres))


def coarse_by_targets(source: Scan, reference: Scan, st: RegisterSettings):
    """Targets found in both scans and matched: ``(pairs, transform, counts, centres)``, the pairs and the
    transform None when fewer than three match (or a scan has no reflectance)."""
    tg = st.targets
    if source.reflectance_db is None or reference.reflectance_db is None:
        return None, None, None, None
    ts, tr = (detect_targets(s, min_reflectance_db=tg.min_target_reflectance_db, target_shape=tg.target_shape,
                             target_radius_m=tg.target_radius_m) for s in (source, reference))
    found = match_targets(ts, tr, tolerance_m=tg.target_tolerance_m,
                          max_tilt_deg=MAX_TILT_DEG if st.coarse.levelled else None)
    if found is None:
        return None, None, (len(ts), len(tr)), None
    pairs, T0 = found
    return pairs, T0, (len(ts), len(tr)), (ts, tr)


def coarse_by_features(source: Scan, reference: Scan, st: RegisterSettings, voxel_sizes, t0) -> RegistrationResult:
    """FPFH + RANSAC hypotheses, grouped, each group finished by ICP and tested, largest first (raises when
    none passes).

    FPFH on the off-ground points (the ground is featureless and would
    dominate); the ``n_hypotheses`` best distinct RANSAC peaks, each refined
    by coarse ICP (peaks that converge together form a group). In foliage the
    inlier count cannot tell the true peak from a structural one (half a turn
    of a roughly round crown scores as high), so each group is finished and
    judged by the acceptance test, largest group first.
    """
    co, ac = st.coarse, st.acceptance
    ps, fs = fpfh_features(off_ground(source.xyz, seed=co.seed), co.global_voxel_m)
    pr, fr = fpfh_features(off_ground(reference.xyz, seed=co.seed), co.global_voxel_m)
    P, Q = feature_matches(ps, fs, pr, fr)
    cands, figs = [], []
    for Tg, n_in in ransac_transform(P, Q, dist_m=1.5 * co.global_voxel_m, rng=np.random.default_rng(co.seed),
                                     n_samples=co.ransac_samples, levelled=co.levelled, top=co.n_hypotheses):
        Th, stages = refine_icp(source.xyz, reference.xyz, Tg, voxel_sizes=voxel_sizes[:1])
        cands.append(Th)
        figs.append(dict(stages[-1], ransac_inliers=n_in))
    groups = [g for g in consensus_groups(cands, rot_deg=co.consensus_rot_deg, trans_m=co.consensus_trans_m)
              if len(g) >= co.min_consensus]
    hypotheses = [len(g) for g in groups]
    tried = []
    for g in groups:
        try:
            return finish(source, reference, cands[g[0]], "fpfh", st, voxel_sizes, t0,
                          extra=dict(hypothesis_groups=hypotheses))
        except RegistrationError as err:
            tried.append(err.figures)
    summary = [(round(f["fitness"], 3), round(f["fitness_off_plane"], 3),
                round(f["coincidence"]["coincidence_ratio"], 2)) for f in tried]
    raise RegistrationError(
        f"{source.name!r} -> {reference.name!r}: FPFH + RANSAC found no trustworthy transform: "
        f"{len(cands)} RANSAC peaks (of {len(P)} feature matches; inliers "
        f"{[f['ransac_inliers'] for f in figs]}) in {len(groups)} groups of >= {co.min_consensus}; "
        f"each finished by ICP scored (fitness, off the dominant plane, coincidence ratio) "
        f"{summary}, need fitness >= {ac.min_fitness} and coincidence ratio >= {ac.min_coincidence_ratio}. "
        "The scans probably do not overlap; if they do, add targets or give init= with method='icp'",
        {"hypothesis_groups": hypotheses, "ransac_inliers": [f["ransac_inliers"] for f in figs],
         "coarse_fitness": [f["fitness"] for f in figs], "candidates": tried,
         "coincidence": min((f["coincidence"] for f in tried), key=lambda c: c["coincidence_ratio"],
                            default=None)})


def finish(source: Scan, reference: Scan, T0, used: str, st: RegisterSettings, voxel_sizes, t0, *,
           refine: bool = True, extra=None) -> RegistrationResult:
    """ICP from ``T0``, then the acceptance test: fitness and coincidence (raises)."""
    min_fitness, min_coincidence_ratio = st.acceptance.min_fitness, st.acceptance.min_coincidence_ratio
    coincidence_m, seed = st.acceptance.coincidence_m, st.coarse.seed
    extra = dict(extra or {})
    centres = extra.pop("target_centres", None)
    pairs = extra.get("target_pairs")
    if not refine:
        T, stages = T0, []
    else:
        T, stages = refine_icp(source.xyz, reference.xyz, T0, voxel_sizes=voxel_sizes)
    # fitness both ways (scans of different density and extent), the larger kept
    kw = dict(voxel_m=voxel_sizes[-1], distance_m=2.5 * voxel_sizes[-1])
    fit_a = fitness_scores(source.xyz, reference.xyz, T, **kw)
    fit_b = fitness_scores(reference.xyz, source.xyz, np.linalg.inv(T), **kw)
    fit = {k: max(fit_a[k], fit_b[k]) for k in ("fitness", "fitness_off_plane")}
    fit["inlier_rmse_m"] = fit_a["inlier_rmse_m"] if fit_a["fitness"] >= fit_b["fitness"] else fit_b["inlier_rmse_m"]
    fit["fitness_distance_m"] = kw["distance_m"]
    target_rmse = None
    if pairs is not None:
        ts, tr = centres
        d = apply_transform(T, ts[pairs[:, 0]]) - tr[pairs[:, 1]]
        target_rmse = float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
    result = RegistrationResult(
        source=source.name, reference=reference.name, transform=T, method=used,
        fitness=fit["fitness"], fitness_off_plane=fit["fitness_off_plane"],
        inlier_rmse_m=fit["inlier_rmse_m"], fitness_distance_m=fit["fitness_distance_m"],
        target_rmse_m=target_rmse, stages=stages, settings=st.to_dict(), **extra)
    T_true = true_relative_transform(source, reference)
    if T_true is not None:
        rot, tr_err = pose_error(T, T_true)
        result.error_vs_truth = {"rotation_deg": rot, "translation_m": tr_err}
    result.coincidence = coincidence(source.xyz, reference.xyz, T, radius_m=coincidence_m, seed=seed)
    ratio = result.coincidence["coincidence_ratio"]
    result.seconds = time.perf_counter() - t0
    if min(result.fitness, result.fitness_off_plane) < min_fitness or ratio < min_coincidence_ratio:
        figures = result.to_dict()
        raise RegistrationError(
            f"{source.name!r} -> {reference.name!r}: registration by {used} is not trustworthy: "
            f"fitness {result.fitness:.3f}, off the dominant plane {result.fitness_off_plane:.3f} "
            f"(need >= {min_fitness}), inlier RMSE {result.inlier_rmse_m * 1000:.1f} mm within "
            f"{result.fitness_distance_m * 1000:.0f} mm; points within {coincidence_m * 1000:.0f} mm "
            f"of each other {result.coincidence['coincident']:.4f}, by chance "
            f"{result.coincidence['coincident_by_chance']:.4f}: ratio {ratio:.2f} (need >= "
            f"{min_coincidence_ratio}). Do the scans overlap? If so, try "
            "another method, larger voxel_sizes, or targets", figures)
    return result


def register_scans(scans: list[Scan], *, reference: int = 0, **kwargs) -> list[RegistrationResult | None]:
    """Register every scan to ``scans[reference]`` and set each scan's ``pose``.

    The reference keeps its ``pose`` (identity when unknown); every other scan
    gets ``pose = pose_ref @ T``.  Keyword arguments go to :func:`register_pair`.

    Returns
    -------
    list
        One :class:`RegistrationResult` per scan, None for the reference.

    Raises
    ------
    RegistrationError
        When any scan fails; no scan's pose is changed then.
    """
    if len(scans) < 2:
        raise InputError(f"register_scans needs at least 2 scans, got {len(scans)}")
    if not (0 <= reference < len(scans)):
        raise InputError(f"reference={reference} is not a scan index (0..{len(scans) - 1})")
    ref = scans[reference]
    results: list[RegistrationResult | None] = []
    for k, s in enumerate(scans):
        results.append(None if k == reference else register_pair(s, ref, **kwargs))
    pose_ref = ref.pose if ref.pose is not None else np.eye(4)
    ref.pose = pose_ref
    for s, r in zip(scans, results):
        if r is not None:
            s.pose = pose_ref @ r.transform
    return results
