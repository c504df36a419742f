""":func:`measure_leaf_angles`: the stages of a measurement, from the scans to per-layer distributions."""

from __future__ import annotations

import numpy as np

from tlsvox.errors import InputError
from tlsvox.leafangles._histogram import HALF_PI, _em, _weighted, fit_beta
from tlsvox.leafangles._layers import LayerLeafAngles, LeafAngleMeasurement, LeafAngleMethod, _in_layer
from tlsvox.leafangles._planes import _fit_scan, trunk_center
from tlsvox.leafangles._simulate import _layer_rows
from tlsvox.leafangles.settings import LeafAngleSettings
from voxlidar.leaf_orientation import LeafAngle


def _class_mask(scan, material, point_class):
    """Echoes of a truth material, else of a class; None when the scan says neither."""
    if scan.truth_material is not None:
        return np.asarray(scan.truth_material) == material
    if scan.classification is not None:
        return np.asarray(scan.classification) == point_class
    return None


def _leaf_mask(scan):
    from tlsvox.classify import PointClass
    from voxlidar.materials import Material

    mask = _class_mask(scan, Material.LEAF, PointClass.LEAF)
    if mask is None:
        raise InputError(f"scan {scan.name!r} says neither which echoes are leaves (no truth_material, no "
                         "classification): classify it first (tlsvox.classify_scan) or pass leaf=[mask, ...]")
    return mask


def _scan_beam(scan):
    """(exit radius m, half divergence rad, sub-rays) of a scan's preset, else the RIEGL VZ-400's."""
    p = scan.meta.get("preset", {})
    return (0.5 * float(p.get("beam_exit_diameter_m", 0.007)), 0.5e-3 * float(p.get("divergence_mrad", 0.35)),
            int(p.get("n_subrays", 7)))


