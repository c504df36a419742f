"""The error budget: simulated waveforms against the explicit-geometry reference.

For a synthetic tree the waveform a pulse would really record is known: the
mesh reference (:mod:`clsim.validation.meshref`) traces it against the leaves and
branches themselves.  A voxel model is then scored pulse by pulse:

- (a) the mesh reference,
- (b) a voxel scene of the mesh's exact LAD (``tree.truth_scene``): (a) vs (b)
  is the turbid-medium error (hot spot, clumping inside voxels),
- (c) the scene from the TLS pipeline (scan, register, classify, VoxLAD):
  (b) vs (c) is the estimation error.

Metrics (:func:`waveform_metrics`) use what a simulation knows exactly: the
ground return time (from the geometry) and the split of energy between
vegetation and ground (from the per-kind tallies).

Examples
--------
>>> p = default_pulses(crown_center=(0.0, 0.0), crown_radius=6.0)
>>> [q.name for q in p]
['nadir-centre', 'nadir-edge', 'oblique-centre', 'oblique-edge']
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from clsim.sensor import C_M_PER_NS, Sensor
from clsim.waveforms.metrics import pearson_r, relative_heights

__all__ = ["PulseSpec", "default_pulses", "waveform_metrics", "run_budget", "budget_table"]


@dataclass(frozen=True)
class PulseSpec:
    """One airborne pulse: where its axis meets the ground, and its direction."""

    name: str
    target: tuple
    off_nadir_deg: float = 0.0
    azimuth_deg: float = 0.0

    def sensor(self, base: Sensor) -> Sensor:
        return base.replace(off_nadir_deg=self.off_nadir_deg, azimuth_deg=self.azimuth_deg)


def default_pulses(*, crown_center=(0.0, 0.0), crown_radius: float = 6.0, off_nadir_deg: float = 15.0):
    """Four pulses: nadir and oblique, through the crown centre and near its edge."""
    cx, cy = float(crown_center[0]), float(crown_center[1])
    edge = (cx + 0.75 * crown_radius, cy)
    return [
        PulseSpec("nadir-centre", (cx, cy)),
        PulseSpec("nadir-edge", edge),
        PulseSpec("oblique-centre", (cx, cy), off_nadir_deg, 200.0),
        PulseSpec("oblique-edge", edge, off_nadir_deg, 200.0),
    ]


def waveform_metrics(result, reference, *, ground_time_ns: float) -> dict:
    """Score a simulated waveform against a reference on the same time grid.

    Parameters
    ----------
    result, reference : clsim.transport.simulator.SimulationResult
        Same sensor and time window (as the simulators make them).
    ground_time_ns : float
        Time of the ground return at the beam axis, ns.

    Returns
    -------
    dict
        ``r`` (Pearson), ``nrmse`` (RMSE over the reference peak), energy
        ratios ``total``, ``vegetation``, ``ground`` (simulated / reference, with
        their standard errors), ``veg_ground`` and ``ref_veg_ground`` (energy
        ratios), and ``drh50``, ``drh98`` (m, simulated minus reference).
    """
    t, w = result.time_ns, result.waveform
    rt, rw = reference.time_ns, reference.waveform
    ws = np.interp(rt, t, w, left=0.0, right=0.0)
    out = {"r": pearson_r(ws, rw), "nrmse": float(np.sqrt(np.mean((ws - rw) ** 2)) / max(rw.max(), 1e-300))}
    for kind in (None, "vegetation", "ground"):
        e, se = result.energy(kind=kind)
        er, ser = reference.energy(kind=kind)
        key = kind or "total"
        out[key] = e / er if er > 0 else float("nan")
        out[key + "_se"] = float(np.hypot(se / er, e * ser / er**2)) if er > 0 else float("nan")
    ev, eg = result.energy(kind="vegetation")[0], result.energy(kind="ground")[0]
    rv, rg = reference.energy(kind="vegetation")[0], reference.energy(kind="ground")[0]
    out["veg_ground"] = ev / eg if eg > 0 else float("inf")
    out["ref_veg_ground"] = rv / rg if rg > 0 else float("inf")
    rh = relative_heights(t, w, percentiles=(50, 98), ground_time_ns=ground_time_ns)
    rrh = relative_heights(rt, rw, percentiles=(50, 98), ground_time_ns=ground_time_ns)
    out["drh50"] = rh[50.0] - rrh[50.0]
    out["drh98"] = rh[98.0] - rrh[98.0]
    return out


def run_budget(tree, scenes: dict, base_sensor: Sensor, *, pulses=None, photons_mesh: int = 100_000,
               photons_voxel: int = 1_000_000, max_order: int = 3, seed: int = 1, simulator=None,
               hotspot_variants=(False, True), progress: bool = True) -> dict:
    """Simulate every pulse over the mesh and over each voxel scene, and score them.

    Parameters
    ----------
    tree : tlsvox.truth.synthetic.SyntheticTree
    scenes : dict {name: tlsvox.Scene}
        Voxel scenes to score, e.g. ``{"b: exact LAD": ..., "c: TLS pipeline": ...}``.
    base_sensor : Sensor
        Sensor; each pulse sets its own off-nadir angle and azimuth.
    pulses : list of PulseSpec, optional
        Default :func:`default_pulses` around the tree's crown.
    photons_mesh, photons_voxel : int
    max_order : int
    seed : int
    simulator : clsim.Simulator, optional
    hotspot_variants : tuple of bool
        Run each voxel scene with and/or without the hot-spot option.

    Returns
    -------
    dict
        ``rows`` (one dict per pulse x scene x variant), ``results`` (the
        SimulationResults by (pulse, label)), ``timings`` (seconds by label).
    """
    from tqdm.auto import tqdm

    from clsim.transport.simulator import Simulator
    from clsim.validation.meshref import MeshReferenceSimulator

    sim = simulator or Simulator()
    if pulses is None:
        r = tree.params.crown_radius if tree.params is not None else 3.0
        pulses = default_pulses(crown_center=tree.crown_center[:2], crown_radius=r)
    twin = next(iter(scenes.values()))
    results, rows, timings = {}, [], {}
    jobs = len(pulses) * (1 + len(scenes) * len(hotspot_variants))
    bar = tqdm(total=jobs, desc="error budget", unit="run", disable=not progress, leave=False)
    for pulse in pulses:
        sensor = pulse.sensor(base_sensor)
        t0 = time.perf_counter()
        ref = MeshReferenceSimulator().run(tree, sensor, photons=photons_mesh, seed=seed, max_order=max_order,
                                           target=pulse.target, twin=twin)
        timings["a: mesh"] = timings.get("a: mesh", 0.0) + time.perf_counter() - t0
        results[(pulse.name, "a: mesh")] = ref
        bar.update()
        ground_t = 2.0 * sensor.range_m / C_M_PER_NS
        for name, scene in scenes.items():
            for hot in hotspot_variants:
                label = f"{name}{' + hot spot' if hot else ''}"
                t0 = time.perf_counter()
                res = sim.run(scene, sensor, photons=photons_voxel, seed=seed, max_order=max_order,
                              target=pulse.target, hotspot=hot)
                timings[label] = timings.get(label, 0.0) + time.perf_counter() - t0
                results[(pulse.name, label)] = res
                row = {"pulse": pulse.name, "model": label, **asdict(pulse)}
                row.update(waveform_metrics(res, ref, ground_time_ns=ground_t))
                rows.append(row)
                bar.update()
    bar.close()
    return {"rows": rows, "results": results, "timings": timings, "pulses": pulses}


def budget_table(rows) -> str:
    """Markdown table of :func:`run_budget` rows."""
    head = ("| pulse | model | r | NRMSE | total E ratio | vegetation E ratio | ground E ratio | "
            "veg/ground (mesh) | dRH50 (m) | dRH98 (m) |")
    lines = [head, "|" + "---|" * 10]
    for r in rows:
        lines.append(
            f"| {r['pulse']} | {r['model']} | {r['r']:.3f} | {r['nrmse']:.3f} | "
            f"{r['total']:.3f} ± {r['total_se']:.3f} | {r['vegetation']:.3f} ± {r['vegetation_se']:.3f} | "
            f"{r['ground']:.3f} ± {r['ground_se']:.3f} | {r['veg_ground']:.2f} ({r['ref_veg_ground']:.2f}) | "
            f"{r['drh50']:+.2f} | {r['drh98']:+.2f} |")
    return "\n".join(lines)
