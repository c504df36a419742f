"""A simple quantitative structure model: cylinders fitted to the wood echoes.

The TLS pipeline's wood is otherwise the stretched count of wood echoes per
voxel (:mod:`tlsvox.voxel.wood`), a turbid medium: the scans see a trunk's
near side, so a trunk becomes a shell of bark voxels around empty ones, which
an airborne beam passes through, and its bark scatters as random facets.
Here the wood echoes are grouped into branch pieces and a cylinder is fitted
to each; well-supported cylinders then fill solid wood voxels
(:func:`apply_cylinders`) with the machinery the truth's twin uses
(:mod:`tlsvox.voxel.wood.solid`: flat-ended cylinders, the cap share from the
cylinders' surface, the fitted cylinder's turbid bark beside its core
dropped).  Wood echoes no cylinder explains stay turbid wood.  Leaf-classed
echoes on a fitted cylinder's bark (:func:`bark_echoes`) are bark the
classifier missed: the pipeline relabels them wood before it voxelises.

The steps (:func:`fit_cylinders`):

1. thin the wood echoes to one point per ``spacing`` cell (their mean);
2. link points closer than ``link`` into a graph; in each connected part,
   the geodesic distance from its lowest point (Dijkstra);
3. cut the geodesic distance into slices ``slice_length`` long; the
   connected parts of each slice are its clusters, each joined to the
   cluster of the slice below that it shares the most links with;
4. follow the cluster tree from each root, always into the child with the
   most points beneath it (the stem, then the main branches, each a chain);
   cut each chain into pieces of ``piece_length``;
5. fit a cylinder to each piece by robust least squares (soft-L1 on the
   distance to the axis minus the radius, with scale ``noise``), started from
   the direction between the piece's first and last cluster and an algebraic
   circle fit across it; its ends are the extreme inliers along the axis;
6. keep a cylinder only when at least ``min_points`` points lie within
   ``max(3 sigma, noise)`` of its surface (sigma: the residuals' robust
   spread), they cover at least ``min_coverage_deg`` of its circumference,
   sigma is at most ``noise`` and ``max_residual`` of its radius (a piece
   across a fork, or a clump of leaves taken for wood, fits worse), and it
   is no shorter than half a slice;
7. a chain's last cylinder runs on along its axis over the points on its
   surface beyond it, up to a gap of ``max_gap``.

The segmentation by geodesic slices follows the idea of TreeQSM (Raumonen
et al. 2013) in a much simpler form (no cover sets, no taper model); the
circle that starts each fit is Kasa's (1976).

References
----------
Raumonen, P. et al. (2013). Fast automatic precision tree models from
    terrestrial laser scanner data. Remote Sensing 5(2), 491-520.
    doi:10.3390/rs5020491
Kasa, I. (1976). A circle fitting procedure and its error analysis. IEEE
    Transactions on Instrumentation and Measurement 25(1), 8-14.
    doi:10.1109/TIM.1976.6312298

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> phi, z = rng.uniform(0, np.pi, 3000), rng.uniform(0, 2, 3000)   # the half of a trunk a scanner sees
>>> pts = np.column_stack([0.2 * np.cos(phi), 0.2 * np.sin(phi), z]) + rng.normal(0, 0.003, (3000, 3))
>>> m = fit_cylinders(pts)
>>> bool(abs(m.cylinders[:, 6] - 0.2).max() < 0.01), bool(np.all(np.abs(m.cylinders[:, [0, 1, 3, 4]]) < 0.01))
(True, True)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError

__all__ = ["CylinderModel", "fit_cylinders", "apply_cylinders", "bark_echoes", "wood_points"]


@dataclass
class CylinderModel:
    """Cylinders fitted to wood echoes, and how well each is supported.

    Attributes
    ----------
    cylinders : (C, 7) float64
        Start (3), end (3), radius, metres; kept cylinders only (the base end first).
    support : (C,) int
        Thinned points within the inlier band of each.
    sigma : (C,) float64, m
        Robust spread of those points' distance to the surface (1.4826 MAD).
    coverage_deg : (C,) float64
        Share of the circumference the inliers cover, degrees (10 degree sectors).
    chain : (C,) int
        The chain (stem or branch) each piece belongs to.
    tried : int
        Pieces fitted, kept or not.
    """

    cylinders: np.ndarray
    support: np.ndarray
    sigma: np.ndarray
    coverage_deg: np.ndarray
    chain: np.ndarray
    tried: int = 0

    def __len__(self) -> int:
        return len(self.cylinders)

    def explained(self, points, *, tolerance: float | None = None) -> np.ndarray:
        """(N,) bool: points within ``tolerance`` (default ``max(3 sigma, 2 cm)`` of each
        cylinder) of a cylinder's surface, or inside it, between its ends (plus the tolerance)."""
        return self.owner(points, tolerance=tolerance) >= 0

    def owner(self, points, *, tolerance: float | None = None, surface: bool = False,
              floor: float = 0.02) -> np.ndarray:
        """(N,) int: the first cylinder that explains each point (:meth:`explained`), -1 for none.

        The default tolerance is each cylinder's ``max(3 sigma, floor)``.  With
        ``surface``, only points within the tolerance of the side (not inside) count."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.full(len(p), -1, np.int64)
        if not len(p) or not len(self):
            return out
        order = np.argsort(p[:, 0], kind="stable")  # each cylinder's box is a slice of the points sorted by x
        px = p[order, 0]
        for i, (c, s) in enumerate(zip(self.cylinders, self.sigma)):
            tol = max(3.0 * s, floor) if tolerance is None else float(tolerance)
            a, b, r = c[:3], c[3:6], c[6]
            reach = r + tol
            pad = reach + tol  # a point tol beyond an end and reach off the axis lies within this of the end
            lo, hi = np.minimum(a, b) - pad, np.maximum(a, b) + pad
            idx = order[np.searchsorted(px, lo[0], "left"):np.searchsorted(px, hi[0], "right")]
            q = p[idx]
            idx = idx[np.all((q[:, 1:] >= lo[1:]) & (q[:, 1:] <= hi[1:]), axis=1) & (out[idx] < 0)]
            if not len(idx):
                continue
            length = np.linalg.norm(b - a)
            u = (b - a) / length
            x = p[idx] - a
            t = x @ u
            radial = np.linalg.norm(x - t[:, None] * u, axis=1)
            hit = (t > -tol) & (t < length + tol) & (radial < reach)
            if surface:
                hit &= radial > r - tol
            out[idx[hit]] = i
        return out

    def summary(self) -> dict:
        r = self.cylinders[:, 6] if len(self) else np.zeros(0)
        length = np.linalg.norm(self.cylinders[:, 3:6] - self.cylinders[:, :3], axis=1) if len(self) else r
        return {"cylinders": int(len(self)), "tried": int(self.tried), "chains": int(len(np.unique(self.chain))),
                "length_m": round(float(length.sum()), 3),
                "volume_m3": round(float((np.pi * r**2 * length).sum()), 4),
                "radius_m": [round(float(r.min()), 4), round(float(r.max()), 4)] if len(r) else []}


def _thin(points, spacing):
    key = np.floor(points / spacing).astype(np.int64)
    _, inv, cnt = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    mean = np.column_stack([np.bincount(inv, weights=points[:, k], minlength=len(cnt)) for k in range(3)])
    return mean / cnt[:, None]


def _circle(xy):
    """Algebraic (Kasa) circle fit: centre (2,), radius."""
    A = np.column_stack([2 * xy, np.ones(len(xy))])
    sol, *_ = np.linalg.lstsq(A, (xy**2).sum(axis=1), rcond=None)
    return sol[:2], float(np.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 1e-12)))


def _fit_piece(q, u0, noise):
    """Robust cylinder through points ``q`` started along ``u0``: (centre, axis, radius) or None."""
    from scipy.optimize import least_squares

    from tlsvox.truth._mesh import orthonormal

    u0 = u0 / np.linalg.norm(u0)
    e1, e2 = (v[0] for v in orthonormal(u0[None]))
    c0 = q.mean(axis=0)
    xy = np.column_stack([(q - c0) @ e1, (q - c0) @ e2])
    centre, r0 = _circle(xy)
    p0 = np.array([centre[0], centre[1], 0.0, 0.0, r0])

    def frame(p):
        u = u0 + p[2] * e1 + p[3] * e2
        return c0 + p[0] * e1 + p[1] * e2, u / np.linalg.norm(u)

    def resid(p):
        c, u = frame(p)
        x = q - c
        return np.linalg.norm(x - (x @ u)[:, None] * u, axis=1) - p[4]

    try:
        sol = least_squares(resid, p0, loss="soft_l1", f_scale=noise, max_nfev=60)
    except (ValueError, np.linalg.LinAlgError):
        return None
    if not np.all(np.isfinite(sol.x)) or sol.x[4] <= 0:
        return None
    c, u = frame(sol.x)
    return c, u, float(sol.x[4]), resid(sol.x)


def fit_cylinders(points, *, spacing: float = 0.02, link: float = 0.06, slice_length: float = 0.2,
                  piece_length: float = 0.6, noise: float = 0.01, min_points: int = 30,
                  min_coverage_deg: float = 90.0, max_residual: float = 0.15,
                  max_radius: float = 2.0, max_gap: float = 0.3) -> CylinderModel:
    """Fit cylinders to wood echoes (world frame, metres); see the module's steps.

    Parameters
    ----------
    points : (N, 3) float
        Wood echoes.
    spacing : float, m
        Thinning cell.
    link : float, m
        Points closer than this are neighbours (occlusion gaps longer than
        this split a branch into parts fitted apart).
    slice_length, piece_length : float, m
        Geodesic slice and the length of the pieces a chain is cut into.
    noise : float, m
        Scale of the robust loss and the least inlier band (range noise,
        registration error, bark roughness).
    min_points, min_coverage_deg, max_residual, max_radius
        What a kept cylinder needs: its residuals' robust spread at most
        ``noise`` and at most ``max_residual`` of its radius.
    max_gap : float, m
        A chain's last cylinder runs on along its axis over the points on its
        surface beyond it (the thinner, less seen top of a stem, cut off from
        the chain by occlusion gaps) until a gap longer than this.

    Returns
    -------
    CylinderModel
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components, dijkstra
    from scipy.spatial import cKDTree

    from tlsvox.truth._mesh import orthonormal

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    for name, v in (("spacing", spacing), ("link", link), ("slice_length", slice_length),
                    ("piece_length", piece_length), ("noise", noise), ("max_radius", max_radius)):
        if not (np.isfinite(v) and v > 0):
            raise InputError(f"fit_cylinders: {name}={v!r} must be a number > 0 (metres)")
    if link <= spacing:
        raise InputError(f"fit_cylinders: link={link!r} must exceed spacing={spacing!r}, or no thinned points link")
    empty = CylinderModel(np.zeros((0, 7)), np.zeros(0, int), np.zeros(0), np.zeros(0), np.zeros(0, int))
    if len(p) < min_points or not np.all(np.isfinite(p)):
        if len(p) and not np.all(np.isfinite(p)):
            raise InputError("fit_cylinders: the wood points hold NaN or inf")
        return empty
    pts = _thin(p, spacing)
    n = len(pts)
    pairs = cKDTree(pts).query_pairs(link, output_type="ndarray")
    if not len(pairs):
        return empty
    w = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1) + 1e-9
    graph = coo_matrix((w, (pairs[:, 0], pairs[:, 1])), shape=(n, n)).tocsr()
    _, part = connected_components(graph, directed=False)
    order = np.lexsort((pts[:, 2], part))
    first = np.ones(n, bool)
    first[1:] = part[order[1:]] != part[order[:-1]]
    roots = order[first]  # the lowest point of each connected part
    dist = dijkstra(graph, directed=False, indices=roots, min_only=True)
    sl = np.floor(dist / slice_length).astype(np.int64)

    # clusters: the connected parts of each slice
    same = sl[pairs[:, 0]] == sl[pairs[:, 1]]
    sp = pairs[same]
    n_cl, cl = connected_components(coo_matrix((np.ones(len(sp)), (sp[:, 0], sp[:, 1])), shape=(n, n)),
                                    directed=False)
    cl_slice = np.zeros(n_cl, np.int64)
    cl_slice[cl] = sl
    size = np.bincount(cl, minlength=n_cl)
    # parents: the cluster one slice down sharing the most links
    up = sl[pairs[:, 1]] - sl[pairs[:, 0]]
    lo_hi = np.concatenate([pairs[up == 1], pairs[up == -1][:, ::-1]])
    parent = np.full(n_cl, -1)
    if len(lo_hi):
        link_pairs, counts = np.unique(np.column_stack([cl[lo_hi[:, 1]], cl[lo_hi[:, 0]]]), axis=0,
                                       return_counts=True)
        best = np.lexsort((-counts, link_pairs[:, 0]))
        lp = link_pairs[best]
        keep = np.ones(len(lp), bool)
        keep[1:] = lp[1:, 0] != lp[:-1, 0]
        parent[lp[keep, 0]] = lp[keep, 1]
    # points beneath each cluster, children in order of slice (deepest first)
    beneath = size.astype(np.int64).copy()
    for c in np.argsort(-cl_slice, kind="stable"):
        if parent[c] >= 0:
            beneath[parent[c]] += beneath[c]
    main = np.full(n_cl, -1)
    for c in np.flatnonzero(parent >= 0):
        pc = parent[c]
        if main[pc] < 0 or beneath[c] > beneath[main[pc]]:
            main[pc] = c
    heads = [c for c in range(n_cl) if parent[c] < 0 or main[parent[c]] != c]
    members = np.split(np.argsort(cl, kind="stable"), np.cumsum(size)[:-1])
    centroid = np.array([pts[m].mean(axis=0) for m in members])

    per_piece = max(1, int(round(piece_length / slice_length)))
    rows, support, sigma, cover, chain_of = [], [], [], [], []
    tried = 0
    for k, head in enumerate(heads):
        chain = [head]
        while main[chain[-1]] >= 0:
            chain.append(main[chain[-1]])
        if sum(size[c] for c in chain) < min_points:
            continue
        cuts = list(range(0, len(chain), per_piece))
        if len(cuts) > 1 and len(chain) - cuts[-1] < (per_piece + 1) // 2:
            cuts.pop()  # a short tail joins the piece before it
        for j, s in enumerate(cuts):
            piece = chain[s:cuts[j + 1] if j + 1 < len(cuts) else len(chain)]
            q = pts[np.concatenate([members[c] for c in piece])]
            if len(q) < min_points:
                continue
            # direction: across the piece's clusters (a one-cluster piece: across its neighbours in the chain)
            a_i, b_i = (s, s + len(piece) - 1) if len(piece) >= 2 else (max(s - 1, 0), min(s + 1, len(chain) - 1))
            u0 = centroid[chain[b_i]] - centroid[chain[a_i]]
            if np.linalg.norm(u0) < 0.25 * slice_length:  # no span to go by: the points' main axis
                u0 = np.linalg.eigh(np.cov((q - q.mean(axis=0)).T))[1][:, -1]
                if u0 @ (centroid[chain[-1]] - centroid[chain[0]]) < 0:
                    u0 = -u0
            tried += 1
            fit = _fit_piece(q, u0, noise)
            if fit is None:
                continue
            c, u, r, res = fit
            if u @ u0 < 0:
                u = -u
            mad = 1.4826 * np.median(np.abs(res - np.median(res)))
            inl = np.abs(res) < max(3.0 * mad, noise)
            x = q[inl] - c
            t = x @ u
            e1, e2 = (v[0] for v in orthonormal(u[None]))
            ang = np.arctan2(x @ e2, x @ e1)
            coverage = 10.0 * len(np.unique(np.floor((ang + np.pi) / np.deg2rad(10.0)).astype(int) % 36))
            length = float(t.max() - t.min()) if inl.any() else 0.0
            ok = (inl.sum() >= min_points and coverage >= min_coverage_deg and mad <= min(noise, max_residual * r)
                  and r <= max_radius and length >= 0.5 * slice_length)
            if not ok:
                continue
            t_lo, t_hi = t.min(), t.max()
            if main[piece[-1]] < 0:  # the chain's tip: on along the axis while points lie on the surface
                x = pts - c
                ta = x @ u
                band = np.abs(np.linalg.norm(x - ta[:, None] * u, axis=1) - r) < max(3.0 * mad, noise)
                beyond = np.sort(ta[band & (ta > t_hi)])
                gaps = np.diff(np.r_[t_hi, beyond])
                stop = np.flatnonzero(gaps > max_gap)
                if len(beyond):
                    t_hi = beyond[stop[0] - 1] if len(stop) and stop[0] > 0 else (t_hi if len(stop) else beyond[-1])
            rows.append(np.r_[c + t_lo * u, c + t_hi * u, r])
            support.append(int(inl.sum()))
            sigma.append(float(mad))
            cover.append(coverage)
            chain_of.append(k)
    if not rows:
        empty.tried = tried
        return empty
    return CylinderModel(np.array(rows), np.array(support), np.array(sigma), np.array(cover, float),
                         np.array(chain_of), tried)


