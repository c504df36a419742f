"""clsim against mitransient (transient Mitsuba 3) on the same scenes, in one run; writes
docs/bench/mitransient.md.

    bash benchmarks/peers/setup_mitransient.sh                 # once: the peer's own venv
    flock /tmp/voxlidar-bench.lock .venv/bin/python benchmarks/bench_mitransient.py [--quick]

The peer runs in its own environment (``.peer-venv/mitransient``, made by the set-up
script: mitransient 1.3.1, Mitsuba 3.9, Dr.Jit 1.5 and Debian's libLLVM 19, which Dr.Jit's
LLVM back end needs) as a long-lived subprocess (benchmarks/peers/mitransient_worker.py);
histograms come back as .npz files.  Runs alternate between the two programs (and
between clsim's estimator variants) at every sample count, so a change of machine load
hits both alike.

Scenes
- ``slab``: ``homogeneous_layer(lad=1, thickness=2, base_height=2, width=20, voxel_size=0.5)``
  (and 0.1 m voxels for clsim), spherical leaves R 0.437 / T 0.478, Lambertian ground 0.30,
  preset ``ahab-chiroptera-i`` at 360 m, nadir.  For Mitsuba: a homogeneous medium box
  with sigma_t = G u = 0.5 /m, albedo R + T = 0.915 and the *same* phase function
  (spherical bi-Lambertian leaves scatter like a rotation-invariant medium: Ross's
  area scattering phase function, tabulated for Mitsuba's ``tabphase``).
- ``oak``: the synthetic oak's exact leaf area (``make_tree(seed=0).truth_scene(0.2)``)
  with spherical leaves and no wood in both programs; for Mitsuba a heterogeneous medium
  on the same voxel grid (nearest-neighbour lookup), sigma_t = LAD / 2.

Measured for each set-up: samples (photons, camera paths) per second; the relative L2
error of the 0.25 ns return histogram (all orders <= 3, NEE) against the set-up's own
high-sample reference, at several sample counts; error = a t^-b fitted in log-log, and
the time to 1 % error from the fit.  The closed forms of docs/method.md section 8 are
checked for both programs on the slab (single scattering): ground two-way attenuation
exp(-2 sigma_t H), single-scattering canopy energy, decay 2 sigma_t.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _bench import write_page  # noqa: E402
from scipy.integrate import quad

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from clsim.sensor import C_M_PER_NS, Sensor  # noqa: E402
from clsim.transport.setup import prepare_run, prepare_scene  # noqa: E402
from clsim.transport.simulator import Simulator  # noqa: E402
from clsim.validation import testscenes  # noqa: E402

PEER_ENV = ROOT / ".peer-venv" / "mitransient"
R_L, T_L, RHO_G = 0.437, 0.478, 0.30
MAX_ORDER = 3
BIN_NS = 0.25
OLD = dict(tight=False, leaf_avg=False, qmc=False, uniform=False)
NO_UNIFORM = dict(uniform=False)  # the voxel-by-voxel walk (uniform bricks not crossed in one segment)


# -- physics shared by both programs ----------------------------------------------------------
def ross_phase(n: int = 1025) -> np.ndarray:
    """Phase function (1/sr, integral 1) of spherical bi-Lambertian leaves on a uniform grid of
    cos(beta) in [-1, 1], beta between the incoming and outgoing propagation directions:
    Gamma / (pi omega G) with Ross's Gamma (docs/method.md, "Variance reduction")."""
    c = np.linspace(-1.0, 1.0, n)
    b = np.arccos(c)
    gamma_pi = ((R_L + T_L) * (np.sin(b) - b * c) / (3 * np.pi) + T_L * c / 3) / np.pi
    return gamma_pi / ((R_L + T_L) * 0.5)


def closed_forms(R: float, top: float, H: float, sigma: float) -> dict:
    """Single scattering at nadir, turbid return, 1/r^2 kept: canopy / ground energy ratio,
    ground two-way attenuation, decay rate with depth."""
    # leaf collisions at depth z: density sigma e^(-sigma z), backscatter weight E[f] = 2 R / (3 pi)
    can = quad(lambda z: sigma * 2 * R_L / (3 * np.pi) * np.exp(-2 * sigma * z) / (top + z) ** 2, 0, H)[0]
    gr = RHO_G / np.pi * np.exp(-2 * sigma * H) / R**2
    return dict(ratio=can / gr, two_way=np.exp(-2 * sigma * H), decay=2 * sigma)


def checks_from_hist(hist, edges_ns, R, top, H, bare=None):
    """(canopy/ground ratio, ground/bare, decay) of a single-scattering histogram."""
    mid = 0.5 * (edges_ns[:-1] + edges_ns[1:]) * C_M_PER_NS / 2  # one-way range, m
    ground_sel = mid > R - 0.5 * (R - top - H)
    can_sel = (mid >= top) & (mid < top + H)
    can, gr = hist[~ground_sel].sum(), hist[ground_sel].sum()
    z = mid - top
    sel = can_sel & (z > 0.1) & (z < H - 0.1) & (hist > 0)
    y = np.log(hist[sel] * (mid[sel] / top) ** 2)
    decay = -np.polyfit(z[sel], y, 1)[0]
    out = dict(ratio=can / gr, decay=decay)
    if bare is not None:
        out["two_way"] = gr / bare[ground_sel].sum()
    return out


