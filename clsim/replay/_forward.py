"""The forward model of a replay: a scene from training pulses, each test pulse simulated as fired.

1. :func:`scene_from_pulses`: the training pulses' echoes (the instrument's
   pulse as template, :mod:`clsim.replay._echoes`) become beams whose echo
   weights are each echo's energy over a full hit's
   (:func:`tlsvox.voxel.airborne.airborne_beams`), traced through a voxel
   grid with the TLS estimators (:func:`tlsvox.voxel.airborne.voxelize_beams`).
2. :func:`simulate_pulses`: every pulse is simulated by :class:`clsim.Simulator`
   from its own sensor position along its own direction, with the sensor's
   divergence; the photons' energy per fine time bin is put on the record's
   sample clock (its sample 0 at the record's own range) and convolved with
   the instrument's pulse (the measured system impulse response).
3. :class:`Calibration`: the gain (counts per unit of received energy) and
   the time offset (samples) that bring the simulation into the file's units,
   fitted on training pulses only (:func:`calibrate`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from clsim.errors import InputError
from clsim.sensor import C_M_PER_NS, Sensor

__all__ = ["Calibration", "SimulatedPulses", "calibrate", "scene_echoes", "scene_from_pulses", "simulate_pulses"]

#: Where a scene's echoes come from, and how they share their pulse.
ECHO_SOURCES = ("waveform", "returns")
ECHO_WEIGHTS = ("energy", "uniform")


def scene_echoes(prepared, *, source: str = "waveform", weights: str = "energy"):
    """The echoes a scene is made from: the waveforms' or the file's discrete returns, weighted by energy or 1/n.

    Parameters
    ----------
    prepared : Prepared
    source : str
        ``waveform`` (default): the template decomposition of the records
        (:func:`clsim.replay.prepare`). ``returns``: the file's own discrete
        returns (LAS files; ``meta["returns_ns"]``), each with the energy of
        a template echo as high as the record's sample there.
    weights : str
        ``energy`` (default): each echo's energy, to be set against a full
        hit's (the share of the beam it stopped). ``uniform``: 1/n of its
        pulse, as for a discrete-return file without intensity.

    Returns
    -------
    Prepared
        ``prepared`` with its echoes replaced (the records and pulse shape unchanged).
    """
    import dataclasses

    if source not in ECHO_SOURCES:
        raise InputError(f"echo source {source!r}: choose {' or '.join(ECHO_SOURCES)}")
    if weights not in ECHO_WEIGHTS:
        raise InputError(f"echo weights {weights!r}: choose {' or '.join(ECHO_WEIGHTS)}")
    p = prepared.pulses
    out = prepared
    if source == "returns":
        returns = p.meta.get("returns_ns")
        if returns is None:
            raise InputError(f"{p.name} has no discrete returns (a {p.meta.get('source', 'record')} file); use the "
                             "waveforms' echoes")
        pulse = np.concatenate([np.full(len(r), i, np.int64) for i, r in enumerate(returns)] or [np.zeros(0, np.int64)])
        loc = np.concatenate([np.asarray(r, dtype=np.float64) for r in returns] or [np.zeros(0)]) / p.dt_ns
        keep = (loc >= 0) & (loc <= p.n_samples[pulse] - 1)
        pulse, loc = pulse[keep], loc[keep]
        i0 = np.minimum(np.floor(loc).astype(np.int64), prepared.signal.shape[1] - 2)
        f = loc - i0
        height = (1 - f) * prepared.signal[pulse, i0] + f * prepared.signal[pulse, i0 + 1]
        energy = np.clip(height, 0.0, None) / float(prepared.shape.max())
        xyz = p.bin0[pulse] + loc[:, None] * p.step[pulse]
        out = dataclasses.replace(prepared, echo_pulse=pulse, echo_sample=loc, echo_energy=energy,
                                  echo_sigma=np.zeros(loc.size), echo_xyz=xyz, part_echo=None, part_sample=None,
                                  part_energy=None)
    if weights == "uniform":
        n = np.bincount(out.echo_pulse, minlength=len(p))
        uniform = 1.0 / n[out.echo_pulse].astype(np.float64)
        parts = {}
        if out.part_echo is not None:  # each echo's profile keeps its shape, scaled to 1/n
            scale = uniform / np.maximum(out.echo_energy, 1e-300)
            parts = dict(part_energy=out.part_energy * scale[out.part_echo])
        out = dataclasses.replace(out, echo_energy=uniform, **parts)
    return out


def scene_from_pulses(prepared, train, *, voxel_size: float = 0.25, pool_m: float = 0.3, n_min: int = 1,
                      full_percentile: float = 95.0, estimator: str = "beer_lambert", spread: bool = True,
                      return_path: str = "hotspot", ground=None, bounds=None, tracer=None, progress: bool = False):
    """A plant-area scene from the training pulses ``train`` (see the module docstring).

    Parameters
    ----------
    prepared : Prepared
    train : (J,) int, the training pulses
    voxel_size : float, metres
    pool_m : float, metres
        Horizontal Gaussian the voxels' sums are pooled over
        (:func:`tlsvox.voxel.airborne.pool_layers`).
    n_min : int
        Pooled beams a voxel needs to be seen (else it takes a wider pooling).
    full_percentile : float
        The full hit's energy is this percentile of the training pulses' echo energies.
    estimator : str
        ``beer_lambert`` by default: with each echo weighted by the share of
        the beam it stopped, Beer-Lambert on the voxel's intercepted share is
        exact for a turbid layer (tests/tlsvox/voxel/test_airborne.py), while
        the bcMLE's small-sample correction, made for hits of weight 1, takes
        about 1/(2N) off with N pooled beams (a sixth with 3).
    spread : bool
        Each echo along the beam as its profile in range: the template
        shifts it is the sum of (an extended target such as a crown layer is
        one echo over several shifts, the deconvolved profile of its return).
        False: each echo at its mean range.
    return_path : {"hotspot", "turbid"}
        As :func:`tlsvox.voxel.airborne.airborne_beams`: how echo energies
        become shares of the beam.
    ground : None, "ransac" or float
        As :func:`tlsvox.voxel.airborne.voxelize_beams`: None (the replay's
        default) counts the ground echoes as a dense lowest layer.
    bounds : (2, 3) float, metres, optional
        Default: the echoes' box widened by the pooling's reach.
    tracer : Tracer, optional
    progress : bool

    Returns
    -------
    voxlidar.scene.Scene
        ``meta["airborne"]`` adds the full-hit energy used.
    """
    from tlsvox.voxel.airborne import airborne_beams, full_hit_energy, voxelize_beams

    p = prepared.pulses
    train = np.asarray(train, dtype=np.int64)
    sel = np.isin(prepared.echo_pulse, train)
    local = np.searchsorted(train, prepared.echo_pulse[sel])
    per_pulse = np.bincount(local, weights=prepared.echo_energy[sel], minlength=len(train))
    full = full_hit_energy(per_pulse, percentile=full_percentile)
    rng = np.linalg.norm(prepared.echo_xyz[sel] - p.origin[prepared.echo_pulse[sel]], axis=1)
    energy = prepared.echo_energy[sel]
    if spread and prepared.part_echo is not None:
        on = sel[prepared.part_echo]
        pe = prepared.part_echo[on]
        pulse = prepared.echo_pulse[pe]
        local = np.searchsorted(train, pulse)
        # a part's range: its echo's, moved by the part's offset from the echo's mean sample
        rng = rng[np.searchsorted(np.flatnonzero(sel), pe)] + (
            prepared.part_sample[on] - prepared.echo_sample[pe]) * p.metres_per_sample[pulse]
        energy = prepared.part_energy[on]
    end = p.range0()[train] + p.n_samples[train] * p.metres_per_sample[train]
    beams = airborne_beams(p.origin[train], p.direction[train], echo_pulse=local, echo_range=rng,
                           echo_energy=energy, full_energy=full, record_end=end, return_path=return_path)
    # the echoes' box, widened by the pooling's reach so that the pooled sums spread beyond the outer beams
    pts = beams.echo_points()
    reach = np.array([3.0 * pool_m, 3.0 * pool_m, 0.0])
    if bounds is None:
        bounds = np.array([pts.min(axis=0) - reach, pts.max(axis=0) + reach])
    scene = voxelize_beams(beams, voxel_size=voxel_size, n_min=n_min, pool_m=pool_m, tracer=tracer, estimator=estimator,
                           bounds=bounds, ground=ground, progress=progress)
    scene.meta["airborne"]["full_hit_energy"] = full
    scene.meta["airborne"]["full_hit_percentile"] = full_percentile
    return scene


@dataclass
class SimulatedPulses:
    """Simulated pulses before calibration: received energy per fine time bin, on each record's sample clock.

    Attributes
    ----------
    index : (K,) int64, the pulses simulated
    at : list of (F_k,) float64, the fine bins' times in record samples (sample 0 = the record's first)
    energy : list of (F_k,) float64, received energy per bin (fraction of the emitted energy)
    seconds : float, simulation wall time
    outside : (M,) int64, the pulses skipped because their beam leaves the scene
    """

    index: np.ndarray
    at: list
    energy: list
    seconds: float
    outside: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    def responses(self, prepared, *, sub: int = 10) -> tuple[np.ndarray, np.ndarray]:
        """The received energy convolved with the instrument's pulse, on a grid ``1/sub`` sample apart.

        Returns ``t`` (G,) in record samples and ``response`` (K, G): the
        pulse's peak sits at each bin's time (unit sum per sample)."""
        length = prepared.signal.shape[1]
        h, peak = prepared.shape, prepared.shape_peak
        pad = h.size + 2
        t = np.arange(-pad * sub, (length + pad) * sub) / sub
        hf = np.interp(np.arange(0, (h.size - 1) * sub + 1) / sub, np.arange(h.size), h)
        lag0 = int(round(peak * sub))
        out = np.zeros((len(self.index), t.size))
        for r, (a, e) in enumerate(zip(self.at, self.energy)):
            pos = np.rint((a + pad) * sub).astype(np.int64)
            ok = (pos >= 0) & (pos < t.size) & (e > 0)
            fine = np.bincount(pos[ok], weights=e[ok], minlength=t.size)
            full = np.convolve(fine, hf)
            out[r] = full[lag0: lag0 + t.size]
        return t, out

    def waveforms(self, prepared, *, gain: float = 1.0, lag: float = 0.0, responses=None) -> np.ndarray:
        """(K, S) the pulses on their records' samples, delayed by ``lag`` samples, times ``gain``."""
        t, resp = responses if responses is not None else self.responses(prepared)
        idx = np.arange(prepared.signal.shape[1]) - float(lag)
        return gain * np.stack([np.interp(idx, t, r, left=0.0, right=0.0) for r in resp])


