"""The NumPy oracle's geometry: directions, normals, scattering, field of view.

Float64 twins of the small functions of ``kernels/geometry.cl`` and
``kernels/transport.cl`` (cosine-weighted directions, wood normals and
extinction parts, the bi-Lambertian next event, the receiver's field of
view, the lattice of first free paths), vectorised over rows of photons.
They serve :mod:`clsim.transport.reference` and the mesh reference
(:mod:`clsim.validation.meshref`).

>>> m = np.array([[0.0, 0.0, 1.0]])
>>> cosine_dir(m, np.array([0.0]), np.array([0.0])).tolist()   # u1 = 0: along the normal
[[0.0, 0.0, 1.0]]
"""

from __future__ import annotations

import numpy as np

__all__ = ["beam_directions", "cosine_dir", "in_fov", "lattice_unit", "leaf_avg_f", "receiver_view",
           "row_dot", "wood_majorant", "wood_normal", "wood_parts"]


def _onb(n):
    s = np.where(n[:, 2] >= 0, 1.0, -1.0)  # copysign(1, z); -0.0 -> +1 here, never hit in practice
    a = -1.0 / (s + n[:, 2])
    b = n[:, 0] * n[:, 1] * a
    b1 = np.column_stack([1.0 + s * n[:, 0] ** 2 * a, s * b, -s * n[:, 0]])
    b2 = np.column_stack([b, s + n[:, 1] ** 2 * a, -n[:, 1]])
    return b1, b2


def cosine_dir(m, u1, u2):
    """Cosine-weighted unit directions about unit normals m (n, 3)."""
    b1, b2 = _onb(m)
    r, ph = np.sqrt(u1), 2.0 * np.pi * u2
    v = (r * np.cos(ph))[:, None] * b1 + (r * np.sin(ph))[:, None] * b2 \
        + np.sqrt(np.maximum(0.0, 1.0 - u1))[:, None] * m
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def wood_parts(q, sw, d):
    """Directional wood extinction along unit ``d`` (n, 3): (cylinder part, random-facet part).

    ``q`` (n, 4) holds ``(bark axis, beta)`` per row, or is None (no directions:
    the parts are ``(0, sw)``); ``sw`` (n,) is the direction-averaged extinction.
    The kernel's ``wood_parts`` (docs/method.md, directional wood)."""
    if q is None:
        return np.zeros_like(sw), sw
    c = row_dot(q[:, :3], d)
    sin_psi = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    solid = q[:, 3] < 0  # solid wood (w = -1 - cap share): opaque, all on the surface model
    return (np.where(solid, sw, sw * q[:, 3] * (4.0 / np.pi) * sin_psi),
            np.where(solid, 0.0, sw * (1.0 - q[:, 3])))


def wood_majorant(q, sw):
    """Largest wood extinction over directions, ``sw (beta 4 / pi + 1 - beta)`` (kernel ``wood_majorant``)."""
    if q is None:
        return sw
    return np.where(q[:, 3] < 0, sw, sw * q[:, 3] * (4.0 / np.pi) + sw * (1.0 - q[:, 3]))


def wood_normal(q, d, cyl, u1, u2):
    """Normals of wood elements hit from ``d``, facing ``-d``, weighted by ``|n . d|``.

    Rows with ``cyl`` lie on the cylinder part, perpendicular to the bark axis
    (``n = -cos(phi) u + sin(phi) a x u``, ``sin(phi) = 2 u1 - 1``); the rest are
    random facets, cosine-weighted about ``-d`` (kernel ``wood_normal``).  Solid
    wood (``q[:, 3] = -1 - cap``): an end cap (``n = -sign(a . d) a``) when
    ``u2 (end + side) < end``, ``end = cap |a . d|``, ``side = (1 - cap) sin(psi) / pi``
    (their projected areas), else the side as above."""
    n = cosine_dir(-d, u1, u2)
    if q is None or not np.any(cyl):
        return n
    a = q[:, :3]
    ca = row_dot(a, d)
    p = d - a * ca[:, None]
    l2 = row_dot(p, p)
    cap = np.where(q[:, 3] < 0, -1.0 - q[:, 3], 0.0)
    end = cap * np.abs(ca)
    side = (1.0 - cap) * np.sqrt(l2) / np.pi
    on_cap = cyl & (q[:, 3] < 0) & (u2 * (end + side) < end)
    n[on_cap] = np.where((ca[on_cap] > 0)[:, None], -a[on_cap], a[on_cap])
    use = cyl & ~on_cap & (l2 > 1e-12)
    if use.any():
        u = p[use] / np.sqrt(l2[use])[:, None]
        s = 2.0 * u1[use] - 1.0
        c = np.sqrt(np.maximum(0.0, 1.0 - s * s))
        n[use] = s[:, None] * np.cross(a[use], u) - c[:, None] * u
    return n