# -- the peer -------------------------------------------------------------------------------
class Peer:
    """The mitransient worker in its own venv; None-like when it cannot start (reason kept)."""

    def __init__(self, env: Path, tmp: Path, python: str | None = None, variant: str = "llvm_ad_mono"):
        self.reason = None
        self.proc = None
        self.tmp = tmp
        self.variant = variant
        environ = dict(os.environ, DRJIT_CACHE_DIR=str(tmp / "drjit-cache"), MITRANSIENT_VARIANT=variant)
        if python:  # an interpreter that imports mitransient as it is (a GPU machine's own Python)
            py = Path(python)
        else:
            py = env / "bin" / "python"
            llvm = env / "llvm-path.txt"
            if not py.exists() or not llvm.exists():
                self.reason = f"no peer environment at {env}: run `bash benchmarks/peers/setup_mitransient.sh`"
                return
            environ["DRJIT_LIBLLVM_PATH"] = llvm.read_text().strip()
            environ.pop("PYTHONPATH", None)
        self.proc = subprocess.Popen([str(py), str(ROOT / "benchmarks" / "peers" / "mitransient_worker.py")],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=environ)
        self.versions = None

    def ask(self, msg: dict) -> dict:
        self.proc.stdin.write(json.dumps(msg) + "\n")
        self.proc.stdin.flush()
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError("the mitransient worker stopped (see its stderr above)")
        return json.loads(line)

    def scene(self, spec: dict, name: str = ""):
        self.versions = self.ask({"cmd": "scene", "name": name, "spec": spec})

    def render(self, spp: int, seed: int, name: str = ""):
        out = self.tmp / "peer.npz"
        r = self.ask({"cmd": "render", "name": name, "spp": int(spp), "seed": int(seed), "out": str(out)})
        return np.load(out)["hist"], r["seconds"]

    def close(self):
        if self.proc is not None:
            try:
                self.ask({"cmd": "quit"})
            except (RuntimeError, BrokenPipeError, json.JSONDecodeError):
                pass
            self.proc.wait(timeout=30)


# -- scenes ---------------------------------------------------------------------------------
def slab_scene(voxel):
    return testscenes.homogeneous_layer(lad=1.0, thickness=2.0, base_height=2.0, width=20.0,
                                        voxel_size=voxel)


def oak_scene(voxel):
    from tlsvox.truth.synthetic import make_tree
    from voxlidar.leaf_orientation import LeafAngle
    from voxlidar.scene import Scene

    s = make_tree(seed=0).truth_scene(voxel)
    s = Scene(origin=s.origin, voxel_size=s.voxel_size, shape=s.shape, ijk=s.ijk, lad=s.lad,
              wood=np.zeros(len(s.lad)), leaf_angle=LeafAngle("spherical"), leaf_azimuth="uniform",
              crown_center=s.crown_center, ground_z=s.ground_z, meta=dict(s.meta, bench="oak, spherical, no wood"))
    return testscenes.set_optics(s, 1064, leaf=(R_L, T_L), ground=(RHO_G, 0.0))


def peer_spec(scene, setup, end, *, max_depth, tmp: Path, sampler="independent", bare=False):
    """Translate a clsim scene and run set-up into the worker's spec (world frame with the beam's
    target at the origin, the ground at z = 0)."""
    p = setup.p
    target = np.asarray(setup.settings["target"])
    sensor = setup.sensor
    edges = setup.edges_ns
    spec = dict(sensor_z=float(setup.settings["sensor_position"][2] - target[2]), end=end,
                beam_half_rad=0.5e-3 * sensor.divergence_mrad, fov_half_rad=1e-3 * sensor.fov_mrad,
                ground_R=RHO_G, albedo=R_L + T_L, phase=ross_phase().tolist(), max_depth=max_depth,
                start_opl=float(edges[0] * C_M_PER_NS), bin_opl=float(BIN_NS * C_M_PER_NS),
                nbins=int(p["nbins"]), sampler=sampler)
    if bare:
        spec.update(slab=[-0.01, 0.01, -0.01, 0.01, -5.0, -4.99], sigma_t=1e-9)  # a speck under the ground
        return spec
    lo = scene.origin - target
    if scene.meta.get("testscene") == "homogeneous_layer":
        hi = lo + scene.voxel_size * np.asarray(scene.shape)
        base = float(scene.meta["base_height"])
        spec.update(slab=[lo[0], hi[0], lo[1], hi[1], base, base + float(scene.meta["thickness"])],
                    sigma_t=0.5 * float(scene.meta["lad"]))
    else:
        # the grid cropped to the voxels with leaves: mitransient drops the path length of
        # the null-collision segments in a heterogeneous medium (null_collision_section), so
        # every empty voxel layer in the medium's box moves the returns below it early
        ijk = scene.ijk[scene.lad > 0]
        k0, k1 = ijk.min(axis=0), ijk.max(axis=0) + 1
        dense = np.zeros(tuple(k1 - k0), np.float32)
        i, j, k = (ijk - k0).T
        dense[i, j, k] = 0.5 * scene.lad[scene.lad > 0]
        path = tmp / "sigma_t.npy"
        np.save(path, np.ascontiguousarray(dense.transpose(2, 1, 0)))  # [z, y, x]
        spec.update(grid=str(path), grid_origin=(lo + k0 * scene.voxel_size).tolist(),
                    grid_voxel=float(scene.voxel_size))
    return spec


