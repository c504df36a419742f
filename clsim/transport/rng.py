"""Counter-based random numbers: Philox4x32-10, bit-identical to the kernels.

Every photon owns a stream keyed by ``(seed, photon id)``: block ``c`` of
photon ``p`` is ``philox4x32_10(counter=(c, p_lo, p_hi, 0), key=(s_lo, s_hi))``
and yields four uniforms.  Work-group size, device and launch order do not
change the numbers, and the NumPy oracle (:mod:`clsim.transport.reference`) replays
any photon of a kernel run.  The kernel twin lives in ``kernels/philox.cl``.

Uniforms are ``((x >> 9) + 0.5) * 2**-23``: 23 bits plus a half, in the open
interval (0, 1) and exactly representable in float32 (24-bit significand), so
the device and the oracle see the same values.  (With 24 bits, as before,
every value above 1/2 needed 25 bits: float32 rounded it, and the largest
became exactly 1.)

References
----------
Salmon, J. K., Moraes, M. A., Dror, R. O. & Shaw, D. E. (2011). Parallel
    random numbers: as easy as 1, 2, 3. SC'11. doi:10.1145/2063384.2063405

Examples
--------
>>> [hex(v) for v in philox4x32_10((0, 0, 0, 0), (0, 0))]
['0x6627e8d5', '0xe169c58d', '0xbc57ac4c', '0x9b00dbd8']
>>> u = uniforms(np.array([0, 1]), np.array([0, 0]), seed=7)
>>> u.shape, bool(np.all((u > 0) & (u < 1)))
((2, 4), True)
"""

from __future__ import annotations

import numpy as np

from clsim.errors import InputError

__all__ = ["check_seed", "philox4x32_10", "uniforms", "split_seed"]

_M0 = np.uint64(0xD2511F53)
_M1 = np.uint64(0xCD9E8D57)
_W0 = np.uint64(0x9E3779B9)
_W1 = np.uint64(0xBB67AE85)
_MASK = np.uint64(0xFFFFFFFF)
_S32 = np.uint64(32)


def check_seed(seed) -> int:
    """``seed`` as an int in [0, 2**64) (the key of the Philox streams), or an InputError."""
    try:
        s = int(seed)
    except (TypeError, ValueError) as err:
        raise InputError(f"seed must be an integer in [0, 2**64), got {seed!r}") from err
    if not 0 <= s < 2**64:
        raise InputError(f"seed must be an integer in [0, 2**64), got {seed!r}")
    return s


def split_seed(seed: int) -> tuple[int, int]:
    """(lo, hi) 32-bit words of a non-negative 64-bit ``seed``."""
    s = check_seed(seed)
    return s & 0xFFFFFFFF, s >> 32


def philox4x32_10(counter, key):
    """Philox4x32 with 10 rounds, element-wise over arrays.

    Parameters
    ----------
    counter : 4 array_like of uint32
        Counter words (broadcastable arrays).
    key : 2 array_like of uint32
        Key words.

    Returns
    -------
    tuple of 4 ndarray (uint64 holding 32-bit values)
    """
    c0, c1, c2, c3 = (np.asarray(c, dtype=np.uint64) & _MASK for c in counter)
    k0, k1 = (np.asarray(k, dtype=np.uint64) & _MASK for k in key)
    for r in range(10):
        if r:
            k0 = (k0 + _W0) & _MASK
            k1 = (k1 + _W1) & _MASK
        p0 = _M0 * c0
        p1 = _M1 * c2
        c0, c1, c2, c3 = (
            ((p1 >> _S32) ^ c1 ^ k0) & _MASK,
            p1 & _MASK,
            ((p0 >> _S32) ^ c3 ^ k1) & _MASK,
            p0 & _MASK,
        )
    return c0, c1, c2, c3


def uniforms(photon_id, block, *, seed: int) -> np.ndarray:
    """Four uniforms in (0, 1) for each (photon, block) pair.

    Parameters
    ----------
    photon_id : (n,) int
        Photon ids (< 2**64).
    block : (n,) int
        Block counter of each photon's stream (< 2**32).
    seed : int
        Run seed.

    Returns
    -------
    (n, 4) float64
        Identical to the float32 values the kernel draws.
    """
    pid = np.asarray(photon_id, dtype=np.uint64)
    lo, hi = split_seed(seed)
    out = philox4x32_10(
        (np.asarray(block, dtype=np.uint64), pid & _MASK, pid >> _S32, np.uint64(0)), (lo, hi)
    )
    return np.stack([((x >> np.uint64(9)).astype(np.float64) + 0.5) * 2.0**-23 for x in out], axis=-1)