def measure_leaf_angles(scans, settings: LeafAngleSettings | None = None, *, leaf=None,
                        **kwargs) -> LeafAngleMeasurement:
    """Measure the leaf inclination distribution per crown layer from leaf echoes.

    The stages, each a function of this module: :func:`check_settings`,
    :func:`scan_poses`, :func:`crown_centre` (the outward model's axis),
    :func:`fit_scans` (the plane fits of each scan's leaf echoes),
    :func:`deconvolution_rows` (the simulated measurement per scan and layer),
    :func:`choose_azimuth` (each layer's azimuth model), then
    :func:`layer_result` per layer and for the crown.  Their settings come
    from ``settings`` (:class:`~tlsvox.leafangles.settings.LeafAngleSettings`,
    grouped by stage), any of whose fields a keyword argument replaces
    (``measure_leaf_angles(scans, layers=2)``); ``params["settings"]``
    records them in full.

    Parameters
    ----------
    scans : list of Scan
        Registered scans (a pose each; a simulated scan's true pose is used
        when it has no other).
    settings : LeafAngleSettings, optional
        Every setting below, grouped (default: the defaults).
    layers : int
        Equal-height crown layers between the 1st and 99th height percentiles
        of the leaf echoes with a plane fit (>= 1).
    method : {"deconvolve", "weighted"}
        See the module docstring.
    radius : float, metres
        Neighbourhood radius of the plane fits (leaf scale).
    min_points : int
        Echoes a neighbourhood needs for a plane fit (>= 3).
    min_spread : float, metres
        Smallest in-plane minor spread (square root of the middle covariance
        eigenvalue) of a neighbourhood kept for a plane fit; nearly collinear
        neighbourhoods (oblique leaves) fix no plane.  The deconvolution
        applies the same test to its simulated leaves.
    bins : int
        Inclination bins on [0, 90] degrees.
    range_noise : float, metres, optional
        Range noise (1 sigma) of the instrument; default the scan's preset
        (``meta["preset"]["range_noise_m"]``) else 5 mm (RIEGL VZ-400).
    leaf_size : float, metres
        Leaf length of the simulated leaves (ellipses, width half the
        length) in the deconvolution.
    angular_step : float or (2,) float, degrees, optional
        Zenith and azimuth steps of the scans; default each scan's angular
        grid (pulse table) or simulator preset.
    beam : (3,) tuple, optional
        The instrument's beam in the deconvolution: (exit beam diameter m,
        full divergence mrad, sub-rays 1/7/19/37); default each scan's preset,
        else the RIEGL VZ-400's (7 mm, 0.35 mrad, 7).  ``(0, 0, 1)`` is a
        pencil beam.
    azimuth : {"auto", "uniform", "outward"}
        Leaf azimuth model of the deconvolution: leaves facing any azimuth,
        facing away from the crown centre, or (``"auto"``) per layer the one
        of the two with the larger share when both are fitted together
        (``params["azimuth_share"]``, ``params["azimuth_model"]``).  Without
        a crown centre (none given and no trunk found) only ``"uniform"`` is
        used and ``params["azimuth_models"]`` says so.
    crown_center : (2,) float, metres, optional
        The crown's axis (x, y) in the world frame for the outward model;
        default the trunk's (:func:`trunk_center` of the wood echoes: truth
        bark or the classification's wood class).
    zenith_groups, samples, max_simulated, iterations
        Deconvolution: groups of beam zenith angles per scan and crown
        layer, simulated leaves per bin, sampled echo and azimuth model
        (spread over the occlusion levels), echoes sampled per scan and crown
        layer, EM iterations (of each fit: with ``"auto"`` the shares' fit
        comes first).
    cap : float
        Smallest ``|cos a|`` between a fitted normal and its beam: fits nearer
        edge-on are dropped (their normals are set by the errors along the
        beam), in the simulation too; the others are weighted by ``1 / |cos a|``.
    second_leaf : bool
        Deconvolution: add occlusion levels where a second leaf behind the
        first lies in the neighbourhood (see :func:`_simulate_kernel`); their
        share, like the other levels', is fitted.  False gives the
        single-leaf levels alone.
    seed : int
        Seeds the simulated leaves.

    leaf : list of (N_i,) bool, optional
        Leaf echoes per scan; default ``truth_material == LEAF`` or the
        classification's leaf class.

    Returns
    -------
    LeafAngleMeasurement
    """
    s = LeafAngleSettings.from_kwargs(settings, **kwargs)
    scans = list(scans)
    if not scans:
        raise InputError("measure_leaf_angles needs at least one scan")
    if leaf is not None and len(leaf) != len(scans):
        raise InputError(f"leaf= holds {len(leaf)} masks for {len(scans)} scans; give one per scan")
    method, beam, crown_center = check_settings(s)
    h, pf, dc = s.histogram, s.planes, s.deconvolution
    rng = np.random.default_rng(dc.seed)
    poses = scan_poses(scans)
    centre, centre_from, models = crown_centre(scans, poses, method, dc.azimuth, crown_center)
    n_azimuth = 4 if "outward" in models else 1
    fits, noise_used, steps, beams, used = fit_scans(scans, poses, s, method, beam, centre, n_azimuth, leaf)
    z_all = np.concatenate([f.z[f.ok] for f in fits]) if fits else np.zeros(0)
    if len(z_all) < 10 * h.bins:
        raise InputError(f"only {len(z_all)} leaf echoes have {pf.min_points} neighbours within {pf.radius} m: too "
                         "few for a leaf angle histogram; scan closer or denser, or raise radius")
    lo, hi = np.percentile(z_all, [1, 99])
    cuts = np.linspace(lo, hi, h.layers + 1)
    rows = []
    if method is LeafAngleMethod.DECONVOLVE:
        rows = deconvolution_rows(fits, cuts, s, steps, beams, noise_used, models, n_azimuth, rng)
    shares, chosen, rows = choose_azimuth(rows, len(fits), h.layers, models, dc.iterations)
    mixes = [[None] * h.layers for _ in fits]
    per_layer = [layer_result(fits, rows, [k], cuts[k:k + 2], cuts, method, h.bins, dc.iterations, mixes)
                 for k in range(h.layers)]
    crown = layer_result(fits, rows, list(range(h.layers)), [z_all.min(), z_all.max()], cuts, method, h.bins,
                         dc.iterations, mixes)
    deconvolve = method is LeafAngleMethod.DECONVOLVE
    params = {"occlusion_mix": [[None if m is None else [round(float(v), 3) for v in m] for m in scan_mixes]
                                for scan_mixes in mixes],
              "azimuth_models": list(models) if deconvolve else None,
              "azimuth_share": [None if a is None else {mod: round(float(v), 3) for mod, v in zip(models, a)}
                                for a in shares] if deconvolve else None,
              "azimuth_model": [None if c is None else models[c] for c in chosen] if deconvolve else None,
              "scans_used": used,
              "crown_center_m": None if centre is None else [round(float(v), 3) for v in centre],
              "crown_center_from": centre_from,
              "beam": [{"exit_radius_m": b[0], "half_divergence_rad": b[1], "subrays": b[2]} for b in beams],
              "layers": h.layers, "radius_m": float(pf.radius), "min_points": int(pf.min_points),
              "min_spread_m": float(pf.min_spread), "bins": h.bins, "range_noise_m": [float(v) for v in noise_used],
              "zenith_groups": int(dc.zenith_groups), "leaf_size_m": float(dc.leaf_size), "samples": int(dc.samples),
              "max_simulated": int(dc.max_simulated), "iterations": int(dc.iterations), "cap": float(pf.cap),
              "second_leaf": bool(dc.second_leaf), "seed": int(dc.seed), "settings": s.to_dict()}
    return LeafAngleMeasurement(layers=per_layer, crown=crown, method=method, params=params)


