"""The Levenberg-Marquardt fits of :mod:`._batch_fit` on an OpenCL device.

One work-item fits one waveform (``clsim/kernels/decompose_lm.cl``): the same
model, censoring, linear start, damping, trust region and stopping rules as the
NumPy path, in float32, with the normal matrix summed over blocks of 8 samples
instead of a stored Jacobian (an echo is left out of the blocks beyond 8 of its
sigmas, where its exponential is under 1.3e-14); the step's linear system is
scaled to a unit diagonal before its float32 Cholesky factorisation (Marquardt
1963). The standard errors come from ``J^T J`` at the fit, inverted in the kernel
(in double where the device has it, as :func:`._batch_fit.standard_errors` does on
the NumPy path; the same figures to float32 rounding). A chunk's samples
are uploaded once (:meth:`DeviceFitter.bind`); a round of fits
(:meth:`BoundFitter.fit_groups`: groups of waveforms, each with its own number of
echoes) is then one upload of all their row indices and start values, one launch
per group and one result buffer, which returns the fits, their standard errors
and, for the search of further echoes, the residuals and the residuals through the matched filter
and the Gaussian of sigma 1 sample (:meth:`BoundFitter.set_pulse`; float32 sums of the same weights
as :func:`._matched.filter_output` and ``gaussian_filter1d``).

Measured on the shared 2-core test machine: PoCL 3.1 fits two echoes to 150
samples from rough starts about 100,000 times a second (the NumPy path 5,000 to
15,000 in the same runs), and reaches the NumPy fits' minimum within 0.02
standard error (``tests/clsim/waveforms/test_decompose_batch.py``).

References
----------
Marquardt, D. W. (1963). An algorithm for least-squares estimation of
    nonlinear parameters. J. SIAM 11(2), 431-441. doi:10.1137/0111030
"""

from __future__ import annotations

import threading
import time
from importlib import resources

import numpy as np

from clsim.waveforms.decompose._batch_fit import _TOL, GroupFit

#: Flag bits of a sample in the kernel: it counts; it is censored (clipped).
_USE, _CENS = 1, 2
#: Launch errors that mean "this kernel needs more than the device gives a work-item"
#: (CL_OUT_OF_RESOURCES, CL_OUT_OF_HOST_MEMORY, CL_INVALID_WORK_GROUP_SIZE): the fit
#: falls back to NumPy; any other error is raised.
_TOO_LARGE = (-5, -6, -54)


def _source() -> tuple[str, str]:
    kdir = resources.files("clsim") / "kernels"
    return (kdir / "decompose_lm.cl").read_text(), f"-I{kdir}"


def build_options(info, k: int, fit_baseline: bool) -> list[str]:
    """``-D`` options of the fitting kernel: echoes per waveform and baseline fitted.

    No ``-cl-fast-relaxed-math``: the kernel relies on a non-finite residual sum
    failing the step's acceptance test."""
    opts = [f"-DK={int(k)}", f"-DFIT_BASELINE={int(bool(fit_baseline))}", "-cl-mad-enable"]
    if info.runtime.startswith("PoCL"):
        opts.append("-DCLSIM_CLANG_BUILTINS")
    return opts


def probe_build(device) -> str | None:
    """Build the fitting kernel (one echo) on a ``pyopencl.Device``; the device
    layer's probe (:data:`voxlidar.devices.KERNEL_SETS`). Raises on a build failure."""
    import pyopencl as cl

    from clsim.waveforms.decompose import _detect_cl
    from voxlidar.devices import build_program, describe

    src, inc = _source()
    build_program(cl.Context([device]), src, [inc] + build_options(describe(device), 1, True))
    _detect_cl.probe_build(device)
    return None