def apply_cylinders(scene, model: CylinderModel, wood_points=None, *, min_radius: float | None = None):
    """The scene with solid wood voxels filled from ``model``'s cylinders.

    Every voxel whose centre lies inside a cylinder becomes solid wood
    (``Scene.wood_solid``: opaque, scattering off the cylinder's side or end
    caps, the cap share from the cylinders' own surface around it, as
    :meth:`~tlsvox.truth.synthetic.SyntheticTree.truth_scene` does).  In the
    voxels beside a solid one (its 26 neighbours) the turbid wood is scaled by
    the share of the voxel's wood echoes (``wood_points``) no cylinder
    explains: the fitted cylinder's bark is its core there, not a second
    medium.  Without ``wood_points`` that turbid wood is left as it is.
    Cylinders thinner than ``min_radius`` (default half a voxel: no voxel
    centre can lie inside) are skipped.

    Returns
    -------
    (Scene, dict)
        The new scene (the input is not changed; ``meta["qsm"]`` holds the
        model's summary and the dict) and what was done: ``cylinders_filling``
        (those of at least ``min_radius``), ``solid_voxels``, ``new_voxels``
        (solid voxels the scene did not store before), ``turbid_scaled``
        (voxels whose turbid wood was scaled down), ``wood_echoes_explained``
        (share of ``wood_points`` on or in a cylinder).
    """
    import dataclasses

    from tlsvox.truth.meshtruth import normal_moments_per_voxel
    from tlsvox.voxel.wood.solid import cap_share, cylinder_cells, cylinder_surface

    h = float(scene.voxel_size)
    shape = tuple(int(v) for v in scene.shape)
    origin = np.asarray(scene.origin, dtype=np.float64)
    cyl = model.cylinders
    min_radius = 0.5 * h if min_radius is None else float(min_radius)
    use = cyl[:, 6] >= min_radius
    cyl = cyl[use]
    info = {"cylinders_filling": int(len(cyl)), "solid_voxels": 0, "new_voxels": 0, "turbid_scaled": 0,
            "wood_echoes_explained": None}
    if not len(cyl):
        return scene, info
    flat, axis, owner = cylinder_cells(cyl, origin=origin, voxel_size=h, shape=shape)
    if not len(flat):
        return scene, info
    # a cylinder's end is open where another cylinder holds the point just beyond it (stacked pieces)
    a, b, r = cyl[:, :3], cyl[:, 3:6], cyl[:, 6]
    u = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    step = 0.5 * np.minimum(r, h)

    def covered(pt, skip):
        x = pt - a
        t = np.einsum("ij,ij->i", x, u)
        radial = np.linalg.norm(x - t[:, None] * u, axis=1)
        inside = (t >= 0) & (t <= np.linalg.norm(b - a, axis=1)) & (radial < r)
        inside[skip] = False
        return inside.any()

    open_start = np.array([covered(a[i] - step[i] * u[i], i) for i in range(len(cyl))])
    open_end = np.array([covered(b[i] + step[i] * u[i], i) for i in range(len(cyl))])
    tris = cylinder_surface(cyl, caps_start=~open_start, caps_end=~open_end)
    sf, sa, sm = normal_moments_per_voxel(tris, origin=origin, voxel_size=h, shape=shape)
    cap = cap_share(flat, axis, sf, sa, sm, shape)

    keys = np.ravel_multi_index(scene.ijk.T, shape)
    order = np.argsort(keys)
    skeys = keys[order]
    pos = np.searchsorted(skeys, flat)
    pos_c = np.minimum(pos, max(len(skeys) - 1, 0))
    found = (pos < len(skeys)) & (skeys[pos_c] == flat) if len(skeys) else np.zeros(len(flat), bool)
    rows_old = order[pos_c[found]]
    new = flat[~found]
    m0, m1 = len(keys), len(new)
    solid_kind_value = 1.0 - 1e-6

    def grow(v, fill):
        v = np.asarray(v)
        return np.concatenate([v, np.full((m1,) + v.shape[1:], fill, dtype=v.dtype)])

    ijk = np.vstack([scene.ijk, np.column_stack(np.unravel_index(new, shape))]).astype(scene.ijk.dtype)
    lad = grow(scene.lad, 0.0)
    wood = grow(scene.wood, 0.0).astype(np.float64)
    wood_axis = grow(scene.wood_axis, 0.0)
    wood_axis[m0:] = [0.0, 0.0, 1.0]
    wood_beta = grow(scene.wood_beta, 0.0)
    wood_solid = grow(scene.wood_solid, False)
    wood_cap = grow(scene.wood_cap, 0.0)
    occluded = grow(scene.occluded, False) if scene.occluded is not None else None
    lad_std = grow(scene.lad_std, 0.0) if scene.lad_std is not None else None
    rows = np.concatenate([rows_old, m0 + np.arange(m1)])
    sel = np.concatenate([np.flatnonzero(found), np.flatnonzero(~found)])
    wood_solid[rows] = True
    wood[rows] = solid_kind_value if scene.wood_kind == "probability" else max(float(np.max(wood, initial=0.0)), 1.0)
    wood_axis[rows] = axis[sel]
    wood_beta[rows] = 0.0
    wood_cap[rows] = cap[sel]
    if occluded is not None:
        occluded[rows] = False
    # the cylinders' bark beside their cores: turbid wood scaled by the unexplained share of its echoes
    if wood_points is not None:
        wp = np.asarray(wood_points, dtype=np.float64).reshape(-1, 3)
        wijk = np.floor((wp - origin) / h).astype(np.int64)
        ok = np.all((wijk >= 0) & (wijk < np.asarray(shape)), axis=1)
        wflat = np.ravel_multi_index(wijk[ok].T, shape)
        expl = CylinderModel(cyl, model.support[use], model.sigma[use], model.coverage_deg[use],
                             model.chain[use]).explained(wp[ok])
        info["wood_echoes_explained"] = round(float(expl.mean()), 4) if len(expl) else 0.0
        allk = np.ravel_multi_index(ijk.T, shape)
        cand = np.flatnonzero(~wood_solid & (wood > 0))
        cand = cand[_beside(ijk[cand], flat, shape)]
        if len(cand):
            uk, inv = np.unique(wflat, return_inverse=True)
            tot = np.bincount(inv, minlength=len(uk))
            un = np.bincount(inv, weights=(~expl).astype(float), minlength=len(uk))
            p = np.searchsorted(uk, allk[cand])
            pc = np.minimum(p, max(len(uk) - 1, 0))
            hit = (p < len(uk)) & (uk[pc] == allk[cand]) if len(uk) else np.zeros(len(cand), bool)
            share = np.ones(len(cand))
            share[hit] = un[pc[hit]] / tot[pc[hit]]
            wood[cand] *= share
            info["turbid_scaled"] = int((share < 1).sum())
    info.update(solid_voxels=int(len(flat)), new_voxels=int(m1))
    meta = dict(scene.meta or {})
    meta["qsm"] = {**model.summary(), **info}
    out = dataclasses.replace(scene, ijk=ijk, lad=lad, wood=wood, wood_axis=wood_axis, wood_beta=wood_beta,
                              wood_solid=wood_solid, wood_cap=wood_cap, occluded=occluded, lad_std=lad_std,
                              meta=meta)
    return out, info


