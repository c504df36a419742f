"""The outcome of a transport run: waveforms per order and kind, statistics, photon paths.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clsim.digitize import digitize
from clsim.errors import InputError
from clsim.transport.setup import COUNT_STATS, STAT_NAMES, RunSetup
from voxlidar.safeio import atomic_write, json_text


@dataclass
class SimulationResult:
    """A simulated waveform with its Monte Carlo statistics.

    Attributes
    ----------
    time_ns : (S,) float64
        Sample times after emission, ns, at the sensor's sampling rate.
    waveform : (S,) float64
        Received power, fraction of the emitted energy per ns (all orders).
    by_order : (K, S) float64
        ``waveform`` split by scattering order (row 0: single scattering).
    fine_edges_ns : (F+1,) float64
        Edges of the fine time bins.
    fine : (K, 2, F) float64
        Energy per fine bin (fraction of emitted energy) by order and by the
        material of the last scattering (0 vegetation, 1 ground), before the
        pulse convolution.
    fine_batches : (B, K, 2, F) float64
        The same per batch (photon id modulo B), each normalised by its own
        photon count; the spread gives standard errors.
    batch_photons : (B,) int
    stats : dict of (B,) float64
        Per-batch photon fates (weights per launched photon; counts for
        ``detections``, ``voxel_steps``, ``events``, ``shadow_rays``, ``walk_steps``;
        ``voxel_steps`` counts the voxels the walk reached, shadow rays included
        (the same count whether a uniform brick is crossed in one segment or
        voxel by voxel), ``walk_steps`` its steps, where a uniform brick crossed
        in one segment is one step; the NumPy oracle walks voxel by voxel, so
        both are equal there).
    settings : dict
    flags : list of str
        Things a user should know about this result.
    traces : (P, 16, 4) float32 or None
        First events (x, y, z in world metres, type) of the first P photons;
        type -2 launch, 0 escape, 1 leaf, 2 wood, 3 ground, -1 absorbed, -9 unused.
    elapsed_s : float
    """

    time_ns: np.ndarray
    waveform: np.ndarray
    by_order: np.ndarray
    fine_edges_ns: np.ndarray
    fine: np.ndarray
    fine_batches: np.ndarray
    batch_photons: np.ndarray
    stats: dict
    settings: dict
    flags: list = field(default_factory=list)
    traces: np.ndarray | None = None
    elapsed_s: float = 0.0

    _KINDS = {None: slice(None), "vegetation": 0, "ground": 1}

    def _batch_values(self, values):
        """(B,) per-photon estimates -> (mean, standard error)."""
        v = np.asarray(values, dtype=np.float64)
        n = self.batch_photons
        ok = n > 0
        mean = float(np.sum(v[ok] * n[ok]) / n[ok].sum())
        se = float(np.std(v[ok], ddof=1) / math.sqrt(ok.sum())) if ok.sum() > 1 else math.nan
        return mean, se

    def energy(self, order=None, kind=None) -> tuple[float, float]:
        """Received energy (fraction of emitted) and its standard error.

        Parameters
        ----------
        order : int or None
            Scattering order (1 = single); None for all.
        kind : {"vegetation", "ground", None}
            Material of the last scattering event; None for both.
        """
        if kind not in self._KINDS:
            raise InputError(f"kind={kind!r} must be one of vegetation, ground, None")
        fb = self.fine_batches
        if order is not None:
            if not 1 <= order <= fb.shape[1]:
                raise InputError(f"order={order!r} must lie in 1..{fb.shape[1]}")
            fb = fb[:, order - 1 : order]
        per = fb[:, :, self._KINDS[kind]].reshape(fb.shape[0], -1).sum(axis=1)
        return self._batch_values(per)

    def stat(self, name: str) -> tuple[float, float]:
        """A photon-fate statistic per launched photon (or total count) and its standard error."""
        if name not in self.stats:
            raise InputError(f"stat {name!r} unknown; have {sorted(self.stats)}")
        if name in COUNT_STATS:
            return float(np.sum(self.stats[name])), math.nan
        return self._batch_values(self.stats[name])

    @property
    def photons_per_second(self) -> float:
        return self.settings["photons"] / self.elapsed_s if self.elapsed_s > 0 else math.nan

    def save(self, path) -> Path:
        """Write ``time_ns``, ``waveform``, ``by_order``, the fine histograms and settings as NPZ."""
        arrays = dict(time_ns=self.time_ns, waveform=self.waveform, by_order=self.by_order,
                      fine_edges_ns=self.fine_edges_ns, fine=self.fine,
                      batch_photons=self.batch_photons,
                      settings=np.str_(json_text(self.settings)),
                      flags=np.str_(json_text(self.flags)),
                      **{f"stat_{k}": v for k, v in self.stats.items()})
        if self.traces is not None:
            arrays["traces"] = self.traces

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **arrays)

        return atomic_write(path, write)


def digitized(setup: RunSetup, hist) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sensor's waveform from the tallies ``hist`` (B, K, 2, F) of a run:
    ``time_ns`` (S,), ``by_order`` (K, S) (sum over the first axis: the waveform)
    and the fine energies ``fine`` (K, 2, F).  One computation for
    :func:`assemble_result` and :meth:`clsim.Simulator.run_pulses`, so that both
    give the same bits."""
    scale = setup.sensor.aperture_area_m2 / setup.range_ref_m**2
    fine = hist.sum(axis=0) * scale / setup.photons
    time_ns, by_order = digitize(setup.edges_ns, fine.sum(axis=1), sampling_ghz=setup.sensor.sampling_ghz,
                                 pulse_fwhm_ns=setup.sensor.pulse_fwhm_ns)
    return time_ns, by_order, fine