class DeviceFitter:
    """An OpenCL context, queue and the fitting programs built on one device.

    Parameters
    ----------
    info : voxlidar.devices.DeviceInfo
        A device that builds the ``decompose`` kernel set.
    se_float : bool
        Invert for the standard errors in float32 even where the device has
        double (as on devices without it; for the tests).
    """

    def __init__(self, info, *, se_float: bool = False):
        import pyopencl as cl

        from voxlidar.devices import open_queue

        self._cl = cl
        self.info = info
        self.se_float = bool(se_float)
        self.context, self.queue = open_queue(info)
        self._kernels = {}
        self.build_seconds = 0.0
        # one waveform per work-group on a CPU (the runtime's own choice of a large
        # group overflows PoCL's stack with the kernel's private arrays); GPUs: the
        # runtime's choice
        self.local_size = None if info.is_gpu else (1,)
        self._detector = None
        # kernels (k, fit_baseline) this device cannot launch: their private arrays, of
        # (3k+1)^2 floats, exceed what the driver reserves per work-item (NVIDIA's OpenCL
        # answers OUT_OF_HOST_MEMORY at k = 40); those groups are fitted by NumPy
        self.too_large: set = set()
        # chunks run in threads (decompose_batch): a kernel object's arguments and its
        # launch must not interleave with another thread's, nor two builds
        self.lock = threading.RLock()
        # the residual filters' weights on the device, by pulse (the last few kept)
        self._filters: dict = {}

    @property
    def detector(self):
        """The detection kernels (:class:`._detect_cl.Detector`), built on first use."""
        with self.lock:
            if self._detector is None:
                from clsim.waveforms.decompose._detect_cl import Detector

                t0 = time.perf_counter()
                self._detector = Detector(self)
                self.build_seconds += time.perf_counter() - t0
        return self._detector

    def kernel(self, k: int, fit_baseline: bool):
        """The ``lm_fit`` kernel for ``k`` echoes (built once per fitter)."""
        key = (int(k), bool(fit_baseline))
        with self.lock:
            kern = self._kernels.get(key)
            return kern if kern is not None else self._build(key)

    def _build(self, key):
        if key not in self._kernels:
            from voxlidar.devices import build_program

            src, inc = _source()
            t0 = time.perf_counter()
            opts = build_options(self.info, *key) + (["-DCLSIM_SE_FLOAT"] if self.se_float else [])
            prg = build_program(self.context, src, [inc] + opts)
            self.build_seconds += time.perf_counter() - t0
            kern = self._cl.Kernel(prg, "lm_fit")
            # the scalar arguments' types, declared once (set_args is then 30x faster)
            kern.set_scalar_arg_dtypes([None, None, np.int32, None, None, None, None, None,
                                        np.int32, np.int32, np.float32, np.int32, None,
                                        np.int32, np.int32, np.int32, np.int32, np.int32,
                                        np.int64, np.int64])
            self._kernels[key] = kern
        return self._kernels[key]

    def filter_buffer(self, pulse):
        """The residual filters of the fits (:meth:`BoundFitter.set_pulse`) on the
        device: (buffer, matched-filter size, its lag-0 index, the residual's zero
        padding), made once per pulse: the matched filter of ``pulse`` (None: a unit
        weight), then the 9 weights of the Gaussian of sigma 1 sample."""
        from clsim.waveforms.decompose._detect_cl import _SMOOTH

        p, pc = (np.ones(1), 0) if pulse is None else (pulse.weights, int(pulse.centre))
        key = (pc, p.tobytes())
        with self.lock:
            got = self._filters.get(key)
            if got is None:
                cl = self._cl
                w = np.concatenate([p, _SMOOTH[:9]]).astype(np.float32)
                # the residual's zero padding on either side: the filters' reach and a block
                pad = max(pc, p.size - 1 - pc, 4) + 8
                got = (cl.Buffer(self.context, cl.mem_flags.READ_ONLY
                                 | cl.mem_flags.COPY_HOST_PTR, hostbuf=w), p.size, pc, pad)
                if len(self._filters) >= 8:
                    self._filters.pop(next(iter(self._filters)))
                self._filters[key] = got
        return got

    def bind(self, y, use, cens, noise) -> BoundFitter:
        """Upload a chunk: samples (N, n), the samples that count and the censored
        ones (N, n) bool, the noise sigma (N,)."""
        return BoundFitter(self, y, use, cens, noise)