def row_dot(a, b):
    """Row-wise dot products of two (n, 3) arrays."""
    return np.einsum("ij,ij->i", a, b)


def receiver_view(sensor, axis, tan2_fov, x, m, R, T):
    """Next-event geometry of scattering points ``x`` (n, 3) with incident-side normals ``m``.

    Returns ``(r, drx, cosr, c, f, ok)``: distance to the receiver, unit direction to it,
    that direction's cosine on the beam axis, ``m . drx``, the bi-Lambertian BSDF value
    towards the receiver, and the mask of points that scatter towards a receiver that
    sees them (``f > 0`` and inside the field of view)."""
    to = sensor - x
    r = np.linalg.norm(to, axis=1)
    drx = to / r[:, None]
    cosr = -row_dot(drx, np.broadcast_to(axis, drx.shape))
    c = row_dot(m, drx)
    f = np.where(c > 0, R * c / np.pi, -T * c / np.pi)
    ok = (f > 0) & in_fov(-to, axis, tan2_fov)
    return r, drx, cosr, c, f, ok


def leaf_avg_f(d, w, R, T):
    """Next-event weight (1/sr) of a leaf event averaged over the leaf normals of a spherical
    leaf-angle distribution with uniform azimuths, incoming unit ``d``, outgoing unit ``w``
    (rows): Ross's area scattering phase function over pi G (G = 1/2); docs/method.md.

    >>> z = np.array([[0.0, 0.0, 1.0]])
    >>> bool(np.isclose(leaf_avg_f(-z, z, 0.437, 0.478)[0], 2 * 0.437 / (3 * np.pi)))
    True
    """
    c = np.clip(row_dot(d, w), -1.0, 1.0)
    beta = np.arccos(c)
    return ((R + T) * (np.sqrt(1.0 - c * c) - beta * c) / (3.0 * np.pi) + T * c / 3.0) * (2.0 / np.pi)


def lattice_unit(shift, pid, step):
    """Coordinate of photons ``pid`` on the seed-shifted Kronecker lattice, as the kernel's
    uniform in (0, 1): ((shift + pid step) mod 2^32 >> 9 + 1/2) 2^-23."""
    x = (np.uint64(shift) + (np.asarray(pid, np.uint64) & np.uint64(0xFFFFFFFF)) * np.uint64(step)) \
        & np.uint64(0xFFFFFFFF)
    return ((x >> np.uint64(9)).astype(np.float64) + 0.5) * 2.0**-23


def in_fov(v, axis, tan2_fov):
    """Rows of v (sensor -> point) inside the field of view around unit ``axis``.

    Tested on the offset from the axis, as the kernel does (a cosine near 1
    is too coarse in float32)."""
    along = v @ axis
    off = v - along[:, None] * axis
    return (along > 0) & (row_dot(off, off) <= tan2_fov * along**2)


def beam_directions(axis, e1, e2, sigma, u_r, u_phi):
    """Unit directions of a Gaussian beam about unit ``axis`` (rows of uniforms ``u_r``, ``u_phi``).

    Box-Muller: the offset ``sigma sqrt(-2 ln u_r)`` (per-axis angular standard
    deviation ``sigma``, radians) at angle ``2 pi u_phi`` in the plane of the
    unit vectors ``e1``, ``e2`` across the axis; the kernel's first direction."""
    rr = sigma * np.sqrt(-2.0 * np.log(u_r))
    ph = 2.0 * np.pi * u_phi
    d = axis + (rr * np.cos(ph))[:, None] * e1 + (rr * np.sin(ph))[:, None] * e2
    return d / np.linalg.norm(d, axis=1, keepdims=True)