def check_settings(s: LeafAngleSettings):
    """Refuse settings out of their range; ``(method, beam, crown_center)`` parsed."""
    from voxlidar.leaf_orientation import LeafAzimuth

    h, pf, ins, dc = s.histogram, s.planes, s.instrument, s.deconvolution
    method = LeafAngleMethod.parse(h.method, "method")
    radius, cap = pf.radius, pf.cap
    if not (isinstance(radius, int | float) and np.isfinite(radius) and radius > 0):
        raise InputError(f"radius={radius!r} must be a positive number of metres (leaf scale, e.g. 0.025)")
    if not isinstance(pf.min_points, int | np.integer) or int(pf.min_points) < 3:
        raise InputError(f"min_points={pf.min_points!r} must be >= 3 (a plane needs three points)")
    if not (isinstance(cap, int | float) and np.isfinite(cap) and 0 < cap < 1):
        raise InputError(f"cap={cap!r} must lie in (0, 1): the smallest |cos| between a leaf normal and its beam "
                         "(e.g. 0.2)")
    azimuth = str(dc.azimuth).lower()
    if azimuth not in ("auto", LeafAzimuth.UNIFORM.value, LeafAzimuth.OUTWARD.value):
        raise InputError(f"azimuth={dc.azimuth!r} is not known; choose one of: auto, uniform, outward")
    for name, value, least in (("layers", h.layers, 1), ("zenith_groups", dc.zenith_groups, 1),
                               ("samples", dc.samples, 1), ("max_simulated", dc.max_simulated, 1),
                               ("iterations", dc.iterations, 1), ("bins", h.bins, 2)):
        if not isinstance(value, int | np.integer) or isinstance(value, bool) or value < least:
            raise InputError(f"{name}={value!r} must be an integer >= {least}")
    beam = ins.beam
    if beam is not None:
        try:
            raw = tuple(beam)
            beam = (float(raw[0]), float(raw[1]), float(raw[2]))
            ok = len(raw) == 3 and 0 <= beam[0] < 0.1 and 0 <= beam[1] < 10 and beam[2] in (1, 7, 19, 37)
        except (TypeError, ValueError, IndexError):
            ok = False
        if not ok:
            raise InputError(f"beam={ins.beam!r} must be (exit diameter m < 0.1, full divergence mrad < 10, "
                             "sub-rays 1, 7, 19 or 37), e.g. (0.007, 0.35, 7) for the RIEGL VZ-400")
        beam = (beam[0], beam[1], int(beam[2]))
    crown_center = None
    if dc.crown_center is not None:
        try:
            crown_center = np.asarray(dc.crown_center, float).reshape(-1)
        except (TypeError, ValueError):
            crown_center = np.array([np.nan])
        if crown_center.shape != (2,) or not np.isfinite(crown_center).all():
            raise InputError(f"crown_center={dc.crown_center!r} must be (x, y) in metres, world frame, e.g. "
                             "(0.4, -0.2)")
    if ins.angular_step is not None:
        try:
            st = np.asarray(ins.angular_step, float).reshape(-1)
        except (TypeError, ValueError):
            st = np.array([np.nan])
        if st.size not in (1, 2) or not (np.isfinite(st).all() and (st > 0).all()):
            raise InputError(f"angular_step={ins.angular_step!r} must be one or two positive angles in degrees "
                             "(zenith, azimuth), e.g. 0.06")
    return method, beam, crown_center


