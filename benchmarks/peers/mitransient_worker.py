"""mitransient side of benchmarks/bench_mitransient.py; runs in the peer's own venv.

    DRJIT_LIBLLVM_PATH=... .peer-venv/mitransient/bin/python benchmarks/peers/mitransient_worker.py

A long-lived worker (so Dr.Jit's compiled kernels stay warm between the
benchmark's alternating runs).  It reads one JSON command per line on stdin
and answers one JSON line on stdout:

- ``{"cmd": "scene", "name": str, "spec": {...}}``: build a scene (see :func:`scene_dict`)
  and keep it under ``name``; answers ``{"ok": true, versions}``.
- ``{"cmd": "render", "name": str, "spp": N, "seed": s, "out": "file.npz"}``: render N
  samples of the one-pixel transient film; writes ``hist`` (the temporal bins,
  the film's radiance estimate) to ``out`` and answers ``{"seconds": wall}``
  (the whole render call: sampling, splatting, develop, copy to NumPy).
- ``{"cmd": "quit"}``.

Nothing here is tuned to the answer: the scene is described by the benchmark
in clsim's terms (sensor height, slab or voxel grid, extinction, albedo, the
tabulated phase function, ground reflectance, time bins) and translated 1:1.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np


def _deg(rad):
    return float(np.degrees(rad))


def scene_dict(mi, spec: dict) -> dict:
    """Mitsuba scene dictionary of a benchmark ``spec``.

    ``spec`` keys: ``sensor_z`` (m, above the ground at z = 0), ``end`` ("laser":
    camera rays follow the laser beam and next-event estimation connects to the
    receiver, as clsim does; "receiver": camera = receiver field of view, light =
    laser), ``beam_half_rad`` (laser cone half angle), ``fov_half_rad``
    (receiver), ``ground_R``, ``albedo``, ``phase`` (values of the phase function
    on a uniform grid of cos(angle between the propagation directions) in
    [-1, 1]), ``max_depth``, ``start_opl``, ``bin_opl``, ``nbins``, ``sampler``,
    and either ``slab`` ([x0, x1, y0, y1, z0, z1] and ``sigma_t``) or ``grid``
    (path of an .npy sigma_t[z, y, x] array, with ``grid_origin`` and
    ``grid_voxel``).
    """
    T = mi.ScalarTransform4f
    zs = float(spec["sensor_z"])
    eye, target, up = [0.0, 0.0, zs], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]
    # Mitsuba's tabphase takes the cosine between the incident direction pointing *to*
    # the scattering point and the outgoing one reversed; verified against the
    # single-scattering closed form by the benchmark (see docs/bench/mitransient.md).
    phase = {"type": "tabphase", "values": ", ".join(f"{v:.9g}" for v in spec["phase"])}
    if "slab" in spec:
        x0, x1, y0, y1, z0, z1 = spec["slab"]
        medium = {"type": "homogeneous", "sigma_t": float(spec["sigma_t"]),
                  "albedo": float(spec["albedo"]), "phase": phase, "sample_emitters": True}
        box = T().translate([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2]).scale(
            [(x1 - x0) / 2, (y1 - y0) / 2, (z1 - z0) / 2])
    else:
        sig = np.load(spec["grid"]).astype(np.float32)  # [z, y, x]
        nz, ny, nx = sig.shape
        h = float(spec["grid_voxel"])
        ox, oy, oz = spec["grid_origin"]
        size = [nx * h, ny * h, nz * h]
        to_world = T().translate([ox, oy, oz]).scale(size)
        vol = mi.VolumeGrid(sig)
        medium = {"type": "heterogeneous", "albedo": float(spec["albedo"]), "scale": 1.0,
                  "phase": phase, "sample_emitters": True,
                  "sigma_t": {"type": "gridvolume", "grid": vol, "filter_type": "nearest",
                              "to_world": to_world}}
        box = T().translate([ox + size[0] / 2, oy + size[1] / 2, oz + size[2] / 2]).scale(
            [size[0] / 2, size[1] / 2, size[2] / 2])
    beam, fov = float(spec["beam_half_rad"]), float(spec["fov_half_rad"])
    laser_end = spec["end"] == "laser"
    # The perspective camera starts its rays on the near plane, and mitransient counts the
    # path length from there: near_clip 1 m put every return 1 m of path (0.5 m of range)
    # early.  Mitsuba's default 1 cm here (5 mm of range, 1/7 of a bin; 1 mm with a far
    # clip of 3600 m moved the laser-end canopy/ground ratio by 4 %: float32 projection).
    # A square one-pixel camera: its side gives the same per-axis spread as the
    # cone it stands for (laser: Gaussian of sigma = beam/2; receiver: the
    # field-of-view cone's solid angle).
    cam_side = 2.0 * (beam / 2.0) * np.sqrt(3.0) if laser_end else np.sqrt(np.pi) * fov
    light_half = fov if laser_end else beam
    film = {"type": "transient_hdr_film", "width": 1, "height": 1,
            "temporal_bins": int(spec["nbins"]), "bin_width_opl": float(spec["bin_opl"]),
            "start_opl": float(spec["start_opl"]), "rfilter": {"type": "box"}}
    return {
        "type": "scene",
        "integrator": {"type": "transient_prbvolpath", "max_depth": int(spec["max_depth"]),
                       "rr_depth": 1000},
        "sensor": {"type": "perspective", "fov": _deg(cam_side), "fov_axis": "x",
                   "near_clip": 0.01, "far_clip": 2.0 * zs,
                   "to_world": T().look_at(origin=eye, target=target, up=up),
                   "sampler": {"type": spec.get("sampler", "independent"), "sample_count": 4},
                   "film": film},
        "light": {"type": "spot", "to_world": T().look_at(origin=eye, target=target, up=up),
                  "cutoff_angle": _deg(light_half), "beam_width": _deg(light_half) * 0.999999,
                  "intensity": {"type": "spectrum", "value": 1.0}},
        "ground": {"type": "rectangle", "to_world": T().scale([1000.0, 1000.0, 1.0]),
                   "bsdf": {"type": "diffuse",
                            "reflectance": {"type": "spectrum", "value": float(spec["ground_R"])}}},
        "canopy": {"type": "cube", "to_world": box, "bsdf": {"type": "null"}, "interior": medium},
    }


def main() -> int:
    import os

    # replies go to the original stdout; everything the libraries print goes to stderr
    out = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    import mitsuba as mi

    mi.set_variant(os.environ.get("MITRANSIENT_VARIANT", "llvm_ad_mono"))
    import drjit as dr
    import mitransient  # noqa: F401  (registers the transient plugins)

    scenes = {}
    for line in sys.stdin:
        if not line.strip():
            continue
        msg = json.loads(line)
        cmd = msg["cmd"]
        if cmd == "quit":
            break
        if cmd == "scene":
            scene = mi.load_dict(scene_dict(mi, msg["spec"]))
            # one untimed render compiles the scene's kernels
            mi.render(scene, spp=1024, seed=2**31 - 1)
            scenes[msg.get("name", "")] = scene
            out.write(json.dumps({"ok": True, "mitsuba": mi.__version__, "drjit": dr.__version__,
                                  "mitransient": mitransient.__version__,
                                  "threads": dr.thread_count()}) + "\n")
        elif cmd == "render":
            t0 = time.perf_counter()
            scene = scenes[msg.get("name", "")]
            _, transient = mi.render(scene, spp=int(msg["spp"]), seed=int(msg["seed"]))
            hist = np.array(transient, dtype=np.float64).reshape(-1)
            dt = time.perf_counter() - t0
            np.savez(msg["out"], hist=hist)
            out.write(json.dumps({"seconds": dt}) + "\n")
        else:
            out.write(json.dumps({"error": f"unknown command {cmd!r}"}) + "\n")
        out.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