def _beside(ijk, flat, shape) -> np.ndarray:
    """(K,) bool: which voxels ``ijk`` have one of their 26 neighbours among ``flat`` (sorted flat indices).

    Looked up per voxel, so nothing of the grid's size is made (a 2 cm grid has 10^8 voxels).
    """
    out = np.zeros(len(ijk), bool)
    if not len(flat) or not len(ijk):
        return out
    shape_a = np.asarray(shape)
    for off in np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3):
        if not off.any():
            continue
        nb = ijk + off
        ok = np.all((nb >= 0) & (nb < shape_a), axis=1)
        keys = np.ravel_multi_index(nb[ok].T, tuple(shape))
        pos = np.minimum(np.searchsorted(flat, keys), len(flat) - 1)
        out[np.flatnonzero(ok)[flat[pos] == keys]] = True
    return out


#: :func:`bark_echoes`: the least half-width of a cylinder's bark band, m.  A fit's sigma is the spread of
#: the thinned points (each the mean of the echoes in a 2 cm cell), less than one echo's; 1 cm is about
#: 3 sigma of a TLS range (3-5 mm precision and accuracy for the VZ-400 class of scanners)
BARK_FLOOR = 0.01


def bark_echoes(scans, model: CylinderModel, classes=None, *, class_codes: str = "pointclass",
                tolerance: float | None = None) -> list:
    """Per scan, (N_s,) bool: echoes classed as leaf that lie on a fitted cylinder's bark.

    A leaf-classed echo within ``tolerance`` of a cylinder's side (default
    each cylinder's ``max(3 sigma, BARK_FLOOR)``; not inside it: an oversized
    piece across a fork would take the leaves in it) is bark the leaf/wood
    classifier missed (dark, wet or foreshortened bark reads like leaves in
    reflectance): a cylinder fitted to hundreds of wood echoes says where the
    bark is better than one echo's reflectance.  Only cylinders whose band
    holds at least as many of the scans' wood echoes as leaf echoes relabel:
    the classifier agrees with them on most of their surface; one with more
    leaf than wood echoes on it runs through foliage and its leaves stay
    leaves.  Leaves within the band of a trusted branch are taken with it
    (docs/bench/relabel.md measures how often against the truth).

    Parameters
    ----------
    scans : sequence of tlsvox.scan.Scan
        Registered scans (``pose``), as given to ``voxelize``.
    model : CylinderModel
        Cylinders fitted to the same scans' wood echoes (:func:`fit_cylinders`).
    classes, class_codes
        As :func:`tlsvox.voxel.stages.voxelize`'s: one label array per scan,
        default each scan's own classification, else its truth material.
    tolerance : float, optional
        Half-width of the bark band, m (default per cylinder, above).

    Returns
    -------
    list of (N_s,) bool
        Per scan, its leaf-classed echoes on a trusted cylinder's bark.

    Examples
    --------
    >>> from tlsvox.scan import PulseTable, Scan
    >>> m = CylinderModel(np.array([[0, 0, 0, 0, 0, 2, 0.1]]), np.array([100]), np.array([0.002]),
    ...                   np.array([180.0]), np.array([0]))
    >>> xyz = np.array([[0.1, 0, 1], [0.1, 0, 1.2], [0.105, 0, 0.5], [0.2, 0, 1]])  # bark x 3, 10 cm off
    >>> scan = Scan(xyz=xyz, pulse_id=np.arange(4), pose=np.eye(4),
    ...             pulses=PulseTable(xyz / np.linalg.norm(xyz, axis=1, keepdims=True), np.ones(4, int)))
    >>> from tlsvox.classify import PointClass
    >>> labels = np.array([PointClass.WOOD, PointClass.WOOD, PointClass.LEAF, PointClass.LEAF], np.uint8)
    >>> bark_echoes([scan], m, [labels])[0].tolist()
    [False, False, True, False]
    """
    from tlsvox.voxel.stages import _kinds_for
    from tlsvox.voxel.trace import EchoKind

    scans = list(scans)
    classes = [None] * len(scans) if classes is None else list(classes)
    if len(classes) != len(scans):
        raise InputError(f"classes holds {len(classes)} label arrays for {len(scans)} scans; pass one per scan")
    n = len(model)
    if n == 0:  # nothing fitted (too few wood echoes): nothing to relabel
        return [np.zeros(len(s), bool) for s in scans]
    leaf_owner, n_leaf, n_wood = [], np.zeros(n, np.int64), np.zeros(n, np.int64)
    for s, c in zip(scans, classes):
        kind = _kinds_for(s, c, class_codes)
        owner = np.full(len(kind), -1, np.int64)
        if n and len(kind):
            xyz = s.world_xyz(s.pose if s.pose is not None else np.eye(4))
            sel = (kind == EchoKind.LEAF) | (kind == EchoKind.WOOD)
            owner[sel] = model.owner(xyz[sel], tolerance=tolerance, surface=True, floor=BARK_FLOOR)
            on = owner >= 0
            n_leaf += np.bincount(owner[on & (kind == EchoKind.LEAF)], minlength=n)
            n_wood += np.bincount(owner[on & (kind == EchoKind.WOOD)], minlength=n)
            owner[kind != EchoKind.LEAF] = -1
        leaf_owner.append(owner)
    trusted = n_wood >= n_leaf
    return [(o >= 0) & trusted[np.maximum(o, 0)] for o in leaf_owner]


def wood_points(scans, classes=None, *, class_codes: str = "pointclass") -> np.ndarray:
    """(N, 3) world positions of the scans' wood echoes, classed as :func:`tlsvox.voxel.stages.voxelize` does.

    ``classes`` as ``voxelize``'s (default each scan's ``classification``, else
    its ``truth_material``); a scan without a pose is taken in its own frame.
    """
    from tlsvox.voxel.stages import _kinds_for
    from tlsvox.voxel.trace import EchoKind

    scans = list(scans)
    classes = [None] * len(scans) if classes is None else list(classes)
    out = [np.zeros((0, 3))]
    for s, c in zip(scans, classes):
        k = _kinds_for(s, c, class_codes)
        wood = k == EchoKind.WOOD
        if wood.any():
            out.append(s.world_xyz(s.pose if s.pose is not None else np.eye(4))[wood])
    return np.vstack(out)