# -- measurement ------------------------------------------------------------------------------
def rel_l2(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def fit(points):
    """Time to 1 % error from (wall time, error) points in order of sample count.

    ``t1``: log-log interpolation between the two consecutive points that bracket 1 %
    (the local err = a t^-b through them; where the later point took no longer, as when
    fixed costs dominate, the later point's time, "read off"), else the power law fitted
    to all points with 1e-4 < err < 0.5 (extrapolated, ``how`` says which); ``b`` that fit's
    exponent; ``t1_half`` the fixed-exponent err = c / sqrt(t) fit (plain Monte Carlo)."""
    pts = np.array([(t, e) for t, e in points if 1e-4 < e < 0.5 and t > 0])
    if len(pts) < 2:
        return dict(a=np.nan, b=np.nan, t1=np.nan, t1_half=np.nan, how="no fit")
    lt, le = np.log(pts[:, 0]), np.log(pts[:, 1])
    slope, icept = np.polyfit(lt, le, 1)
    b = -slope
    a = np.exp(icept)
    c = float(np.exp(np.median(le + 0.5 * lt)))
    out = dict(a=a, b=b, t1=(a / 0.01) ** (1 / b) if b > 0 else np.nan, t1_half=(c / 0.01) ** 2,
               how="extrapolated")
    for (t0, e0), (t1, e1) in zip(pts[:-1], pts[1:]):
        if e0 >= 0.01 > e1:
            if t1 > t0:
                k = np.log(e0 / e1) / np.log(t1 / t0)
                out.update(t1=t0 * (e0 / 0.01) ** (1 / k), how="interpolated")
            else:  # run time flat (fixed costs): the first time already under 1 %
                out.update(t1=t1, how="read off")
            break
    return out


def run_scene(args, name, scene_fn, voxels, peer, lines, tmp):
    sensor = Sensor.preset("ahab-chiroptera-i")
    kw = dict(bin_ns=BIN_NS, max_order=MAX_ORDER)
    scenes = {v: scene_fn(v) for v in voxels}
    scene = scenes[voxels[0]]
    setup = prepare_run(scene, sensor, photons=1, seed=0, **kw)
    # clsim set-ups: the new default, the estimator before issue 16 (all features off), and
    # each feature off alone (on the first voxel size); the default on other voxel sizes
    # each scene prepared once (bricks, tables; uploaded at the first run), as the peer loads
    # its scene once: the timed calls are the runs themselves
    prepared = {v: prepare_scene(scenes[v], wavelength_nm=sensor.wavelength_nm) for v in voxels}
    sims = {}
    for v in voxels:
        sims[f"clsim {v:g} m"] = (Simulator(), scenes[v], prepared[v])
        if args.variants:
            sims[f"clsim {v:g} m, no uniform"] = (Simulator(features=NO_UNIFORM), scenes[v], prepared[v])
    if args.variants:
        sims[f"clsim {voxels[0]:g} m, before (no feature)"] = (Simulator(features=OLD), scene, prepared[voxels[0]])
        for f in ("qmc", "leaf_avg", "tight"):
            sims[f"clsim {voxels[0]:g} m, no {f}"] = (Simulator(features={f: False}), scene, prepared[voxels[0]])
    for s, sc, prep in sims.values():  # build every program before anything is timed
        s.run(sc, sensor, photons=2000, seed=0, scene_setup=prep, **kw)
    ref = Simulator().run(scene, sensor, photons=args.ref_photons, seed=987654, **kw).fine.sum(axis=(0, 1))
    refs = {k: ref for k in sims}
    peers = []
    if peer.proc is not None:
        for end, sampler in args.peer_setups:
            peers.append((f"mitransient {end} end, {sampler}", end, sampler))
    peer_refs = {}
    for label, end, sampler in peers:
        peer.scene(peer_spec(scene, setup, end, max_depth=MAX_ORDER + 1, tmp=tmp, sampler=sampler), name=label)
        h = [peer.render(args.ref_spp, 1000 + i, name=label)[0] for i in range(args.ref_chunks)]
        peer_refs[label] = np.mean(h, axis=0)
    rows = {k: [] for k in list(sims) + [p[0] for p in peers]}
    for n in args.series:
        for label, _, _ in peers:  # Dr.Jit compiles per launch size: once, untimed
            peer.render(n, 1, name=label)
        for rep in range(args.repeats):
            for label, (s, sc, prep) in sims.items():
                t0 = time.perf_counter()
                r = s.run(sc, sensor, photons=n, seed=10_000 + 97 * n + rep, scene_setup=prep, **kw)
                dt = time.perf_counter() - t0
                rows[label].append((n, dt, rel_l2(r.fine.sum(axis=(0, 1)), refs[label])))
            for label, end, sampler in peers:
                h, dt = peer.render(n, 20_000 + 97 * n + rep, name=label)
                rows[label].append((n, dt, rel_l2(h, peer_refs[label])))
            print(f"  {name} n={n:,} rep {rep}: " + ", ".join(
                f"{k}: {rows[k][-1][1]:.2f} s {100 * rows[k][-1][2]:.2f} %" for k in rows), flush=True)
    summary = {}
    for label, pts in rows.items():
        by_n = {}
        for n, dt, e in pts:
            by_n.setdefault(n, []).append((dt, e))
        med = [(n, statistics.median(d for d, _ in v), float(np.sqrt(np.mean([e * e for _, e in v]))))
               for n, v in sorted(by_n.items())]
        f = fit([(t, e) for _, t, e in med])
        top_n = max(by_n)
        sps = top_n / statistics.median(d for d, _ in by_n[top_n])
        summary[label] = dict(series=med, sps=sps, **f)
    # same physics: the references' shapes (each scaled to unit sum) should nearly agree
    unit = lambda h: h / h.sum()  # noqa: E731
    for label in peer_refs:
        summary[label]["shape_vs_clsim"] = rel_l2(unit(peer_refs[label]), unit(ref))
    return summary, setup, peers


def null_collision_section(peer, lines, tmp):
    """The peer's heterogeneous medium keeps time through null collisions, or not: the
    ground return under a nearly empty 4 m box of voxels, with and without one dense
    voxel in a far corner (which only raises the majorant, so adds null collisions)."""
    sensor = Sensor.preset("ahab-chiroptera-i")
    setup = prepare_run(slab_scene(0.5), sensor, photons=1, seed=0, bin_ns=BIN_NS, max_order=1)
    mid = 0.5 * (setup.edges_ns[:-1] + setup.edges_ns[1:]) * C_M_PER_NS / 2
    rows = []
    for hot in (0.0, 5.0, 50.0):
        sig = np.full((8, 40, 40), 1e-6, np.float32)  # [z, y, x]: 20 m x 20 m x 4 m from 2 m up
        sig[0, 0, 0] = max(hot, 1e-6)
        np.save(tmp / f"null{hot:g}.npy", sig)
        spec = peer_spec(slab_scene(0.5), setup, "laser", max_depth=2, tmp=tmp)
        spec.pop("slab")
        spec.pop("sigma_t")
        spec.update(grid=str(tmp / f"null{hot:g}.npy"), grid_origin=[-10.0, -10.0, 2.0], grid_voxel=0.5)
        peer.scene(spec, name=f"null{hot:g}")
        h, _ = peer.render(1 << 16, 3, name=f"null{hot:g}")
        rows.append(f"| {hot:g} | {np.sum(h * mid) / h.sum():.3f} | {np.sum(h * mid) / h.sum() - sensor.range_m:+.3f} |")
    lines += ["### The peer's heterogeneous medium loses time in null collisions", "",
              "Ground return (range centroid, m) under a nearly empty 20 x 20 x 4 m voxel box (sigma_t 1e-6 /m) "
              f"from 2 m to 6 m above the ground, ground at {sensor.range_m:.3f} m; one voxel in the box's far "
              "corner, nowhere near the beam, made dense: it changes only the medium's majorant.", "",
              "| corner voxel sigma_t (1/m) | ground return range (m) | error (m) |", "|---|---|---|", *rows, "",
              "Null collisions should change nothing but noise. With a majorant the returns come up to 2 m "
              "early: mitransient 1.3.1's `transient_prbvolpath` does not count the path crossed between null "
              "collisions on the way in (here the box's 4 m: 2 m of range). Every heterogeneous medium has them (its majorant is the densest voxel), so the oak, "
              "which Mitsuba can only take as a grid, cannot be matched with this peer; its table below compares "
              "speed and noise only. The slab is a homogeneous medium, where no null collision occurs.", ""]


def closed_form_section(args, peer, lines, tmp):
    """Single scattering on the slab, both programs, against the closed forms."""
    sensor = Sensor.preset("ahab-chiroptera-i")
    scene = slab_scene(0.5)
    kw = dict(bin_ns=BIN_NS, max_order=1)
    setup = prepare_run(scene, sensor, photons=1, seed=0, **kw)
    R = sensor.range_m
    top = R - 4.0
    cf = closed_forms(R, top, 2.0, 0.5)
    res = {}
    r = Simulator().run(scene, sensor, photons=args.cf_photons, seed=5, **kw)
    h = r.fine.sum(axis=(0, 1))
    bare = Simulator().run(testscenes.ground_only(width=20.0), sensor, photons=20_000, seed=6, **kw)
    # clsim's bare ground is its closed form (A/R^2) rho/pi exactly; measured the same way here
    hb = np.zeros_like(h)
    gsel = np.argmin(np.abs(0.5 * (setup.edges_ns[:-1] + setup.edges_ns[1:]) * C_M_PER_NS / 2 - R))
    hb[gsel] = bare.energy(kind="ground")[0]
    res["clsim"] = checks_from_hist(h, setup.edges_ns, R, top, 2.0, bare=hb)
    if peer.proc is not None:
        for end in ("laser", "receiver"):
            peer.scene(peer_spec(scene, setup, end, max_depth=2, tmp=tmp, bare=True), name="cf bare")
            hb = np.mean([peer.render(args.cf_spp, 70 + i, name="cf bare")[0] for i in range(2)], axis=0)
            peer.scene(peer_spec(scene, setup, end, max_depth=2, tmp=tmp), name="cf")
            hp = np.mean([peer.render(args.cf_spp, 80 + i, name="cf")[0] for i in range(2)], axis=0)
            res[f"mitransient {end} end"] = checks_from_hist(hp, setup.edges_ns, R, top, 2.0, bare=hb)
    lines += ["### Closed forms (slab, single scattering, nadir)", "",
              f"sigma_t = G u = 0.5 /m, H = 2 m, canopy top at {top:g} m, ground at {R:g} m; the canopy "
              "integral keeps 1/r^2 across the layer (docs/method.md section 8). "
              f"clsim {args.cf_photons:,} photons; mitransient 2 x {args.cf_spp:,} samples per end "
              "(and a bare-ground render for the two-way attenuation).", "",
              "| program | canopy / ground | rel. to closed form | ground / bare ground | rel. | decay (1/m) | rel. |",
              "|---|---|---|---|---|---|---|",
              f"| closed form | {cf['ratio']:.4f} | | {cf['two_way']:.5f} | | {cf['decay']:.3f} | |"]
    for k, v in res.items():
        lines.append(f"| {k} | {v['ratio']:.4f} | {100 * (v['ratio'] / cf['ratio'] - 1):+.2f} % | "
                     f"{v['two_way']:.5f} | {100 * (v['two_way'] / cf['two_way'] - 1):+.2f} % | "
                     f"{v['decay']:.3f} | {100 * (v['decay'] / cf['decay'] - 1):+.2f} % |")
    lines.append("")
    return res


def write_scene(lines, name, desc, summary, peers, shape_note="beam and field-of-view differences"):
    lines += [f"### {name}", "", desc, "",
              "| set-up | samples/s | error = a t^-b: b | time to 1 % (fit) | time to 1 % (b = 1/2) | errors at the sample counts |",
              "|---|---|---|---|---|---|"]
    for label, s in summary.items():
        errs = ", ".join(f"{n:,}: {100 * e:.2f} % in {t:.3f} s" for n, t, e in s["series"])
        lines.append(f"| {label} | {s['sps'] / 1e6:.2f} M | {s['b']:.2f} | {s['t1']:.3g} s ({s['how']}) | "
                     f"{s['t1_half']:.3g} s | {errs} |")
    clsim_keys = [k for k in summary if k.startswith("clsim") and "," not in k]
    peer_keys = [k for k in summary if k.startswith("mitransient")]
    lines.append("")
    for k in peer_keys:
        lines.append(f"- {k}: reference's shape (unit sum) against clsim's: relative L2 "
                     f"{100 * summary[k]['shape_vs_clsim']:.1f} % ({shape_note}).")
    if peer_keys:
        best_sps = max(peer_keys, key=lambda k: summary[k]["sps"])
        best_t1 = min(peer_keys, key=lambda k: summary[k]["t1"] if np.isfinite(summary[k]["t1"]) else np.inf)
        for k in clsim_keys:
            lines.append(f"- {k}: samples/s {summary[k]['sps'] / summary[best_sps]['sps']:.2f} x "
                         f"mitransient's fastest ({best_sps}); time to 1 % "
                         f"{summary[best_t1]['t1'] / summary[k]['t1']:.2f} x faster than mitransient's best "
                         f"({best_t1}, {summary[best_t1]['t1']:.3g} s) (goals: 1.5 x and 2 x).")
    for k in clsim_keys:
        if f"{k}, no uniform" in summary:
            u = summary[f"{k}, no uniform"]
            lines.append(f"- {k} against the voxel-by-voxel walk (`uniform` off), same run: samples/s "
                         f"{summary[k]['sps'] / u['sps']:.2f} x, time to 1 % {u['t1'] / summary[k]['t1']:.2f} x shorter.")
    before = [k for k in summary if k.endswith("before (no feature)")]
    if before and clsim_keys:
        k0 = clsim_keys[0]
        lines.append(f"- issue 16's estimator against the one before it (all features off), same code and run: "
                     f"time to 1 % {summary[before[0]]['t1'] / summary[k0]['t1']:.2f} x shorter; samples/s "
                     f"{summary[k0]['sps'] / summary[before[0]]['sps']:.2f} x.")
        for f in ("qmc", "leaf_avg", "tight"):
            kk = [k for k in summary if k.endswith(f"no {f}")]
            if kk:
                lines.append(f"  - without `{f}` alone: time to 1 % {summary[kk[0]]['t1'] / summary[k0]['t1']:.2f} x "
                             f"the default's, samples/s {summary[kk[0]]['sps'] / summary[k0]['sps']:.2f} x.")
    lines.append("")


def profile_section(args, lines):
    """Where the voxel walk costs: the slab at 0.5, 0.25 and 0.1 m voxels, the default estimator."""
    sensor = Sensor.preset("ahab-chiroptera-i")
    kw = dict(bin_ns=BIN_NS, max_order=MAX_ORDER)
    sims = {True: Simulator(), False: Simulator(features=NO_UNIFORM)}
    n = args.profile_photons
    rows = []
    for v in (0.5, 0.25, 0.1):
        sc = slab_scene(v)
        for s in sims.values():
            s.run(sc, sensor, photons=2000, seed=0, **kw)
        for hot, uni in ((False, True), (True, True), (False, False)):
            sim = sims[uni]
            walls, kern, res = [], [], None
            for rep in range(3):
                t0 = time.perf_counter()
                res = sim.run(sc, sensor, photons=n, seed=500 + rep, hotspot=hot, **kw)
                walls.append(time.perf_counter() - t0)
                kern.append(res.elapsed_s)
            t_small = statistics.median(
                [sim.run(sc, sensor, photons=256, seed=9, hotspot=hot, **kw).elapsed_s for _ in range(3)])
            st = {k: res.stat(k)[0] for k in ("voxel_steps", "walk_steps", "events", "shadow_rays")}
            wall, k = statistics.median(walls), statistics.median(kern)
            rows.append((v, hot, uni, n / wall, st["voxel_steps"] / n, st["walk_steps"] / n, st["events"] / n,
                         st["shadow_rays"] / n, 1e9 * k / st["walk_steps"], wall - k, t_small, n / k))
    lines += ["### Where the voxel walk costs (slab, clsim default estimator)", "",
              f"{n:,} photons, median of 3 runs, `max_order=3`; `hotspot=True` drops the order-1 shadow "
              "rays (their return path is the free incoming one), so the difference between the two rows of "
              "a voxel size is the cost of those shadow walks; `uniform` off walks voxel by voxel through the "
              "uniform bricks instead of crossing each in one segment (docs/method.md, \"Uniform bricks\"). "
              "Voxel steps count the voxels the walk crosses (a segment counts its voxels); walk steps what "
              "it does (a voxel, an empty brick, a uniform brick's segment). ns/walk step = kernel seconds "
              "/ walk steps (all the kernel's work divided by its steps); host = wall - kernel (set-up, "
              "buffers, digitising).", "",
              "| voxel | hotspot | uniform | photons/s (wall) | photons/s (kernel) | voxel steps / photon | "
              "walk steps / photon | events / photon | shadow rays / photon | ns per walk step | host s | "
              "kernel s for 256 photons |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for v, hot, uni, ps, sp, wp, ev, sh, ns, host, small, pk in rows:
        lines.append(f"| {v:g} m | {hot} | {uni} | {ps / 1e6:.2f} M | {pk / 1e6:.2f} M | {sp:.1f} | {wp:.1f} | "
                     f"{ev:.2f} | {sh:.2f} | {ns:.1f} | {host:.3f} | {small:.4f} |")
    pick = {(r[0], r[1], r[2]): r for r in rows}
    r5, r1, r1w = pick[(0.5, False, True)], pick[(0.1, False, True)], pick[(0.1, False, False)]
    lines += ["", f"From 0.5 m to 0.1 m voxels the walk steps per photon grow {r1[5] / r5[5]:.1f} x "
              f"(voxel by voxel: {r1w[5] / pick[(0.5, False, False)][5]:.1f} x); photons/s (kernel) fall "
              f"{r5[11] / r1[11]:.1f} x. Crossing the uniform bricks in one segment cuts the walk steps at 0.1 m "
              f"{r1w[5] / r1[5]:.1f} x and makes the kernel {r1[11] / r1w[11]:.2f} x faster there. What is left "
              "at 0.1 m: a brick is 0.8 m wide, so an oblique path still takes a segment per brick it "
              "crosses, and the host's share per run (the fingerprint of the scene's arrays that keeps its "
              "bricks cached, the histogram's transfer).", ""]


DIFFERENCES = """### Where the physics differs, and what was matched

- **Medium and phase function: matched.** Spherical bi-Lambertian leaves with uniform
  azimuths scatter like a rotation-invariant turbid medium: extinction G u = u/2 in every
  direction, albedo R + T, and the phase function Ross's Gamma(beta) / (pi omega G), which
  Mitsuba receives as a 1025-value `tabphase` (linear in cos beta; 0.1 % from the formula
  at worst). The orientation of `tabphase`'s cosine was verified with the single-scattering
  canopy energy (the reversed table misses it by 9 %). The oak's voxels become a
  `heterogeneous` medium on the same grid with nearest-neighbour lookup; clsim's oak uses
  spherical leaves and no wood for this comparison (its default oak has uniform leaf
  inclinations and bark, which Mitsuba's isotropic media cannot express).
- **Beam: differs.** clsim's beam is Gaussian (1/e^2 half angle 0.5 mrad). Mitsuba has no
  Gaussian emitter or camera: tracing from the laser end the camera is one square pixel
  whose side (0.87 mrad) gives the same per-axis spread; tracing from the receiver end the
  laser is a `spot` light, a uniform cone of 0.5 mrad half angle (same per-axis spread).
- **Field of view: differs slightly.** clsim tests a 1 mrad cone on the offset from the
  axis; Mitsuba's receiver is a `spot` cone (laser end) or a square pixel of the same solid
  angle (receiver end). Mitsuba tests cone edges on a float32 cosine, which at 1 mrad is
  1 - 5e-7, a few float32 steps from 1: its cones are quantised (docs/method.md section 4),
  one reason the receiver-end renders return a different multiple-scattering share.
- **Time:** both bin the path length in 0.25 ns (0.0749 m) bins over the same window; no
  pulse shape is applied (the fine histograms are compared).
- **Time:** mitransient counts a camera path's length from the camera's near plane: the
  near clip is Mitsuba's default 1 cm (5 mm of range early; at 1 m every peer return came
  0.5 m early, which the closed-form check of the decay caught).
- **Estimators:** both use next-event estimation at every scattering; Mitsuba's homogeneous
  medium samples free paths analytically and its heterogeneous medium by delta tracking
  against one global majorant (the oak's densest voxel, about 16 /m, everywhere in the
  12 m box; Mitsuba 3.9's `heterogeneous` plugin rejects a `majorant_resolution_factor`);
  clsim by regular tracking voxel by voxel (a brick of one value in one segment) with the
  tight majorant G u, the leaf-averaged
  next-event weight and the lattice first free path (docs/method.md, "Variance
  reduction"). Mitsuba's error is measured against its own reference at each end (the
  ends differ in their cone quantisation). Mitsuba's `ldsampler` (low-discrepancy) was
  tried from the laser end: its error stalled at 1.3 to 3.8 % on the slab between 16k and
  262k samples (`--quick` run), so it is left out.
"""


def command_line(argv) -> str:
    """The command that wrote the page (the lock and interpreter as a user types them on this machine)."""
    import shlex
    import sys

    rest = " ".join(shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv))
    return ("flock /tmp/voxlidar-bench.lock .venv/bin/python benchmarks/bench_mitransient.py " + rest).strip()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "mitransient.md"))
    ap.add_argument("--peer-env", default=str(PEER_ENV))
    ap.add_argument("--peer-python", default=None,
                    help="run the peer with this interpreter (with mitransient importable) instead of "
                         "--peer-env's; PYTHONPATH is passed on")
    ap.add_argument("--peer-variant", default="llvm_ad_mono",
                    help="Mitsuba variant of the peer: llvm_ad_mono (CPU) or cuda_ad_mono (NVIDIA GPU)")
    ap.add_argument("--scale", type=int, default=1,
                    help="references this many times larger, and the series extended by factors of 4 up to "
                         "this many times its largest count (a GPU needs larger runs to be timed)")
    ap.add_argument("--quick", action="store_true", help="fewer samples (a few minutes)")
    ap.add_argument("--scenes", default="slab,oak")
    ap.add_argument("--no-profile", dest="profile", action="store_false",
                    help="skip the voxel-walk profile")
    ap.add_argument("--no-variants", dest="variants", action="store_false",
                    help="skip clsim's estimator variants (each feature off)")
    ap.add_argument("--dump-slab-spec", default=None, metavar="JSON",
                    help="write the peer's slab spec (laser end, max_depth 4) for peers/mitransient_plain.py and stop")
    args = ap.parse_args(argv)
    if args.dump_slab_spec:
        from clsim.sensor import Sensor
        from clsim.transport.setup import prepare_run

        with tempfile.TemporaryDirectory() as tmp:
            spec = peer_spec(slab_scene(0.5), prepare_run(slab_scene(0.5), Sensor.preset("ahab-chiroptera-i"),
                                                          photons=1, seed=0, bin_ns=BIN_NS, max_order=MAX_ORDER),
                             "laser", max_depth=MAX_ORDER + 1, tmp=Path(tmp))
        Path(args.dump_slab_spec).write_text(json.dumps(spec))
        print(f"wrote {args.dump_slab_spec}")
        return 0
    q = args.quick
    args.series = [1 << 12, 1 << 14, 1 << 16, 1 << 18] if q else [1 << 12, 1 << 14, 1 << 16, 1 << 18, 1 << 20]
    args.repeats = 2
    args.ref_photons = 4_000_000 if q else 16_000_000
    args.ref_spp = 1 << 21 if q else 1 << 22
    args.ref_chunks = 1
    args.cf_photons = 1_000_000 if q else 4_000_000
    args.cf_spp = 1 << 20 if q else 1 << 22
    args.profile_photons = 1 << 17 if q else 1 << 19
    for k in ("ref_photons", "ref_spp", "cf_photons", "cf_spp", "profile_photons"):
        setattr(args, k, getattr(args, k) * args.scale)
    top = args.series[-1]
    while args.series[-1] * 4 <= top * args.scale:  # the same small counts (1 % is crossed there), then larger
        args.series.append(args.series[-1] * 4)
    # Mitsuba's `ldsampler` was tried as a third set-up: its error stalled at 1.3-3.8 % on the slab
    # from 16k to 262k samples (quick run), so it is left out
    args.peer_setups = [("laser", "independent"), ("receiver", "independent")]
    load = os.getloadavg()[0]
    t_start = time.time()
    with tempfile.TemporaryDirectory(prefix="bench-mitransient-") as td:
        tmp = Path(td)
        peer = Peer(Path(args.peer_env), tmp, python=args.peer_python, variant=args.peer_variant)
        lines = ["## clsim against mitransient (transient Mitsuba 3)", "",
                 f"Written by `{command_line(argv)}` on {time.strftime('%Y-%m-%d %H:%M')}; "
                 f"{platform.processor() or platform.machine()}, {os.cpu_count()} logical CPUs, "
                 f"load average {load:.1f} at start (runs alternate "
                 "between the programs at every sample count so the ratios stay fair, absolute speeds "
                 "are lower bounds). Peer set-up: `bash benchmarks/peers/setup_mitransient.sh`.", ""]
        try:
            if peer.proc is not None:
                spec = peer_spec(slab_scene(0.5), prepare_run(slab_scene(0.5), Sensor.preset("ahab-chiroptera-i"),
                                                              photons=1, seed=0, bin_ns=BIN_NS, max_order=3),
                                 "laser", max_depth=4, tmp=tmp)
                peer.scene(spec)
                v = peer.versions
                lines += [f"Peer: mitransient {v['mitransient']}, Mitsuba {v['mitsuba']}, Dr.Jit {v['drjit']} "
                          f"(`{peer.variant}`, {v['threads']} threads, integrator `transient_prbvolpath`, NEE, "
                          "max_depth 4 = 3 scatterings, no Russian roulette); clsim "
                          f"{Simulator().device_name} (exact mode, NEE, max_order 3).", ""]
            else:
                lines += [f"**mitransient not run**: {peer.reason}.", ""]
            lines.append(DIFFERENCES)
            closed_form_section(args, peer, lines, tmp)
            if peer.proc is not None:
                null_collision_section(peer, lines, tmp)
            if args.profile:
                profile_section(args, lines)
            lines += ["### Speed and error against time", "",
                      "Error = relative L2 distance of the 942-bin (slab) return histogram, all orders, to the "
                      f"set-up's own reference (clsim {args.ref_photons:,} photons; mitransient "
                      f"{args.ref_chunks} x {args.ref_spp:,} samples per set-up); RMS over {args.repeats} seeds, wall "
                      "time the median (whole `Simulator.run` over the scene prepared once by `prepare_scene`, as "
                      "the peer loads its scene once / whole `render` call; kernels already built). "
                      "Time to 1 %: the fitted a t^-b; the b = 1/2 column assumes plain Monte Carlo.", ""]
            results = {}
            if "slab" in args.scenes:
                summ, _, peers = run_scene(args, "slab", slab_scene, (0.5, 0.1), peer, lines, tmp)
                results["slab"] = summ
                write_scene(lines, "Slab", "20 m x 20 m x 2 m, LAD 1, spherical leaves, 2 m over the ground; "
                            "clsim with 0.5 m and 0.1 m voxels.", summ, peers)
            if "oak" in args.scenes:
                summ, setup, peers = run_scene(args, "oak", oak_scene, (0.2,), peer, lines, tmp)
                results["oak"] = summ
                sc = setup.scene
                write_scene(lines, "Synthetic oak", f"`make_tree(seed=0).truth_scene(0.2)`: {sc.n_voxels:,} voxels "
                            f"of 0.2 m, grid {tuple(sc.shape)}, exact leaf area, spherical leaves, no wood; "
                            "nadir over the grid centre. **Not matched:** mitransient's heterogeneous medium "
                            "drops the path length of null collisions (section above): its single-scattering "
                            "returns come early (by about 1 m of range at 0.2 m and 0.5 m voxels, measured "
                            "by hand), so this table compares each program's speed and noise "
                            "on its own version of the scene, not the same physics.", summ, peers,
                            shape_note="mostly the peer's null-collision time loss; beam and field of view besides")
        finally:
            peer.close()
    lines.append(f"Total benchmark time {time.time() - t_start:.0f} s.")
    out = Path(args.out)
    write_page(out, lines, echo=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
