"""Beams from scans: every pulse, with its echoes, in the world frame.

A scan written by tlsvox carries a pulse table (every pulse fired, also those
with no echo).  A real scan exported as points only has lost its empty pulses
and the link between echoes and pulses; :func:`group_pulses` and
:func:`reconstruct_empty_pulses` bring them back:

1. Echoes are grouped into pulses: a ``return_number == 1`` echo starts a
   pulse; a later echo joins a first echo nearer to the scanner on the same
   ray (direction within ``tolerance_deg``, same echo count preferred).
2. The first echoes' directions are turned into the scanner's own frame
   (SOCS: zenith and azimuth of its mirror and head) with the scan's
   roll/pitch/yaw.  Each vertical scan line is found on the azimuth lattice,
   after removing the line's common curvature (the continuous head rotation
   and mirror geometry bend every line the same way; the curvature is
   measured from the data as the circular mean azimuth phase per zenith
   degree).  Along each line, gaps between consecutive pulses of more than
   one zenith step, and the line's ends up to the grid's zenith limits, are
   filled with empty pulses at the zenith step.

Empty pulses reconstructed this way are followed to ``max_range`` (default:
the largest echo range in the scan), because a file cut to a plot does not
say whether a pulse that left no echo in it went to the sky or hit something
outside.

Echo classes become :class:`~tlsvox.voxel.trace.EchoKind`: leaf echoes are the
LAD estimators' events, wood echoes the wood estimators', ground and targets
stop the beam, noise is dropped (and does not count in the pulse's ``n``).
How much of its beam each echo stops follows the rule of
:mod:`tlsvox.voxel.weights` (``1/n``, the intercepted fraction, or the
paper's reflectance threshold).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tlsvox.errors import InputError
from tlsvox.scan import AngularGrid, Scan
from tlsvox.voxel.trace import Beams, EchoKind
from tlsvox.voxel.weights import EchoWeights, NominalReflectance, below_threshold, echo_fractions, resolve_rule

__all__ = ["PulseGroups", "beams_from_scan", "g_table", "group_pulses", "kinds_from_material",
           "kinds_from_pointclass", "reconstruct_empty_pulses", "rotation_from_rpy"]


def kinds_from_material(material) -> np.ndarray:
    """EchoKind per echo from :class:`voxlidar.materials.Material` ids (truth)."""
    m = np.asarray(material, dtype=np.int64)
    lut = np.array([EchoKind.IGNORE, EchoKind.LEAF, EchoKind.WOOD, EchoKind.OTHER, EchoKind.OTHER],
                   dtype=np.uint8)
    if m.size and (m.min() < 0 or m.max() >= len(lut)):
        raise InputError(f"material ids must lie in 0..{len(lut) - 1} (voxlidar.materials.Material); "
                         f"got {m.min()}..{m.max()}")
    return lut[m]


def kinds_from_pointclass(labels) -> np.ndarray:
    """EchoKind per echo from :class:`tlsvox.classify.PointClass` labels."""
    from tlsvox.classify import PointClass

    lab = np.asarray(labels, dtype=np.int64)
    out = np.full(lab.shape, EchoKind.IGNORE, dtype=np.uint8)
    out[lab == PointClass.LEAF] = EchoKind.LEAF
    out[lab == PointClass.WOOD] = EchoKind.WOOD
    out[(lab == PointClass.GROUND) | (lab == PointClass.TARGET)] = EchoKind.OTHER
    known = np.isin(lab, [int(c) for c in PointClass])
    if not np.all(known):
        raise InputError(f"labels hold codes that are not PointClass values: "
                         f"{np.unique(lab[~known])[:10].tolist()}")
    return out


def rotation_from_rpy(roll_deg: float, pitch_deg: float, yaw_deg: float) -> np.ndarray:
    """Rotation ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (3, 3): scan frame from SOCS.

    RIEGL's convention for the scanner's inclination and heading.  For the
    rTLS VZ-400i scan it maps the SOCS zenith limit 30 deg onto the data's
    smallest zenith exactly.
    """
    r, p, y = np.deg2rad([roll_deg, pitch_deg, yaw_deg])
    rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return rz @ ry @ rx


@dataclass
class PulseGroups:
    """Echoes grouped into pulses (scanner frame).

    Attributes
    ----------
    pulse_of_echo : (N,) int64
        Pulse row of every echo.
    direction : (P, 3) float64
        Unit direction of each pulse.
    n_nominal : (P,) int64
        Echo count the scanner reported for the pulse (number_of_returns).
    orphans : int
        Later echoes whose first echo was not in the file (they start a pulse).
    """

    pulse_of_echo: np.ndarray
    direction: np.ndarray
    n_nominal: np.ndarray
    orphans: int = 0


def group_pulses(scan: Scan, *, tolerance_deg: float = 0.05) -> PulseGroups:
    """Group a scan's echoes into pulses (see the module docstring).

    Uses ``scan.pulse_id`` when present; otherwise return numbers and ray
    directions.  ``tolerance_deg`` is the largest angle between an echo and
    the first echo of its pulse: coordinates stored to 1 mm scatter a later
    echo's direction by up to ~0.03 deg at a few metres (measured on the
    VZ-400i scan); among candidates, a first echo nearer the scanner with the
    same echo count wins.
    """
    from scipy.spatial import cKDTree

    origin = scan.pulses.origin if scan.pulses is not None else np.zeros(3)
    v = scan.xyz - origin
    r = np.linalg.norm(v, axis=1)
    if np.any(r <= 0):
        raise InputError(f"scan {scan.name!r}: {int(np.sum(r <= 0))} echoes sit at the scanner origin")
    u = v / r[:, None]
    n = len(scan)
    if scan.pulse_id is not None:
        ids, inverse = np.unique(scan.pulse_id, return_inverse=True)
        first = np.full(len(ids), -1)
        order = np.lexsort((r, inverse))
        first[inverse[order][::-1]] = order[::-1]
        nn = np.zeros(len(ids), np.int64)
        np.maximum.at(nn, inverse, scan.number_of_returns.astype(np.int64))
        return PulseGroups(inverse.astype(np.int64), u[first], np.maximum(nn, 1))
    rn = scan.return_number.astype(np.int64)
    nr = scan.number_of_returns.astype(np.int64)
    is_first = rn <= 1
    first_idx = np.nonzero(is_first)[0]
    pulse = np.full(n, -1, np.int64)
    pulse[first_idx] = np.arange(len(first_idx))
    later = np.nonzero(~is_first)[0]
    orphans = 0
    if len(later):
        tree = cKDTree(u[first_idx])
        tol = 2 * np.sin(np.deg2rad(tolerance_deg) / 2)
        dist, nb = tree.query(u[later], k=4, distance_upper_bound=tol)
        ok = np.isfinite(dist)
        cand = np.where(ok, first_idx[np.minimum(nb, len(first_idx) - 1)], -1)
        # a first echo nearer to the scanner than the later one, same echo count preferred
        valid = ok & (r[np.maximum(cand, 0)] < r[later][:, None])
        same_n = valid & (nr[np.maximum(cand, 0)] == nr[later][:, None])
        pick = np.where(same_n.any(axis=1), np.argmax(same_n, axis=1), np.argmax(valid, axis=1))
        has = valid.any(axis=1)
        rows = np.arange(len(later))
        pulse[later[has]] = pulse[cand[rows[has], pick[has]]]
        orph = later[~has]
        orphans = len(orph)
        pulse[orph] = len(first_idx) + np.arange(orphans)
        starts = np.concatenate([first_idx, orph])
    else:
        starts = first_idx
    n_nom = np.zeros(len(starts), np.int64)
    np.maximum.at(n_nom, pulse, nr)
    return PulseGroups(pulse, u[starts], np.maximum(n_nom, 1), orphans)


@dataclass
class Reconstruction:
    """Empty pulses rebuilt on a scan's angular grid, and how well it fitted."""

    direction: np.ndarray  #: (Q, 3) scan frame
    n_lines: int
    azimuth_step_deg: float  #: refined from the data
    line_fit: float  #: fraction of first echoes within a quarter step of their line
    pulses_total: int  #: returned + reconstructed
    pulses_expected: int  #: grid.n_pulses
    meta: dict = field(default_factory=dict)