class BoundFitter:
    """A chunk's samples on the device; :meth:`fit` fits any of its rows."""

    @classmethod
    def on_device(cls, fitter: DeviceFitter, y, flags, span, noise, n_samples: int):
        """On buffers already on the device (:mod:`._detect_cl`): samples and flag
        bits (N, 8 ceil(n/8)), span (N,) int2, noise (N,) float32."""
        self = cls.__new__(cls)
        self.fitter, self.n, self.n_samples = fitter, -(-n_samples // 8) * 8, n_samples
        self.y, self.flags, self.span, self.noise = y, flags, span, noise
        self.set_pulse(None)
        return self

    def __init__(self, fitter: DeviceFitter, y, use, cens, noise):
        cl = fitter._cl
        n = y.shape[1]
        first = np.argmax(use, axis=1)
        last = n - 1 - np.argmax(use[:, ::-1], axis=1)
        # rows padded to a multiple of 8 samples (the kernel reads float8), padding unused
        self.fitter, self.n, self.n_samples = fitter, -(-n // 8) * 8, n
        flags = np.zeros((y.shape[0], self.n), dtype=np.uint8)
        flags[:, :n] = use.astype(np.uint8) * _USE
        if cens is not None:
            flags[:, :n] |= (cens & use).astype(np.uint8) * _CENS
        yp = np.zeros((y.shape[0], self.n), dtype=np.float32)
        yp[:, :n] = y
        span = np.ascontiguousarray(np.stack([first, last], axis=1), dtype=np.int32)
        mf = cl.mem_flags
        ctx = fitter.context

        def up(a):
            return cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.ascontiguousarray(a))

        self.y = up(yp)
        self.flags = up(flags)
        self.span = up(span)
        self.noise = up(np.asarray(noise, dtype=np.float32))
        self.set_pulse(None)

    def set_pulse(self, pulse, residuals: bool = True):
        """The matched filter of the residuals the fits return: ``pulse``
        (:class:`._matched.Pulse`) or None (a unit weight: the residual itself);
        ``residuals=False``: the fits return no residual (no search follows them)."""
        self.resid = bool(residuals)
        self.filters = self.fitter.filter_buffer(pulse)
        self.pad = self.filters[3]

    def fit(self, rows, a, m, s, b, *, fit_baseline=True, linear=False, max_iter=40,
            tol=_TOL) -> GroupFit:
        """Fit chunk rows ``rows`` (G,) from start values (G, K) and (G,), as
        :func:`._batch_fit.fit_group` does (``linear``: the start amplitudes and
        baseline first by linear least squares, :func:`._batch_fit.linear_start`;
        with the baseline fitted only)."""
        return self.fit_groups([(rows, a, m, s, b)], fit_baseline=fit_baseline, linear=linear,
                               max_iter=max_iter, tol=tol)[0]

    def fit_groups(self, groups, *, fit_baseline=True, linear=False, max_iter=40,
                   tol=_TOL) -> list:
        """Fit several groups ``[(rows, a, m, s, b), ...]`` (each its own number of
        echoes K) as :meth:`fit` does, in one round: one upload of all their rows
        and start values, one launch per group and one copy back per group.
        Returns their
        :class:`GroupFit`, in order."""
        cl = self.fitter._cl
        queue = self.fitter.queue
        fb = bool(fit_baseline)
        n, pad = self.n, self.pad
        plan, q_parts, q_off, o_off, host = [], [], 0, 0, {}
        for i, (rows, a, m, s, b) in enumerate(groups):
            g, k = a.shape
            npar = 3 * k + 1
            if (k, fb) in self.fitter.too_large:
                host[i] = self._host_fit(rows, a, m, s, b, fb, linear, max_iter, tol)
                continue
            q = np.empty((g, npar), dtype=np.float32)
            q[:, :k], q[:, k:2 * k], q[:, 2 * k:3 * k], q[:, -1] = a, m, s, b
            # one row per waveform: fit, rss, n_eff, iterations, standard errors and
            # (for a search) the residual, its matched filter and smoothing (the
            # kernel's OUT)
            stride = 2 * npar + 3 + (2 * pad + 3 * n if self.resid else 0)
            plan.append((i, rows, g, k, npar, stride, q_off, o_off))
            q_parts.append(q.reshape(-1))
            q_off += q.size
            o_off += g * stride
        results = [None] * len(groups)
        if plan:
            mf = cl.mem_flags
            ctx = self.fitter.context
            r0 = np.concatenate([[0], np.cumsum([p[2] for p in plan])])
            d_row = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.concatenate(
                [np.asarray(p[1], dtype=np.int32) for p in plan]))
            d_q = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=np.concatenate(q_parts))
            out = np.empty(o_off, dtype=np.float32)
            d_out = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
            launched = []
            with self.fitter.lock:
                for j, (i, rows, g, k, npar, stride, qo, oo) in enumerate(plan):
                    kern = self.fitter.kernel(k, fb)
                    kern.set_args(self.y, self.flags, n, d_row, self.span, self.noise, d_q,
                                  d_out, g, max_iter, tol, int(bool(linear) and fb),
                                  *self.filters, int(self.resid), int(r0[j]), qo, oo)
                    try:
                        cl.enqueue_nd_range_kernel(queue, kern, (g,), self.fitter.local_size)
                    except cl.Error as err:  # more private memory than a work-item gets
                        if getattr(err, "code", None) not in _TOO_LARGE:
                            raise
                        self.fitter.too_large.add((k, fb))
                        a, m, s, b = groups[i][1:]
                        host[i] = self._host_fit(rows, a, m, s, b, fb, linear, max_iter, tol)
                        continue
                    # each group's rows of OUT come back as soon as its launch ends:
                    # the host turns one group into results while the next computes
                    launched.append((j, cl.enqueue_copy(
                        queue, out[oo:oo + g * stride], d_out, src_offset=4 * oo,
                        is_blocking=False)))
            ns = self.n_samples
            for j, done in launched:
                i, rows, g, k, npar, stride, qo, oo = plan[j]
                done.wait()
                o = out[oo:oo + g * stride].reshape(g, stride)
                base = 2 * npar + 3
                fit = o[:, :npar].astype(float)
                rss = o[:, npar].astype(float)
                n_eff = o[:, npar + 1].astype(int)
                se = o[:, npar + 3:base].astype(float)
                se[se < 0.0] = np.nan
                r = flt = None
                if self.resid:
                    r = o[:, base + pad:base + pad + ns]
                    flt = o[:, base + 2 * pad + n:].reshape(g, 2, n)[:, :, :ns]
                results[i] = GroupFit(fit[:, :k], fit[:, k:2 * k], fit[:, 2 * k:3 * k],
                                      fit[:, -1], rss, se, n_eff, o[:, npar + 2].astype(int),
                                      r, flt)
        for i, res in host.items():
            results[i] = res
        return results

    def _host_fit(self, rows, a, m, s, b, fit_baseline, linear, max_iter, tol):
        """The NumPy fit (:func:`._batch_fit.fit_group`) of ``rows``, from
        the chunk's samples read back from the device once."""
        from clsim.waveforms.decompose._batch_fit import fit_group, linear_start

        if getattr(self, "_host", None) is None:
            cl, queue = self.fitter._cl, self.fitter.queue
            n_rows = self.noise.size // 4
            y = np.empty((n_rows, self.n), dtype=np.float32)
            flags = np.empty((n_rows, self.n), dtype=np.uint8)
            noise = np.empty(n_rows, dtype=np.float32)
            for host, dev in ((y, self.y), (flags, self.flags), (noise, self.noise)):
                cl.enqueue_copy(queue, host, dev)
            k = self.n_samples
            self._host = (y[:, :k].astype(float), (flags[:, :k] & _USE) > 0, (flags[:, :k] & _CENS) > 0,
                          noise.astype(float))
        y, use, cens, noise = (v[rows] for v in self._host)
        if linear and fit_baseline:
            a, b = linear_start(y, use & ~cens, a, m, s, b)
        return fit_group(y, use, a, m, s, b, fit_baseline=fit_baseline, noise=noise, cens=cens,
                         max_iter=max_iter, tol=tol)


