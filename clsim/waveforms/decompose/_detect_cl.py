"""The detection of :mod:`._batch` on an OpenCL device, one work-item per waveform.

``clsim/kernels/decompose_detect.cl`` runs the NumPy detection's steps in
float32 (:mod:`._batch_detect` is the reference): kernel ``noise_stats``
gives each waveform's robust baseline and noise sigma, the no-data zeros left
out, the clipped samples, the clipping-tolerant baseline and the half-maximum
width of its strongest echo (the host then takes the batch's pulse width and
the false-alarm level); kernel ``candidates`` runs the matched filter, the
smoothing and curvature filters, finds the peaks, shoulders and matched-filter
maxima above the level and returns the highest ``k_cap`` of each waveform with
their start values. The samples stay on the device, in the layout of the fitting
kernel, for the fits that follow (:meth:`BoundDetection.fitter`).

Detection was about 60 % of ``decompose_batch``'s time with NumPy (several
passes over every sample per step, one core); in the kernel it is one pass per
step, on every core of the device.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources

import numpy as np
from scipy.ndimage import gaussian_filter1d

from clsim.waveforms.decompose._batch_cl import BoundFitter, build_options

#: Most candidates per waveform the kernel keeps (its private arrays).
MAX_CANDIDATES = 32
#: Most work-items of a detection launch (each loops over rows beyond).
ITEMS = 1 << 16
#: Saturation modes of the kernel.
_SAT_NONE, _SAT_AUTO, _SAT_VALUE = 0, 1, 2


def _source() -> tuple[str, str]:
    kdir = resources.files("clsim") / "kernels"
    return (kdir / "decompose_detect.cl").read_text(), f"-I{kdir}"


def detect_options(info) -> list[str]:
    """Build options of the detection kernels (no fast math: the comparisons with
    the level must not be reordered)."""
    return [o for o in build_options(info, 1, True) if not o.startswith(("-DK=", "-DFIT_",
                                                                          "-cl-mad"))]


def probe_build(device) -> None:
    """Build the detection kernels on a ``pyopencl.Device`` (raises on failure)."""
    import pyopencl as cl

    from voxlidar.devices import build_program, describe

    src, inc = _source()
    build_program(cl.Context([device]), src, [inc] + detect_options(describe(device)))


def _impulse_weights(sigma: float, order: int) -> np.ndarray:
    """The correlation weights of ``gaussian_filter1d(x, sigma, order=order)``
    (scipy's own, read from its response to a unit impulse)."""
    radius = int(4.0 * sigma + 0.5)
    delta = np.zeros(2 * radius + 1)
    delta[radius] = 1.0
    return gaussian_filter1d(delta, sigma, order=order, mode="constant")[::-1]


#: ys (sigma 1), yc and d2 (sigma 1.5, orders 0 and 2): 9 + 13 + 13 weights.
_SMOOTH = np.concatenate([_impulse_weights(1.0, 0), _impulse_weights(1.5, 0),
                          _impulse_weights(1.5, 2)]).astype(np.float32)


@dataclass
class NoiseStats:
    """Per waveform (N,): baseline, noise sigma, samples that count, half-maximum
    width of the strongest echo (NaN: none usable); (N, n) masks of the samples
    that count and the censored ones (None when no sample of the chunk is)."""

    b: np.ndarray
    sigma: np.ndarray
    n_valid: np.ndarray
    width: np.ndarray
    use: np.ndarray
    cens: np.ndarray | None


class Detector:
    """The detection program on a :class:`._batch_cl.DeviceFitter`'s context."""

    def __init__(self, fitter):
        import pyopencl as cl

        from voxlidar.devices import build_program

        src, inc = _source()
        prg = build_program(fitter.context, src, [inc] + detect_options(fitter.info))
        self.fitter = fitter
        self._filters: dict = {}
        self.noise = cl.Kernel(prg, "noise_stats")
        self.noise.set_scalar_arg_dtypes([None, np.int32, None, np.int32, np.float32, None,
                                          None, None, None, None, np.int32])
        self.cand = cl.Kernel(prg, "candidates")
        self.cand.set_scalar_arg_dtypes([None, np.int32, np.int32, None, None, None, None,
                                         np.int32, np.int32, np.int32, np.float32, np.float32,
                                         np.int32, np.int32, None, None, None, np.int32])

    def filter_buffer(self, pulse):
        """The detection filters' weights on the device (the matched filter of
        ``pulse``, then :data:`_SMOOTH`), uploaded once per pulse (the last few kept)."""
        import pyopencl as cl

        key = (int(pulse.centre), pulse.weights.tobytes())
        with self.fitter.lock:
            buf = self._filters.get(key)
            if buf is None:
                flt = np.concatenate([pulse.weights, _SMOOTH]).astype(np.float32)
                buf = cl.Buffer(self.fitter.context, cl.mem_flags.READ_ONLY
                                | cl.mem_flags.COPY_HOST_PTR, hostbuf=flt)
                if len(self._filters) >= 8:
                    self._filters.pop(next(iter(self._filters)))
                self._filters[key] = buf
        return buf

    def bind(self, y, lengths) -> BoundDetection:
        """Upload a chunk's samples (N, n) and lengths (N,)."""
        return BoundDetection(self, y, lengths)


class BoundDetection:
    """One chunk on the device: :meth:`noise_stats`, then :meth:`candidates`, then
    :meth:`fitter` for its fits (the same buffers)."""

    def __init__(self, det: Detector, y, lengths):
        cl = det.fitter._cl
        self.det, self.cl = det, cl
        self.queue = det.fitter.queue
        self.rows, self.n = y.shape
        self.ns = -(-self.n // 8) * 8
        yp = np.zeros((self.rows, self.ns), dtype=np.float32)
        yp[:, :self.n] = y
        ctx = det.fitter.context
        mf = cl.mem_flags
        self.y = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=yp)
        self.len = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR,
                             hostbuf=np.ascontiguousarray(lengths, dtype=np.int32))
        self.flags = cl.Buffer(ctx, mf.READ_WRITE, self.rows * self.ns)
        self.span = cl.Buffer(ctx, mf.READ_WRITE, self.rows * 8)
        self.noise = cl.Buffer(ctx, mf.READ_WRITE, self.rows * 4)
        self.lengths = lengths

    def _run(self, kern, *args):
        with self.det.fitter.lock:
            kern.set_args(*args)
            self.cl.enqueue_nd_range_kernel(self.queue, kern, (min(self.rows, ITEMS),),
                                            self.det.fitter.local_size)

    def noise_stats(self, saturation) -> NoiseStats:
        """Kernel ``noise_stats``; ``saturation``: None, "auto" or a full-scale value
        (checked by the caller)."""
        cl = self.cl
        ctx = self.det.fitter.context
        mode, value = ((_SAT_NONE, 0.0) if saturation is None else
                       (_SAT_AUTO, 0.0) if isinstance(saturation, str) else
                       (_SAT_VALUE, float(saturation)))
        scratch = cl.Buffer(ctx, cl.mem_flags.READ_WRITE, self.rows * self.ns * 4)
        d_out = cl.Buffer(ctx, cl.mem_flags.WRITE_ONLY, self.rows * 8 * 4)
        self._run(self.det.noise, self.y, self.ns, self.len, mode, value, scratch, self.flags,
                  self.span, self.noise, d_out, self.rows)
        out = np.empty((self.rows, 8), dtype=np.float32)
        flags = np.empty((self.rows, self.ns), dtype=np.uint8)
        cl.enqueue_copy(self.queue, out, d_out, is_blocking=False)
        cl.enqueue_copy(self.queue, flags, self.flags, is_blocking=True)
        flags = flags[:, :self.n]
        self.stats = out
        width = out[:, 3].astype(float)
        cens = (flags & 2).astype(bool) if out[:, 4].any() else None
        return NoiseStats(out[:, 0].astype(float), out[:, 1].astype(float),
                          out[:, 2].astype(np.int64), np.where(width > 0, width, np.nan),
                          (flags & 1).astype(bool), cens)

    def candidates(self, pulse, level, k_cap):
        """Kernel ``candidates`` with the matched filter of ``pulse`` and the
        detection level (N,) in amplitude units: the start amplitude, location and
        sigma (N, k_cap) of the highest candidates, highest first, and their mask."""
        cl = self.cl
        ctx = self.det.fitter.context
        mf = cl.mem_flags
        p = pulse.shape
        st = np.ascontiguousarray(np.column_stack([self.stats[:, 0], self.stats[:, 1],
                                                   level]), dtype=np.float32)
        d_flt = self.det.filter_buffer(pulse)
        d_st = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=st)
        # the padding of the baseline-free samples: the filters' reach, 8 more for the
        # last block of 8 outputs
        pad = max(pulse.centre, p.size - 1 - pulse.centre, 6) + 8
        work = cl.Buffer(ctx, mf.READ_WRITE, self.rows * (5 * self.ns + 2 * pad) * 4)
        d_cand = cl.Buffer(ctx, mf.WRITE_ONLY, self.rows * k_cap * 3 * 4)
        d_cnt = cl.Buffer(ctx, mf.WRITE_ONLY, self.rows * 4)
        d = int(np.ceil(max(1.0, pulse.sigma)))
        d2_noise = float(np.sqrt(3.0 / (8.0 * np.sqrt(np.pi) * 1.5 ** 5)))
        self._run(self.det.cand, self.y, self.ns, self.n, self.len, self.flags, d_st, d_flt,
                  p.size, pulse.centre, d, d2_noise, pulse.sigma, k_cap, pad, work, d_cand, d_cnt,
                  self.rows)
        cand = np.empty((self.rows, k_cap, 3), dtype=np.float32)
        cnt = np.empty(self.rows, dtype=np.int32)
        cl.enqueue_copy(self.queue, cand, d_cand, is_blocking=False)
        cl.enqueue_copy(self.queue, cnt, d_cnt, is_blocking=True)
        on = np.arange(k_cap) < cnt[:, None]
        # float64 from here: the fits' state (unused slots hold garbage: zeroed)
        cand = np.where(on[:, :, None], cand, 0.0).astype(float)
        return cand[:, :, 0], cand[:, :, 1], np.where(on, cand[:, :, 2], 1.0), on

    def fitter(self) -> BoundFitter:
        """The chunk's :class:`._batch_cl.BoundFitter` on the buffers already here."""
        return BoundFitter.on_device(self.det.fitter, self.y, self.flags, self.span,
                                     self.noise, self.n)