def scan_poses(scans) -> list:
    """Each scan's world-from-scanner pose (its registered one, else a simulated scan's true one)."""
    poses = []
    for s in scans:
        pose = s.pose if s.pose is not None else s.pose_true
        if pose is None:
            raise InputError(f"scan {s.name!r} has no pose: register it (tlsvox register) first")
        poses.append(np.asarray(pose, float))
    return poses


def crown_centre(scans, poses, method, azimuth, crown_center):
    """The outward model's crown axis: ``(centre or None, where it came from, the azimuth models used)``."""
    from tlsvox.classify import PointClass
    from voxlidar.materials import Material

    azimuth = str(azimuth).lower()
    centre, centre_from = None, "none"
    if crown_center is not None:
        centre = crown_center
        centre_from = "given"
    elif method is LeafAngleMethod.DECONVOLVE and azimuth != "uniform":
        wood = [s.world_xyz(p)[m] for s, p in zip(scans, poses)
                if (m := _class_mask(s, Material.BARK, PointClass.WOOD)) is not None]
        centre, _ = trunk_center(np.concatenate(wood) if wood else np.zeros((0, 3)))
        centre_from = "trunk" if centre is not None else "no trunk found in the wood echoes"
    if azimuth == "outward" and centre is None and method is LeafAngleMethod.DECONVOLVE:
        raise InputError("azimuth='outward' needs the crown centre: pass crown_center=(x, y) or scans with wood "
                         "echoes at the trunk's base (classify them first)")
    models = {"auto": ("uniform", "outward"), "uniform": ("uniform",), "outward": ("outward",)}[azimuth]
    if centre is None:
        models = ("uniform",)
    return centre, centre_from, models


def fit_scans(scans, poses, s: LeafAngleSettings, method, beam, centre, n_azimuth, leaf):
    """The plane fits of each scan's leaf echoes, with the instrument each was scanned by:
    ``(fits, range noise, angular steps (rad), beams, names)`` of the scans used (a scan with fewer leaf
    echoes than a fit needs is left out)."""
    pf, ins = s.planes, s.instrument
    fits, noise_used, steps, beams, used = [], [], [], [], []
    for i, (scan, pose) in enumerate(zip(scans, poses)):
        mask = _leaf_mask(scan) if leaf is None else np.asarray(leaf[i], bool)
        if mask.shape != (len(scan),):
            raise InputError(f"leaf[{i}] has shape {mask.shape}; scan {scan.name!r} has {len(scan)} echoes")
        sigma = ins.range_noise
        if sigma is None:
            sigma = float(scan.meta.get("preset", {}).get("range_noise_m", 0.005))
        step = ins.angular_step
        if step is None and scan.pulses is not None and scan.pulses.grid is not None:
            step = (scan.pulses.grid.zenith_step_deg, scan.pulses.grid.azimuth_step_deg)
        if step is None and "zenith_step_deg" in scan.meta.get("preset", {}):
            step = (scan.meta["preset"]["zenith_step_deg"], scan.meta["preset"]["azimuth_step_deg"])
        if step is None and method is LeafAngleMethod.DECONVOLVE:
            raise InputError(f"scan {scan.name!r} has no angular grid: pass angular_step= (degrees, e.g. 0.06 for "
                             "the RIEGL VZ-400) or use method='weighted'")
        step = np.radians(np.broadcast_to(np.asarray(step if step is not None else 0.06, float), (2,)))
        xyz = scan.world_xyz(pose)[mask]
        if len(xyz) < pf.min_points:
            continue
        fits.append(_fit_scan(xyz, pose[:3, 3], radius=pf.radius, min_points=int(pf.min_points),
                              min_spread=float(pf.min_spread), n_bins=s.histogram.bins, cap=pf.cap, centre=centre,
                              n_azimuth=n_azimuth))
        noise_used.append(sigma)
        used.append(scan.name)
        steps.append(tuple(step))
        beams.append(_scan_beam(scan) if beam is None else (0.5 * beam[0], 0.5e-3 * beam[1], int(beam[2])))
    return fits, noise_used, steps, beams, used