#: Fitters built in this process, by device key (a context and built programs each).
_FITTERS: dict = {}
_ENV = ("VOXLIDAR_DEVICE", "PYOPENCL_CTX")


def device_fitter(device=None) -> DeviceFitter | None:
    """The :class:`DeviceFitter` for ``device`` (built once per process), or None for
    the NumPy path.

    Parameters
    ----------
    device : DeviceInfo, pyopencl.Device, str or None
        ``"numpy"``: the NumPy path. None: ``VOXLIDAR_DEVICE``, ``PYOPENCL_CTX``
        or the best device that builds the fitting kernel
        (:func:`voxlidar.devices.choose_device`), and the NumPy path when
        pyopencl is missing or no device builds it (unless one of those
        variables names a device: then its error). Else a device as
        :func:`voxlidar.devices.choose_device` takes it (``"0:1"``, ``"cpu"``,
        ``"gpu"``, ``"intel"``, ...).

    Raises
    ------
    clsim.errors.DeviceError
        A device asked for (argument or variable) that is absent or cannot
        build the kernel; pyopencl missing when a device is asked for.
    """
    import os

    from clsim.errors import DeviceError

    if isinstance(device, str) and device.strip().lower() == "numpy":
        return None
    asked = device is not None or any(os.environ.get(v, "").strip() for v in _ENV)
    memo = ("auto",) + tuple(os.environ.get(v, "") for v in _ENV) if device is None else None
    if memo is not None and memo in _FITTERS:
        return _FITTERS[memo]
    try:
        import pyopencl  # noqa: F401 - the device path needs it

        from voxlidar.devices import choose_device
    except ImportError as err:
        if asked:
            raise DeviceError("decompose_batch on an OpenCL device needs pyopencl; fix: pip "
                              "install pyopencl, or pass device='numpy'") from err
        _FITTERS[memo] = None
        return None
    try:
        info = choose_device(device, kernels=("decompose",))
    except DeviceError as err:
        if asked:
            raise DeviceError(f"{err} (or pass device='numpy')") from None
        _FITTERS[memo] = None
        return None
    if info.key not in _FITTERS:
        _FITTERS[info.key] = DeviceFitter(info)
    if memo is not None:
        _FITTERS[memo] = _FITTERS[info.key]
    return _FITTERS[info.key]