def _sensor_for(p, i: int, base: Sensor) -> tuple[Sensor, np.ndarray]:
    """The sensor placed for pulse ``i`` (its origin, its direction) and the target point on its axis."""
    d = p.direction[i]
    end = p.bin0[i] + p.n_samples[i] * p.step[i]
    off = math.degrees(math.acos(min(1.0, max(-1.0, -d[2]))))
    az = math.degrees(math.atan2(-d[1], -d[0]))
    altitude = float(p.origin[i, 2] - end[2])
    if altitude <= 0:
        raise InputError(f"pulse {i}: its sensor (z {p.origin[i, 2]:.2f} m) is not above its record's end "
                         f"(z {end[2]:.2f} m): the pulses need an airborne geometry")
    return base.replace(altitude_m=altitude, off_nadir_deg=off, azimuth_deg=az % 360.0), end


def simulate_pulses(prepared, scene, index, *, simulator=None, photons: int = 4000, seed: int = 0,
                    max_order: int = 3, bin_ns: float = 0.1, fov_factor: float = 2.0, hotspot: bool = True,
                    outside: str = "error", progress: bool = False) -> SimulatedPulses:
    """Simulate pulses ``index`` as fired over ``scene`` (see the module docstring).

    Parameters
    ----------
    prepared : Prepared
    scene : voxlidar.scene.Scene
    index : (K,) int
    simulator : clsim.Simulator, optional
    photons : int
        Photons per pulse (next-event estimation: every photon adds to the waveform).
    seed : int
        Pulse ``i`` is seeded ``seed + i``: the same pulse gets the same photons in every fold.
    max_order : int
        Highest scattering order.
    bin_ns : float
        Fine time bin, ns.
    fov_factor : float
        Receiver field of view as a multiple of the beam divergence.
    hotspot : bool
        Single scattering returns along the path it came by, already free
        (:meth:`clsim.Simulator.run`): the attenuation that the echo weights
        measured is applied once, as real leaves do, not twice as a turbid
        medium would.
    outside : {"error", "skip"}
        A pulse whose beam leaves the scene's footprint: one clear error, or
        skipped (no energy; listed in ``SimulatedPulses.outside``).
    progress : bool

    Returns
    -------
    SimulatedPulses
    """
    import time

    from clsim.transport.simulator import Simulator

    p = prepared.pulses
    index = np.asarray(index, dtype=np.int64)
    sim = simulator or Simulator()
    base = Sensor(name=p.name, wavelength_nm=p.wavelength_nm, divergence_mrad=p.divergence_mrad,
                  fov_mrad=max(fov_factor * p.divergence_mrad, 1e-3), sampling_ghz=1.0 / p.dt_ns,
                  pulse_fwhm_ns=1.0)
    lo = scene.origin
    hi = scene.origin + scene.voxel_size * np.asarray(scene.shape)
    if outside not in ("error", "skip"):
        raise InputError(f"outside={outside!r} must be 'error' or 'skip'")
    at, energy, missed = [], [], []
    it = index
    if progress:
        from tqdm.auto import tqdm

        it = tqdm(index, desc="replay", unit="pulse", leave=False)
    t0 = time.perf_counter()
    for i in it:
        sensor, target = _sensor_for(p, int(i), base)
        if not (np.all(target[:2] >= lo[:2]) and np.all(target[:2] <= hi[:2])):
            if outside == "skip":
                missed.append(int(i))
                at.append(np.zeros(0))
                energy.append(np.zeros(0))
                continue
            raise InputError(f"pulse {int(i)} ends at x, y {target[:2].round(2).tolist()}, outside the scene "
                             f"({lo[:2].round(2).tolist()} .. {hi[:2].round(2).tolist()}): the scene must cover the "
                             "pulses replayed")
        res = sim.run(scene, sensor, photons=photons, seed=int(seed) + int(i), max_order=max_order, batches=1,
                      bin_ns=bin_ns, target=target, hotspot=hotspot)
        e = res.fine.sum(axis=(0, 1))
        centres = 0.5 * (res.fine_edges_ns[:-1] + res.fine_edges_ns[1:])
        S = sensor.position(target)
        t_rec0 = 2.0 * float(np.linalg.norm(p.bin0[i] - S)) / C_M_PER_NS
        per_sample = float(p.sample_time_ns()[i])
        at.append((centres - t_rec0) / per_sample)
        energy.append(e)
    return SimulatedPulses(index=index, at=at, energy=energy, seconds=time.perf_counter() - t0,
                           outside=np.asarray(missed, dtype=np.int64))