def deconvolution_rows(fits, cuts, s: LeafAngleSettings, steps, beams, noise_used, models, n_azimuth, rng) -> list:
    """The simulated measurement of every scan and crown layer: rows ``(layer, scan, histogram, kernel)``."""
    pf, dc, bins = s.planes, s.deconvolution, s.histogram.bins
    rows = []
    for i, f in enumerate(fits):
        for k in range(len(cuts) - 1):
            rows += [(k, i, h, K) for h, K in _layer_rows(
                f, _in_layer(f.z, cuts, k), n_bins=bins, n_groups=int(dc.zenith_groups),
                max_sim=int(dc.max_simulated), rng=rng, step=steps[i], beam=beams[i], leaf_size=float(dc.leaf_size),
                radius=pf.radius, min_points=int(pf.min_points), min_spread=float(pf.min_spread),
                range_noise=noise_used[i], samples=int(dc.samples), cap=pf.cap, second_leaf=bool(dc.second_leaf),
                azimuths=models, n_azimuth=n_azimuth)]
    return rows


def choose_azimuth(rows, n_scans, n_layers, models, iterations):
    """Each layer's azimuth model: with both, the one with the larger share when both are fitted together.
    Returns ``(shares, chosen, rows)``, the rows' kernels cut to their layer's model."""
    shares, chosen = [None] * n_layers, [0 if len(models) == 1 else None for _ in range(n_layers)]
    if len(models) > 1:
        for k in range(n_layers):
            sel = [(i, h, K) for k_, i, h, K in rows if k_ == k]
            if sel:
                shares[k] = _em([(0, i, 0, h, K) for i, h, K in sel], (1, n_scans, 1), int(iterations))[2][0]
                chosen[k] = int(np.argmax(shares[k]))
        rows = [(k, i, h, K[chosen[k]:chosen[k] + 1]) for k, i, h, K in rows]  # a layer with rows has a choice
    return shares, chosen, rows


def layer_result(fits, rows, ks, z_range, cuts, method, bins, iterations, mixes) -> LayerLeafAngles:
    """The distribution of the layers ``ks`` together (one distribution; an occlusion mix per scan and layer,
    written into ``mixes`` for a single layer)."""
    edges = np.linspace(0.0, HALF_PI, bins + 1)
    masks = [np.logical_or.reduce([_in_layer(f.z, cuts, k) for k in ks]) for f in fits]
    if method is LeafAngleMethod.WEIGHTED:
        p = _weighted(fits, masks, bins)
    else:
        sel = [(k, i, h, K) for k, i, h, K in rows if k in ks]
        p = np.zeros(bins)
        if sel:
            p, mix, _ = _em([(0, i * len(ks) + list(ks).index(k), 0, h, K) for k, i, h, K in sel],
                            (1, len(fits) * len(ks), 1), int(iterations))
            p = p[0]
            if len(ks) == 1:
                for i in range(len(fits)):
                    if any(i_ == i for _, i_, _, _ in sel):
                        mixes[i][ks[0]] = mix[i]
    n = int(sum((m & f.ok).sum() for f, m in zip(fits, masks)))
    th = np.concatenate([f.theta[m & f.ok] for f, m in zip(fits, masks)])
    zr = np.percentile(th, [5, 95]) if len(th) else np.array([np.nan, np.nan])
    la = fit_beta(p, edges) if n and p.sum() > 0 else LeafAngle("uniform")
    return LayerLeafAngles(z_range=np.asarray(z_range, float), edges=edges, density=p / np.diff(edges),
                           n_echoes=n, zenith_range=zr, leaf_angle=la)