def _circular_phase(x, step):
    c = np.exp(2j * np.pi * x / step)
    return c


def reconstruct_empty_pulses(directions, grid: AngularGrid, *, socs_rotation=None,
                             refine_step: bool = True) -> Reconstruction:
    """Directions of the pulses a scan fired but that left no echo.

    Parameters
    ----------
    directions : (P, 3) float
        Unit directions of the pulses that did return (scan frame).
    grid : AngularGrid
        The scan's zenith/azimuth grid in SOCS (degrees).
    socs_rotation : (3, 3) float, optional
        Scan frame from SOCS (:func:`rotation_from_rpy`); identity if None.
    refine_step : bool
        Refine the azimuth step from the data within +-1% of the nominal.

    Returns
    -------
    Reconstruction
        The empty pulses' directions (scan frame) and how well the grid fitted
        the returned ones.
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    if len(d) < 100:
        raise InputError(f"only {len(d)} returned pulses: too few to find the scan lines of the grid")
    rot = np.eye(3) if socs_rotation is None else np.asarray(socs_rotation, dtype=np.float64)
    if rot.shape != (3, 3) or not np.allclose(rot @ rot.T, np.eye(3), atol=1e-6):
        raise InputError("socs_rotation must be a 3x3 rotation matrix (see rotation_from_rpy)")
    s = d @ rot  # SOCS = R^T d
    zen = np.degrees(np.arccos(np.clip(s[:, 2], -1, 1)))
    az = np.degrees(np.arctan2(s[:, 1], s[:, 0])) % 360.0
    dz = float(grid.zenith_step_deg)
    step = float(grid.azimuth_step_deg)
    z_lo = float(grid.zenith_start_deg)
    z_hi = z_lo + dz * (int(grid.n_zenith) - 1)
    sub = np.random.default_rng(0).choice(len(d), size=min(len(d), 50000), replace=False)
    zbin = np.floor(zen - z_lo).astype(np.int64)
    nb = max(int(np.ceil(z_hi - z_lo)) + 1, 1)
    zbin = np.clip(zbin, 0, nb - 1)

    def concentration(stp):
        c = _circular_phase(az[sub], stp)
        sums = np.bincount(zbin[sub], weights=c.real, minlength=nb) + 1j * np.bincount(
            zbin[sub], weights=c.imag, minlength=nb)
        return np.abs(sums).sum() / len(sub)

    if refine_step:
        cands = step * np.linspace(0.99, 1.01, 201)
        step = float(cands[int(np.argmax([concentration(c) for c in cands]))])
    c = _circular_phase(az, step)
    re = np.bincount(zbin, weights=c.real, minlength=nb)
    im = np.bincount(zbin, weights=c.imag, minlength=nb)
    cnt = np.bincount(zbin, minlength=nb)
    good = cnt >= 20
    if good.sum() < 2:
        raise InputError("the returned pulses cover too little of the zenith range to find scan lines")
    centres = z_lo + np.arange(nb) + 0.5
    phase = np.unwrap(np.angle(re[good] + 1j * im[good])) / (2 * np.pi) * step
    shape_at = np.interp(zen, centres[good], phase)
    u = (az - shape_at) / step
    j = np.round(u).astype(np.int64)
    resid = u - j
    line_fit = float(np.mean(np.abs(resid) < 0.25))
    # per-line offset (head rotation is not perfectly uniform)
    j0 = j.min()
    jj = j - j0
    n_lines = int(jj.max()) + 1
    off = np.bincount(jj, weights=resid, minlength=n_lines) / np.maximum(np.bincount(jj, minlength=n_lines), 1)
    # gaps along each line, with virtual pulses one step beyond both zenith limits
    order = np.lexsort((zen, jj))
    lines = np.arange(n_lines)
    all_j = np.concatenate([jj[order], lines, lines])
    all_z = np.concatenate([zen[order], np.full(n_lines, z_lo - dz), np.full(n_lines, z_hi + dz)])
    o2 = np.lexsort((all_z, all_j))
    all_j, all_z = all_j[o2], all_z[o2]
    same = all_j[1:] == all_j[:-1]
    gap = np.diff(all_z)
    k = np.where(same, np.maximum(np.round(gap / dz).astype(np.int64) - 1, 0), 0)
    total_new = int(k.sum())
    gi = np.repeat(np.arange(len(k)), k)
    m = np.arange(total_new) - np.repeat(np.cumsum(k) - k, k) + 1
    new_z = all_z[gi] + gap[gi] * m / (k[gi] + 1)
    new_j = all_j[gi]
    new_z = np.clip(new_z, z_lo, z_hi)
    new_az = (new_j + j0 + off[new_j]) * step + np.interp(new_z, centres[good], phase)
    zr, ar = np.deg2rad(new_z), np.deg2rad(new_az)
    socs = np.column_stack([np.sin(zr) * np.cos(ar), np.sin(zr) * np.sin(ar), np.cos(zr)])
    out = socs @ rot.T
    return Reconstruction(direction=out, n_lines=n_lines, azimuth_step_deg=step, line_fit=line_fit,
                          pulses_total=len(d) + total_new, pulses_expected=grid.n_pulses,
                          meta={"zenith_range_deg": [z_lo, z_hi]})


def g_table(leaf_angle, theta, *, nodes: int = 4097) -> np.ndarray:
    """G(theta) for many beams by linear interpolation in a table over [0, pi].

    G is smooth (Lipschitz at worst, for single-angle leaves), so 4097 nodes
    keep the error under 1e-6 while the work and memory stay independent of
    the number of beams.
    """
    grid = np.linspace(0.0, np.pi, nodes)
    return np.interp(theta, grid, leaf_angle.G(grid))


def outward_g_table(leaf_angle, *, n_theta: int = 181, n_c: int = 129, nodes: int = 2048) -> np.ndarray:
    """G of outward-facing leaves: (n_theta, n_c) over beam zenith [0, pi] x c in [-1, 1].

    A leaf whose normal has inclination theta_L and the azimuth of its
    outward direction from the crown axis (``leaf_azimuth="outward"``)
    projects ``|sin theta_L sin theta c + cos theta_L cos theta|`` of its area
    on a beam of zenith theta, c being the cosine of the angle between the
    beam's horizontal direction and that outward direction.  Averaged over
    the leaf inclinations (``nodes`` quantiles of the model), this is G for
    that beam in that part of the crown; averaged over c uniform in angle it
    is the model's usual G(theta).

    Examples
    --------
    >>> from voxlidar.leaf_orientation import LeafAngle
    >>> t = outward_g_table(LeafAngle("horizontal"), n_theta=3, n_c=3)   # flat leaves: |cos theta|
    >>> np.round(t, 6).tolist()
    [[1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]
    """
    tl = np.asarray(leaf_angle.ppf((np.arange(nodes) + 0.5) / nodes), dtype=np.float64)
    theta = np.linspace(0.0, np.pi, n_theta)
    c = np.linspace(-1.0, 1.0, n_c)
    sin_l, cos_l = np.sin(tl), np.cos(tl)
    out = np.empty((n_theta, n_c))
    for i, th in enumerate(theta):
        out[i] = np.abs(np.outer(c * np.sin(th), sin_l) + np.cos(th) * cos_l).mean(axis=1)
    return out


def layer_g_tables(models, *, outward: bool, n_theta: int | None = None, n_c: int = 129) -> np.ndarray:
    """One G table per crown layer, (layers, n_theta, n_c + 1), as the tracer reads them (``g_layer``).

    Each row (a beam zenith in [0, pi]) holds G at ``n_c`` cosines c in
    [-1, 1] (``outward``: :func:`outward_g_table` of the layer's model, 181
    zenith rows by default; else the model's usual G(theta), the same in two
    columns, 2049 rows) and then the model's azimuth-averaged G(theta), which
    the tracer reads where c is undefined (a vertical beam, a voxel on the
    crown axis), as the one-table mode reads each beam's own G there.

    Examples
    --------
    >>> from voxlidar.leaf_orientation import LeafAngle
    >>> t = layer_g_tables([LeafAngle("horizontal"), LeafAngle("vertical")], outward=False, n_theta=3)
    >>> np.round(t[:, 1, :], 6).tolist()   # a horizontal beam: flat leaves 0, upright ones 2/pi
    [[0.0, 0.0, 0.0], [0.63662, 0.63662, 0.63662]]
    """
    models = list(models)
    rows = int(n_theta if n_theta is not None else (181 if outward else 2049))
    theta = np.linspace(0.0, np.pi, rows)
    out = []
    for m in models:
        g = np.asarray(m.G(theta), dtype=np.float64)[:, None]
        table = outward_g_table(m, n_theta=rows, n_c=n_c) if outward else np.repeat(g, 2, axis=1)
        out.append(np.concatenate([table, g], axis=1))
    return np.stack(out)


def beams_from_scan(scan: Scan, *, kinds=None, pose=None, leaf_angle=None, max_range: float | None = None,
                    angular_grid: AngularGrid | None = None, socs_rotation=None,
                    reconstruct: bool = True, echo_weights="auto",
                    leaf_reflectance: float | None = None,
                    wood_reflectance: float | None = None,
                    leaf_shape: tuple = (0.05, 0.025), lad_field=None) -> tuple[Beams, dict]:
    """Every pulse of ``scan`` as world-frame :class:`~tlsvox.voxel.trace.Beams`.

    Parameters
    ----------
    scan : Scan
    kinds : (N,) uint8, optional
        EchoKind per echo (:func:`kinds_from_pointclass`,
        :func:`kinds_from_material`); default: the scan's ``truth_material``,
        else every echo a leaf (plant area, not leaf area).
    pose : (4, 4) float, optional
        World-from-scanner; default ``scan.pose`` (required).
    leaf_angle : LeafAngle, optional
        Sets each beam's ``g = G(theta)`` (world zenith); default g = 1.
    max_range : float, metres, optional
        How far empty pulses (and missing echoes' tails) are followed: default
        infinity with a pulse table, the scan's largest echo range without.
    angular_grid : AngularGrid, optional
        Grid to rebuild empty pulses on when the scan has no pulse table
        (default: ``scan.pulses.grid`` if any).
    socs_rotation : (3, 3), optional
        Scan frame from the scanner's own frame (:func:`rotation_from_rpy`).
    reconstruct : bool
        False: use only pulses that returned (biased: no gaps!).
    echo_weights : {"uniform", "fraction", "threshold", "geometric", "auto"}
        How echoes share their pulse (:class:`~tlsvox.voxel.weights.EchoWeights`):
        ``1/n``, the intercepted fraction of the beam (``beam_fraction``
        column, else reflectance), the paper's threshold, or the expected
        share from the beam's footprint (:mod:`tlsvox.voxel.footprint`); ``auto``
        (default): fraction when the scan has a ``beam_fraction`` column,
        else uniform.  ``info["echo_weights"]`` says which was used.
    leaf_reflectance, wood_reflectance : float, optional
        Nominal reflectance of a full hit at normal incidence for the
        ``fraction`` (from reflectance) and ``threshold`` rules; default the
        :mod:`voxlidar.materials` optics at the scanner's wavelength.
    leaf_shape : (float, float), metres
        Leaf length and width of the ``geometric`` rule's footprint model.
    lad_field : tlsvox.voxel.footprint.LadField, optional
        The ``geometric`` rule's leaf area density (an estimate made with
        other weights); without it the rule's first pass gives ``1/n``.

    Returns
    -------
    beams : Beams
    info : dict
        Counts (pulses, echoes, empty, reconstructed) and the fit diagnostics.
    """
    if not isinstance(scan, Scan):
        raise InputError(f"scan must be a tlsvox Scan, got {type(scan).__name__}")
    pose = scan.pose if pose is None else np.asarray(pose, dtype=np.float64)
    if pose is None:
        raise InputError(
            f"scan {scan.name!r} has no pose (world-from-scanner 4x4): register the scans first "
            "(tlsvox register), or for a single scan use its own frame (pose=np.eye(4), CLI "
            "--scanner-frame)"
        )
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise InputError(f"pose must be a finite 4x4 matrix, got shape {pose.shape}")
    n = len(scan)
    if kinds is None:
        if scan.truth_material is not None:
            kinds = kinds_from_material(scan.truth_material)
        else:
            kinds = np.full(n, EchoKind.LEAF, np.uint8)
    kinds = np.asarray(kinds, dtype=np.uint8).reshape(-1)
    if len(kinds) != n:
        raise InputError(f"kinds has {len(kinds)} values for the {n} echoes of scan {scan.name!r}")
    rule = resolve_rule(echo_weights, scan)
    info: dict = {"scan": scan.name, "echoes": n, "echo_weights": rule.value}
    nominal = None
    if rule is EchoWeights.THRESHOLD or (rule is EchoWeights.FRACTION and not (
            scan.beam_fraction is not None and np.any(np.isfinite(scan.beam_fraction)))):
        nominal = NominalReflectance.for_scan(scan, leaf_reflectance, wood_reflectance)
    if rule is EchoWeights.THRESHOLD:
        low = below_threshold(scan, kinds, nominal)
        kinds = np.where(low, np.uint8(EchoKind.IGNORE), kinds)
        info.update(echo_weights_source=f"dropped leaf/wood echoes under 50 % of the nominal leaf reflectance "
                    f"{nominal.leaf:g} ({nominal.source})", below_threshold=int(low.sum()))
    origin_s = scan.pulses.origin if scan.pulses is not None else np.zeros(3)
    ranges = np.linalg.norm(scan.xyz - origin_s, axis=1)

    if scan.pulses is not None and scan.pulse_id is not None:
        table = scan.pulses
        pid = scan.pulse_id
        if n and (pid.min() < 0 or pid.max() >= len(table)):
            raise InputError(f"scan {scan.name!r}: pulse_id outside its pulse table of {len(table)} rows")
        dirs = table.direction.astype(np.float64)
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        n_nom = np.maximum(table.n_echoes.astype(np.int64), 1)
        np.maximum.at(n_nom, pid, scan.number_of_returns.astype(np.int64))
        pulse = pid
        mr = np.inf if max_range is None else float(max_range)
        info["source"] = "pulse table"
    else:
        groups = group_pulses(scan)
        pulse, dirs, n_nom = groups.pulse_of_echo, groups.direction, groups.n_nominal
        info.update(source="grouped echoes", orphans=groups.orphans)
        mr = (float(ranges.max()) if n else 0.0) if max_range is None else float(max_range)
        grid = angular_grid if angular_grid is not None else (scan.pulses.grid if scan.pulses else None)
        if reconstruct:
            if grid is None:
                raise InputError(
                    f"scan {scan.name!r} has no pulse table and no angular grid: its empty pulses "
                    "cannot be rebuilt. Pass angular_grid=AngularGrid(...) (CLI --angular-grid) "
                    "or reconstruct=False (biased: every voxel looks full)"
                )
            rec = reconstruct_empty_pulses(dirs, grid, socs_rotation=socs_rotation)
            info.update(reconstructed=len(rec.direction), lines=rec.n_lines,
                        azimuth_step_deg=rec.azimuth_step_deg, line_fit=rec.line_fit,
                        pulses_expected=rec.pulses_expected)
            dirs = np.vstack([dirs, rec.direction])
            n_nom = np.concatenate([n_nom, np.zeros(len(rec.direction), np.int64)])
    p = len(dirs)
    # drop noise echoes; they do not count in the pulse's n either
    keep = kinds != EchoKind.IGNORE
    noise = np.bincount(pulse[~keep], minlength=p)
    n_eff = np.maximum(n_nom - noise, 1)
    pulse_k, rng_k, kind_k = pulse[keep], ranges[keep], kinds[keep]
    order = np.lexsort((rng_k, pulse_k))
    pulse_k, rng_k, kind_k = pulse_k[order], rng_k[order], kind_k[order]
    counts = np.bincount(pulse_k, minlength=p)
    start = np.concatenate([[0], np.cumsum(counts)])
    rot, trans = pose[:3, :3], pose[:3, 3]
    world_dirs = dirs @ rot.T
    world_dirs /= np.linalg.norm(world_dirs, axis=1, keepdims=True)
    if rule is EchoWeights.FRACTION:
        theta = np.arccos(np.clip(world_dirs[pulse, 2], -1, 1))
        frac, info["echo_weights_source"] = echo_fractions(scan, kinds, theta, leaf_angle=leaf_angle,
                                                           nominal=nominal)
        w = _fraction_weights(frac[keep][order], pulse_k, p)
    elif rule is EchoWeights.GEOMETRIC and lad_field is not None:
        from tlsvox.voxel.footprint import FootprintModel, footprint_fractions

        veg = (kind_k == EchoKind.LEAF) | (kind_k == EchoKind.WOOD)
        at = float(np.median(rng_k[veg])) if veg.any() else 10.0
        model = FootprintModel.for_scan(scan, at, leaf_length=leaf_shape[0], leaf_width=leaf_shape[1],
                                        leaf_reflectance=leaf_reflectance)
        frac, meta = footprint_fractions(pulse_k, rng_k, kind_k, rot @ origin_s + trans, world_dirs, model, lad_field,
                                         leaf_angle=leaf_angle if leaf_angle is not None else "uniform")
        w = _fraction_weights(frac, pulse_k, p)
        info["echo_weights_source"] = (f"the beam's footprint ({model.n_subrays} sub-rays, radius "
                                       f"{1000 * model.beam_radius:.1f} mm at {at:.1f} m; leaves "
                                       f"{100 * leaf_shape[0]:g} x {100 * leaf_shape[1]:g} cm) through the "
                                       "estimated leaf area density")
        info["echo_weights_model"] = meta
    else:
        w = 1.0 / n_eff[pulse_k]
        # more echoes present than announced: renormalise so the weights sum to 1
        over = counts > n_eff
        if np.any(over):
            w = np.where(over[pulse_k], 1.0 / counts[pulse_k], w)
        info.setdefault("echo_weights_source", "1/n, n the pulse's echo count")
    wsum = np.bincount(pulse_k, weights=w, minlength=p)
    tail = np.clip(1.0 - wsum, 0.0, 1.0)
    tail[tail < 1e-9] = 0.0
    max_r = np.full(p, mr)
    last = np.zeros(p)
    np.maximum.at(last, pulse_k, rng_k)
    max_r = np.maximum(max_r, last)
    origin_w = rot @ origin_s + trans
    g = None
    if leaf_angle is not None:
        g = np.maximum(g_table(leaf_angle, np.arccos(np.clip(world_dirs[:, 2], -1, 1))), 1e-6)
    info.update(pulses=p, empty=int(np.count_nonzero(counts == 0)), max_range=mr,
                noise_dropped=int((~keep).sum()))
    beams = Beams(origin=np.broadcast_to(origin_w, (p, 3)), direction=world_dirs, echo_start=start,
                  echo_range=rng_k, echo_weight=w, echo_kind=kind_k, tail=tail, max_range=max_r, g=g,
                  scan_index=np.full(p, scan.scan_id, np.int16))
    return beams, info


def _fraction_weights(frac, pulse, p: int) -> np.ndarray:
    """Echo weights from intercepted shares (NaN = unknown), pulse by pulse.

    ``frac`` and ``pulse`` are sorted by pulse, then range.  Echoes without a
    share (ground and targets when the shares come from reflectance, NaN in a
    ``beam_fraction`` column) take equal parts of what the others left.  When
    the shares of a pulse add up to more than 1, the nearer echoes keep theirs
    and a farther one takes only what is left (the beam meets them in order).
    """
    known = np.isfinite(frac)
    f = np.where(known, np.clip(frac, 0.0, 1.0), 0.0)
    used = np.bincount(pulse, weights=f, minlength=p)
    n_unknown = np.bincount(pulse, weights=(~known).astype(np.float64), minlength=p)
    rest = np.clip(1.0 - used, 0.0, 1.0) / np.maximum(n_unknown, 1.0)
    w = np.where(known, f, rest[pulse])
    # cap the running total of each pulse at 1, in range order
    cum = np.cumsum(w)
    first = np.searchsorted(pulse, pulse, side="left")  # row of each pulse's first echo
    before = np.concatenate([[0.0], cum])[first]
    within = np.minimum(cum - before, 1.0)
    prev = np.concatenate([[0.0], within[:-1]])
    prev[np.arange(len(w)) == first] = 0.0
    return np.clip(within - prev, 0.0, 1.0)