def assemble_result(setup: RunSetup, hist, stats, traces, elapsed: float, device: str) -> SimulationResult:
    """Turn raw tallies into a :class:`SimulationResult`.

    ``hist`` (B, K, 2, F) and ``stats`` (B, NSTAT) are in tally units: NEE in
    units of A / R_ref^2 per launched photon, weights per launched photon.
    """
    B = setup.batches
    n_b = np.array([setup.photons // B + (b < setup.photons % B) for b in range(B)], dtype=np.int64)
    scale = setup.sensor.aperture_area_m2 / setup.range_ref_m**2
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(n_b > 0, 1.0 / np.maximum(n_b, 1), 0.0)
    fine_b = hist * scale * inv[:, None, None, None]
    time_ns, by_order, fine = digitized(setup, hist)
    st = {}
    for i, name in enumerate(STAT_NAMES):
        v = stats[:, i].astype(np.float64)
        st[name] = v if name in COUNT_STATS else v * inv
    st["outside_window"] = st["outside_window"] * scale
    flags = list(setup.flags)
    res = SimulationResult(time_ns=time_ns, waveform=by_order.sum(axis=0), by_order=by_order,
                           fine_edges_ns=setup.edges_ns, fine=fine, fine_batches=fine_b,
                           batch_photons=n_b, stats=st, settings=dict(setup.settings, device=device),
                           flags=flags, traces=traces, elapsed_s=elapsed)
    trunc, _ = res.stat("truncated")
    if trunc > 0.01:
        flags.append(f"{100 * trunc:.1f} % of the launched energy was still travelling at max_order="
                     f"{setup.max_order}; raise max_order for the higher orders")
    outside = float(np.sum(st["outside_window"] * n_b)) / setup.photons
    total = float(fine.sum())
    if outside > 1e-3 * max(total, 1e-300):
        flags.append(f"{outside:.3g} of received energy fell outside the time window")
    if B < 2 or (n_b > 0).sum() < 2:
        flags.append("fewer than 2 batches with photons: no standard errors (NaN)")
    if total == 0.0:
        flags.append("no energy reached the receiver")
    return res


def save_results(results, targets, path) -> Path:
    """One NPZ of several pulses (``clsim simulate --targets``, ``clsim pick``): ``targets`` (T, 3; NaN
    where no Z was given), and ``time_ns``, ``waveform``, ``by_order``, ``energy`` and ``settings`` with a
    leading target axis (waveforms padded with NaN to the longest)."""
    nb = max(r.time_ns.size for r in results)

    def pad(a):
        a = np.asarray(a, dtype=np.float64)
        out = np.full(a.shape[:-1] + (nb,), np.nan)
        out[..., :a.shape[-1]] = a
        return out

    tg = np.full((len(targets), 3), np.nan)
    for k, t in enumerate(targets):
        tg[k, :len(t)] = t
    arrays = dict(targets=tg, time_ns=np.stack([pad(r.time_ns) for r in results]),
                  waveform=np.stack([pad(r.waveform) for r in results]),
                  by_order=np.stack([pad(r.by_order) for r in results]),
                  energy=np.array([r.energy() for r in results]),
                  settings=np.str_(json_text([r.settings for r in results])))

    def write(tmp):
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)

    return atomic_write(path, write)


@dataclass
class PulseWaveforms:
    """The waveforms of many pulses (:meth:`clsim.Simulator.run_pulses`), one row each.

    Attributes
    ----------
    index : (N,) int64
        Pulse numbers (``Pulses.index``).
    waveform : (N, S) float64
        Received power in the sensor's samples, fraction of the emitted energy
        per ns; row ``i`` holds ``n_samples[i]`` samples, then zeros (no
        energy reaches the receiver outside a pulse's time window).
    n_samples : (N,) int64
        Samples of each pulse's own time window.
    t0_ns : (N,) float64
        Time of each row's first sample after emission, ns.
    bin_ns : float
        Sample spacing, ns (``1 / sampling_ghz``).
    energy : (N,) float64
        Received energy, fraction of the emitted (before sampling).
    kernel_s : float
        Seconds spent in the transport kernel.
    """

    index: np.ndarray
    waveform: np.ndarray
    n_samples: np.ndarray
    t0_ns: np.ndarray
    bin_ns: float
    energy: np.ndarray
    kernel_s: float = 0.0

    ARRAYS = ("index", "waveform", "n_samples", "t0_ns", "energy")

    def __len__(self) -> int:
        return len(self.index)

    @classmethod
    def from_rows(cls, index, rows, *, t0_ns, bin_ns: float, energy, kernel_s: float = 0.0) -> PulseWaveforms:
        """Rows of different lengths, padded with zeros to the longest."""
        n_s = np.array([len(r) for r in rows], dtype=np.int64)
        wf = np.zeros((len(rows), int(n_s.max()) if len(rows) else 0))
        for i, r in enumerate(rows):
            wf[i, :len(r)] = r
        return cls(index=np.asarray(index, dtype=np.int64), waveform=wf, n_samples=n_s,
                   t0_ns=np.asarray(t0_ns, dtype=np.float64), bin_ns=float(bin_ns),
                   energy=np.asarray(energy, dtype=np.float64), kernel_s=float(kernel_s))

    @classmethod
    def concat(cls, parts) -> PulseWaveforms:
        """Several in order (batches of one survey), padded to the longest row."""
        parts = list(parts)
        if not parts:
            raise InputError("nothing to concatenate: no PulseWaveforms given")
        bins = {p.bin_ns for p in parts}
        if len(bins) != 1:
            raise InputError(f"cannot concatenate waveforms sampled at different spacings {sorted(bins)} ns")
        width = max(p.waveform.shape[1] for p in parts)
        wf = np.zeros((sum(len(p) for p in parts), width))
        row = 0
        for p in parts:
            wf[row:row + len(p), :p.waveform.shape[1]] = p.waveform
            row += len(p)
        cat = {k: np.concatenate([getattr(p, k) for p in parts]) for k in cls.ARRAYS if k != "waveform"}
        return cls(waveform=wf, bin_ns=parts[0].bin_ns, kernel_s=sum(p.kernel_s for p in parts), **cat)

    def save(self, path) -> Path:
        """Write the arrays to an NPZ, atomically (a temporary name renamed)."""
        arrays = {k: getattr(self, k) for k in self.ARRAYS}
        arrays.update(bin_ns=np.float64(self.bin_ns), kernel_s=np.float64(self.kernel_s))

        def write(tmp):
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **arrays)

        return atomic_write(path, write)

    @classmethod
    def load(cls, path) -> PulseWaveforms:
        """Read what :meth:`save` wrote."""
        try:
            with np.load(path) as z:
                return cls(**{k: z[k] for k in cls.ARRAYS}, bin_ns=float(z["bin_ns"]), kernel_s=float(z["kernel_s"]))
        except (OSError, KeyError, ValueError) as err:
            raise InputError(f"{path}: not a batch of pulse waveforms ({err}); fix: delete it and run again") from err