@dataclass(frozen=True)
class Calibration:
    """Gain (counts x samples per unit received energy) and time offset (samples) of a replay."""

    gain: float
    lag: float
    pulses: int

    def to_dict(self) -> dict:
        return {"gain": self.gain, "lag_samples": self.lag, "training_pulses": self.pulses}


#: the time offsets (samples) ``calibrate`` tries by default
LAGS = tuple(np.arange(-6.0, 6.01, 0.25))


def calibrate(prepared, simulated: SimulatedPulses, *, lags=LAGS) -> Calibration:
    """Fit the gain and the time offset on simulated training pulses.

    The offset maximises the median Pearson r between measured and simulated
    training records; the gain is the median ratio of their energies on the
    recorded samples.
    """
    from clsim.replay._scores import _pearson

    idx = simulated.index
    if len(idx) < 3:
        raise InputError(f"calibration needs at least 3 training pulses, got {len(idx)}")
    best, lag = -np.inf, 0.0
    resp = simulated.responses(prepared)
    for L in lags:
        w = simulated.waveforms(prepared, lag=float(L), responses=resp)
        rs = [_pearson(prepared.signal[i][prepared.mask[i]], w[k][prepared.mask[i]]) for k, i in enumerate(idx)]
        r = float(np.nanmedian(rs))
        if r > best:
            best, lag = r, float(L)
    # energies on the recorded samples, as the scores count them (not the light beyond the record's end)
    w = simulated.waveforms(prepared, lag=lag, responses=resp)
    e_sim = np.array([w[k][prepared.mask[i]].sum() for k, i in enumerate(idx)])
    e_meas = prepared.energy[idx]
    ok = e_sim > 0
    if len(simulated.outside):
        ok &= ~np.isin(idx, simulated.outside)
    if not ok.any():
        raise InputError("no simulated training pulse received any energy: the scene does not reach the pulses")
    return Calibration(gain=float(np.median(e_meas[ok] / e_sim[ok])), lag=lag, pulses=int(len(idx)))
