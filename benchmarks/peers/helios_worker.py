"""HELIOS++ half of the side-by-side survey benchmark: build and run "the shared case".

    .venv/bin/python benchmarks/peers/helios_worker.py [--beam-samples 19|271] [--threads 2] [--out DIR]

Run with the *project's* Python (it needs ``tlsvox`` to export the tree and
``clsim`` to read the result back); HELIOS++ itself runs as a child process,
the ``helios++`` executable of the peer build (``benchmarks/peers/setup_helios.sh``,
prefix ``$VOXLIDAR_HELIOS`` or ``~/.cache/voxlidar-peers/helios``).  It prints
one JSON line on stdout at the end (progress goes to stderr).

The shared case
---------------
- Scene: the synthetic oak ``make_tree(seed=1)`` (default ``TreeParams``), the
  same triangles the explicit-mesh reference (``clsim.validation.meshref``)
  ray-casts: leaves, bark and the ground square (z = 0, +-40 m; the
  registration targets are left out, as there).  One OBJ with three
  materials; ``helios_reflectance`` = the project's 1064 nm reflectances
  (``voxlidar.materials.DEFAULT_OPTICS``: leaf R 0.437 (its T 0.478 has no
  counterpart: HELIOS++ surfaces are opaque), bark 0.443, ground 0.30),
  Lambertian (Kd > 0, Ks = 0), ``helios_classification`` = the project's
  ``Material`` id (1 leaf, 2 bark, 3 ground), so the point output's class is it.
- Flight: one straight leg from (-10, 0, 600) to (+10, 0, 600) m at 60 m/s
  (along +x, centred over the trunk at the origin, 600 m above the ground);
  rotating polygon ("rotating" optics) over +-1 deg across track, 100 lines/s,
  ``--pulse-rate`` Hz (default 10 kHz, about 3,300 pulses); beam divergence
  0.25 mrad in ``beamDivergence_rad`` (HELIOS++ uses it as the 1/e^2 *half*
  angle), 4 ns ``pulseLength_ns``, 1064 nm, full waveform on, ``--bin-ns``
  (default 0.5 ns on HELIOS++'s one-way time axis = 0.15 m of range, i.e.
  1 ns of two-way time), detection threshold ``receivedEnergyMin_W`` 1e-12,
  no range noise (accuracy 0), no platform noise, GPS time 0 at the start.
- ``--beam-samples``: sub-rays per pulse, 1 + 3 q (q - 1) for HELIOS++'s
  ``beamSampleQuality`` q (19 = q 3, its default; 271 = q 10).

The OBJ, its .mtl, the scene XML and HELIOS++'s serialised ``.scene`` live in
the cache dir (``--cache``, default ``~/.cache/voxlidar-peers/helios-case``);
the scene XML is only rewritten when its text changes (HELIOS++ rebuilds the
scene whenever the XML is newer than the ``.scene``), so a second run loads the
``.scene`` instead of parsing the OBJ.  Scanner, platform and survey XMLs go
into ``--out`` with HELIOS++'s output.

Figures printed: ``wall_s`` (the HELIOS++ process, end to end: scene load or
build, simulation, files written), ``scene_load_s`` (its "Scene loaded in"
line; ``scene_parts_s`` OBJ parsing and ``kdtree_s`` when built), ``sim_s``
(its "Pulse computation tasks finished in" line: the simulation loop with all
pulses traced), ``peak_rss_mb`` (the HELIOS++ process's maximum resident set,
from ``/usr/bin/time -v``), ``pulses`` (every pulse fired, recomputed by
:func:`exact_pulses` and checked against the waveform rows), ``waveforms``
(rows of ``*_fullwave.txt``) and ``waveforms_read`` (what
``clsim.waveforms.io.helios`` reads of it), ``points``, the output paths and
the scan geometry.  ``pulses_exact_*.txt`` (in ``--out``) lists every pulse at
full precision (HELIOS++ writes origins and directions with 4 decimals);
``pulse_file_rows`` is what HELIOS++'s own ``--writePulse`` file holds, which
loses rows (3,072 of 3,301 here: a 32-pulse chunk and the unflushed tail).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HELIOS_PREFIX = Path(os.environ.get("VOXLIDAR_HELIOS", Path.home() / ".cache/voxlidar-peers/helios"))
CACHE = Path.home() / ".cache/voxlidar-peers/helios-case"

ALTITUDE_M = 600.0
LINE_M = 20.0
SPEED_MPS = 60.0
SCAN_HALF_DEG = 1.0
SCAN_FREQ_HZ = 100.0
DIVERGENCE_RAD = 0.25e-3  # half angle at 1/e^2 (what HELIOS++ does with beamDivergence_rad)
PULSE_NS = 4.0
WAVELENGTH_NM = 1064
THRESHOLD_W = 1e-12
# emitter/receiver: 1 W "averagePower_w" (HELIOS++ uses it as the pulse's power), the project's
# 5 cm receiver aperture, no optical loss, no atmosphere (visibility 1000 km: exp(-2 R a) = 1 - 3e-5)
POWER_W = 1.0
RECEIVER_M = 0.05
EFFICIENCY = 1.0
VISIBILITY_KM = 1000.0
# rangeMin_m also enters the beam model: legacy, as exp(-2 (alpha/theta)^2 R^2 / (R0^2 + R^2)) per sub-ray (1 m:
# a plain Gaussian); improved, as a focus at R0 (w^2 = w0^2 (1 - R/R0)^2 + theta^2 R^2; R0 = 0 gives no power at
# all, 500 m keeps w = theta R within 1e-4).  Hits nearer than R0 are dropped (the tree top is 586 m away).
RANGE_MIN_M = {"legacy": 1.0, "improved": 500.0}


def log(*a):
    print(*a, file=sys.stderr, flush=True)


def bsq_of(samples: int) -> int:
    """HELIOS++ beamSampleQuality q giving ``samples`` sub-rays: 1 + sum_{r<q} int(2 pi) r = 1 + 3 q (q - 1)."""
    for q in range(1, 200):
        if 1 + 3 * q * (q - 1) == samples:
            return q
    raise SystemExit(f"--beam-samples {samples}: HELIOS++ gives 1 + 3 q (q - 1) sub-rays (1, 7, 19, 37, 61, "
                     "91, 127, 169, 217, 271, ...)")


def write_if_changed(path: Path, text: str) -> bool:
    """Write ``text`` unless the file already holds it (keeps its mtime: HELIOS++'s scene cache)."""
    if path.is_file() and path.read_text() == text:
        return False
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    os.replace(tmp, path)
    return True


# ----------------------------------------------------------------------------------------------
# scene


def optics_1064():
    from voxlidar.materials import DEFAULT_OPTICS, Material

    t = DEFAULT_OPTICS[WAVELENGTH_NM]
    return {"leaf": (int(Material.LEAF), t[Material.LEAF].reflectance, t[Material.LEAF].transmittance),
            "bark": (int(Material.BARK), t[Material.BARK].reflectance, t[Material.BARK].transmittance),
            "ground": (int(Material.GROUND), t[Material.GROUND].reflectance, t[Material.GROUND].transmittance)}


def export_obj(cache: Path, seed: int, ground_only: bool = False) -> tuple[Path, dict]:
    """The oak's leaf, bark and ground triangles as OBJ + MTL in ``cache`` (written once);
    ``ground_only``: its ground square alone (a check of the sensor's numbers against closed forms)."""
    stem = f"ground_seed{seed}" if ground_only else f"oak_seed{seed}"
    obj, mtl, meta_p = cache / f"{stem}.obj", cache / f"{stem}.mtl", cache / f"{stem}.json"
    if obj.is_file() and mtl.is_file() and meta_p.is_file():
        return obj, json.loads(meta_p.read_text())
    from tlsvox.truth.synthetic import make_tree
    from voxlidar.materials import Material

    t0 = time.perf_counter()
    log(f"helios_worker: building make_tree(seed={seed}) and writing {obj} ...")
    tree = make_tree(seed=seed)
    if ground_only:
        tree.material = np.where(tree.material == Material.GROUND, tree.material, Material.NONE).astype(np.uint8)
    opt = optics_1064()
    lines = ["# voxlidar synthetic oak, materials at 1064 nm (voxlidar.materials.DEFAULT_OPTICS)\n"]
    colors = {"leaf": "0.20 0.55 0.15", "bark": "0.45 0.30 0.15", "ground": "0.75 0.72 0.65"}
    for name, (mid, r, tr) in opt.items():
        lines += [f"newmtl {name}\n", f"Ka 0 0 0\nKd {colors[name]}\nKs 0 0 0\nNs 0\n",
                  f"helios_reflectance {r:.6g}\n", f"helios_classification {mid}\n",
                  f"# project transmittance {tr:g} (not modelled by HELIOS++: opaque)\n\n"]
    order = [("bark", Material.BARK), ("leaf", Material.LEAF), ("ground", Material.GROUND)]
    keep = np.isin(tree.material, [m for _, m in order])
    order = [(n, m) for n, m in order if np.any(tree.material == m)]
    used = np.unique(tree.triangles[keep])
    remap = np.full(len(tree.vertices), -1, np.int64)
    remap[used] = np.arange(len(used))
    tmp = obj.with_suffix(".obj.tmp")
    counts = {}
    with open(tmp, "w") as fh:
        fh.write(f"# voxlidar make_tree(seed={seed}): leaf, bark and ground triangles (as clsim.validation.meshref)\n")
        fh.write(f"mtllib {mtl.name}\n")
        np.savetxt(fh, tree.vertices[used], fmt="v %.6f %.6f %.6f")
        for name, m in order:
            tri = remap[tree.triangles[tree.material == m]] + 1
            counts[name] = int(len(tri))
            fh.write(f"o {name}\nusemtl {name}\n")
            np.savetxt(fh, tri, fmt="f %d %d %d")
    mtl.write_text("".join(lines))
    os.replace(tmp, obj)
    lo, hi = tree.bounds()
    meta = {"seed": seed, "triangles": counts, "n_triangles": int(sum(counts.values())), "vertices": int(len(used)),
            "ground_z": float(tree.ground_z), "vegetation_bounds": [lo.tolist(), hi.tolist()],
            "materials": {k: {"material_id": v[0], "R": v[1], "T": v[2]} for k, v in opt.items()},
            "export_s": round(time.perf_counter() - t0, 1)}
    meta_p.write_text(json.dumps(meta, indent=1))
    log(f"helios_worker: OBJ written in {meta['export_s']} s ({meta['n_triangles']:,} triangles)")
    return obj, meta


def scene_xml(obj: Path, seed: int) -> str:
    st = obj.stat()
    sid = obj.stem
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<!-- voxlidar make_tree(seed={seed}) for the HELIOS++ side-by-side case; OBJ {st.st_size} bytes, mtime {int(st.st_mtime)}
     (a new OBJ changes this line, so HELIOS++ rebuilds its .scene) -->
<document>
    <scene id="{sid}" name="{sid}">
        <part id="oak">
            <filter type="objloader">
                <param type="string" key="filepath" value="{obj}" />
                <param type="string" key="up" value="z" />
            </filter>
        </part>
    </scene>
</document>
"""


# ----------------------------------------------------------------------------------------------
# sensor, platform, survey


def scanner_xml(pulse_rate: int, range_min: float) -> str:
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<document>
  <!-- the shared case's sensor: a rotating polygon (unidirectional parallel lines), +-{SCAN_HALF_DEG:g} deg -->
  <scanner id="case"
           name="voxlidar shared case (LMS-Q680i-like, 1064 nm)"
           optics="rotating"
           accuracy_m="0"
           beamDivergence_rad="{DIVERGENCE_RAD:g}"
           pulseFreqs_Hz="{pulse_rate}"
           pulseLength_ns="{PULSE_NS:g}"
           wavelength_nm="{WAVELENGTH_NM}"
           averagePower_w="{POWER_W:g}"
           receiverDiameter_m="{RECEIVER_M:g}"
           opticalEfficiency="{EFFICIENCY:g}"
           atmosphericVisibility_km="{VISIBILITY_KM:g}"
           beamQualityFactor="1"
           rangeMin_m="{range_min:g}"
           receivedEnergyMin_W="{THRESHOLD_W:g}"
           maxNOR="0"
           scanAngleMax_deg="{SCAN_HALF_DEG:g}"
           scanAngleEffectiveMax_deg="{SCAN_HALF_DEG:g}"
           scanFreqMin_Hz="1"
           scanFreqMax_Hz="1000">
    <FWFSettings binSize_ns="0.5" beamSampleQuality="3"/>
  </scanner>
</document>
"""


PLATFORM_XML = """<?xml version="1.0" encoding="UTF-8"?>
<document>
  <!-- HELIOS++'s sr22 airplane mount (scanner looking down, scan across track) without its 0.7 m offset:
       the beam origin is the waypoint itself -->
  <platform id="line" name="straight line, no offset" type="linearpath">
    <scannerMount x="0" y="0" z="0">
      <rot axis="x" angle_deg="-90" />
      <rot axis="z" angle_deg="90" />
    </scannerMount>
  </platform>
</document>
"""


def survey_xml(name: str, scene: Path, scene_id: str, platform: Path, scanner: Path, pulse_rate: int, bsq: int,
               bin_ns: float) -> str:
    x0, x1 = -LINE_M / 2, LINE_M / 2
    return f"""<?xml version="1.0" encoding="UTF-8"?>
<document>
  <scannerSettings id="case_set" active="true" pulseFreq_hz="{pulse_rate}" scanAngle_deg="{SCAN_HALF_DEG:g}"
                   scanFreq_hz="{SCAN_FREQ_HZ:g}" trajectoryTimeInterval_s="0.01"/>
  <survey name="{name}" scene="{scene}#{scene_id}" platform="{platform}#line" scanner="{scanner}#case" seed="1">
    <FWFSettings beamSampleQuality="{bsq}" binSize_ns="{bin_ns:g}" winSize_ns="{PULSE_NS / 4:g}"/>
    <detectorSettings accuracy_m="0"/>
    <leg>
      <platformSettings x="{x0:g}" y="0" z="{ALTITUDE_M:g}" onGround="false" movePerSec_m="{SPEED_MPS:g}"/>
      <scannerSettings template="case_set"/>
    </leg>
    <leg>
      <platformSettings x="{x1:g}" y="0" z="{ALTITUDE_M:g}" onGround="false" movePerSec_m="{SPEED_MPS:g}"/>
      <scannerSettings template="case_set" active="false"/>
    </leg>
  </survey>
</document>
"""


# ----------------------------------------------------------------------------------------------
# run


def helios_exe(prefix: Path) -> Path:
    hits = sorted(glob.glob(str(prefix / "venv/lib/python3*/site-packages/pyhelios/bin/helios++")))
    if not hits:
        raise SystemExit(f"no helios++ executable under {prefix}/venv; run benchmarks/peers/setup_helios.sh")
    return Path(hits[0])


def _float(pattern, text):
    m = re.findall(pattern, text)
    return float(m[-1]) if m else None


def exact_pulses(pulse_rate: int) -> dict:
    """Every pulse HELIOS++ fires on the leg, recomputed in double precision as its source does it.

    ``PolygonMirrorBeamDeflector``: the beam angle starts at 0 and each simulation step (1 / pulse rate)
    adds ``scanFreq * 2 * scanAngleMax / pulseFreq``; reaching ``>= +scanAngleMax`` it is set to
    ``-scanAngleMax``; a pulse leaves the device only while ``-1 deg < angle <= +1 deg`` (so the
    reset step fires nothing: 99 pulses a line at 10 kHz, -0.98 ... +0.98 deg).  Step ``s`` is at GPS
    time ``s / rate`` (s from 0), the platform at ``(-10 + 60 t, 0, 600)``, and the beam direction is
    ``(0, sin a, -cos a)`` (positive angles towards +y).  Emitted pulses are numbered 1, 2, ... in
    order: HELIOS++'s ``fullwaveIndex``.  The leg ends when the platform passes its end point.
    """
    amax = np.deg2rad(SCAN_HALF_DEG)
    step = SCAN_FREQ_HZ * (amax - (-amax)) / pulse_rate
    x0, x1 = -LINE_M / 2, LINE_M / 2
    ang, steps = 0.0, []
    s = 0
    while x0 + SPEED_MPS * s / pulse_rate <= x1 + 1e-9:
        ang += step
        if ang >= amax:
            ang = -amax
        if -amax < ang <= amax:
            steps.append((s, ang))
        s += 1
    k = np.array([a for a, _ in steps], np.int64)
    a = np.array([b for _, b in steps])
    t = k / pulse_rate
    origin = np.column_stack([x0 + SPEED_MPS * t, np.zeros_like(t), np.full_like(t, ALTITUDE_M)])
    direction = np.column_stack([np.zeros_like(a), np.sin(a), -np.cos(a)])
    return {"index": np.arange(1, len(k) + 1), "step": k, "gps_time": t, "origin": origin, "direction": direction,
            "scan_angle_rad": a, "steps_total": s}


def write_exact_pulses(path: Path, p: dict) -> None:
    head = ("index step gps_time_s ox oy oz dx dy dz scan_angle_deg  # HELIOS++ shared case, every pulse fired "
            "(helios_worker.exact_pulses); index = fullwaveIndex")
    data = np.column_stack([p["index"], p["step"], p["gps_time"], p["origin"], p["direction"],
                            np.degrees(p["scan_angle_rad"])])
    np.savetxt(path, data, fmt=["%d", "%d", "%.9f", "%.6f", "%.6f", "%.6f", "%.12f", "%.12f", "%.12f", "%.9f"],
               header=head)


def check_pulses(p: dict, fws) -> dict:
    """Compare the recomputed pulses with the waveform rows HELIOS++ wrote (4 decimals there)."""
    idx = np.concatenate([f.index for f in fws])
    o = np.concatenate([f.origin for f in fws])
    d = np.concatenate([f.direction for f in fws])
    t = np.concatenate([f.gps_time for f in fws])
    ok = (idx >= 1) & (idx <= len(p["index"]))
    j = idx[ok] - 1
    return {"rows_matched": int(ok.sum()), "rows_unmatched": int((~ok).sum()),
            "max_origin_diff_m": float(np.abs(o[ok] - p["origin"][j]).max()) if ok.any() else None,
            "max_direction_diff": float(np.abs(d[ok] - p["direction"][j]).max()) if ok.any() else None,
            "max_time_diff_s": float(np.abs(t[ok] - p["gps_time"][j]).max()) if ok.any() else None}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--beam-samples", type=int, default=19, help="sub-rays per pulse (19 = beamSampleQuality 3)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", type=Path, default=Path("helios-out"))
    ap.add_argument("--pulse-rate", type=int, default=10000, help="Hz (integer: HELIOS++ reads pulseFreqs_Hz as int)")
    ap.add_argument("--bin-ns", type=float, default=0.5, help="HELIOS++ binSize_ns (one-way time)")
    ap.add_argument("--energy-model", choices=("legacy", "improved"), default="legacy",
                    help="legacy: what the `helios` command runs (it always adds --legacyEnergyModel)")
    ap.add_argument("--seed", type=int, default=1, help="make_tree seed")
    ap.add_argument("--scene", choices=("oak", "ground"), default="oak",
                    help="ground: the oak's ground square alone (a quick check)")
    ap.add_argument("--cache", type=Path, default=CACHE)
    ap.add_argument("--helios", type=Path, default=HELIOS_PREFIX, help="prefix of the peer build")
    args = ap.parse_args(argv)

    bsq = bsq_of(args.beam_samples)
    exe = helios_exe(args.helios)
    cache = args.cache.expanduser().resolve()
    cache.mkdir(parents=True, exist_ok=True)
    out = args.out.expanduser().resolve()
    out.mkdir(parents=True, exist_ok=True)

    obj, meta = export_obj(cache, args.seed, ground_only=args.scene == "ground")
    scene = cache / f"{obj.stem}_scene.xml"
    rewrote = write_if_changed(scene, scene_xml(obj, args.seed))
    serial = scene.with_suffix(".scene")
    cache_hit = serial.is_file() and serial.stat().st_mtime > scene.stat().st_mtime
    platform, scanner = out / "platform_case.xml", out / "scanner_case.xml"
    write_if_changed(platform, PLATFORM_XML)
    write_if_changed(scanner, scanner_xml(args.pulse_rate, RANGE_MIN_M[args.energy_model]))
    name = f"{obj.stem}_rays{args.beam_samples}" + ("" if args.energy_model == "legacy" else "_improved")
    survey = out / f"survey_{name}.xml"
    write_if_changed(survey, survey_xml(name, scene, obj.stem, platform, scanner, args.pulse_rate, bsq, args.bin_ns))

    spectra_assets = args.helios / "src/python/pyhelios"
    cmd = [str(exe), str(survey), "--assets", str(cache), "--assets", str(spectra_assets),
           "--assets", str(spectra_assets / "data"), "--output", str(out),
           "--writeWaveform", "--writePulse", "--njobs", str(args.threads), "--kdtJobs", str(args.threads),
           "--seed", "1", "--gpsStartTime", "315964809",  # GPS week start + 0 s: pulse times from 0
           "--disablePlatformNoise", "--disableLegNoise"]
    if args.energy_model == "legacy":
        cmd.append("--legacyEnergyModel")
    version = subprocess.run([str(exe), "--version"], capture_output=True, text=True).stdout.strip()
    log("helios_worker: " + " ".join(cmd))
    logfile = out / f"helios_{name}.log"
    # peak RSS: GNU time's wait4 on helios++ (a child forked from this Python would carry this
    # process's own pages into its high-water mark, e.g. after the OBJ export)
    timefile = out / f"time_{name}.txt"
    gnu_time = Path("/usr/bin/time")
    wrapped = ([str(gnu_time), "-v", "-o", str(timefile)] + cmd) if gnu_time.is_file() else cmd
    t0 = time.perf_counter()
    with open(logfile, "w") as fh:
        rc = subprocess.call(wrapped, stdout=fh, stderr=subprocess.STDOUT)
    wall = time.perf_counter() - t0
    rss = re.findall(r"Maximum resident set size \(kbytes\): (\d+)", timefile.read_text()) if timefile.is_file() else []
    rss_kb = int(rss[-1]) if rss else resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    text = logfile.read_text(errors="replace")
    if rc != 0:
        log(text[-3000:])
        raise SystemExit(f"helios++ exited with {rc}; log {logfile}")
    m = re.findall(r'Output directory: "([^"]+)"', text)
    root = Path(m[-1]) if m else max((out / name).iterdir(), key=lambda p: p.stat().st_mtime)
    fw = sorted(root.glob("*_fullwave.txt"))
    pts = sorted(root.glob("*_points.*"))
    pul = sorted(root.glob("*_pulse.txt"))
    traj = sorted(root.glob("*_trajectory.txt"))

    from clsim.waveforms.io.helios import read_helios_fullwave

    n_fw_rows = sum(1 for f in fw for line in open(f) if line.strip())
    read = [read_helios_fullwave(f) for f in fw]
    n_read = sum(len(r) for r in read)
    samples = [len(s) for r in read for s in r.samples]
    dt = np.concatenate([r.dt_ns for r in read]) if read else np.zeros(0)
    n_points = sum(1 for f in pts for line in open(f) if line.strip())
    n_pulse_rows = sum(1 for f in pul for line in open(f) if line.strip())
    pulses = exact_pulses(args.pulse_rate)
    exact_file = out / f"pulses_exact_{name}.txt"
    write_exact_pulses(exact_file, pulses)
    a = np.degrees(pulses["scan_angle_rad"])
    geo = {"pulses": int(len(a)), "sim_steps": int(pulses["steps_total"]),
           "pulse_interval_s": 1.0 / args.pulse_rate, "line_period_s": 1.0 / SCAN_FREQ_HZ,
           "scan_step_deg": float(np.median(np.diff(a)[np.diff(a) > 0])),
           "scan_angle_deg_range": [float(a.min()), float(a.max())], "first_scan_angle_deg": float(a[0]),
           "origin_first": pulses["origin"][0].tolist(), "origin_last": pulses["origin"][-1].tolist(),
           "gps_time_last_s": float(pulses["gps_time"][-1]),
           "check_against_fullwave": check_pulses(pulses, read) if read else None}
    res = {
        "peer": "HELIOS++", "version": version, "scene": obj.stem,
        "energy_model": args.energy_model, "beam_samples": args.beam_samples, "beamSampleQuality": bsq,
        "threads": args.threads, "pulse_rate_hz": args.pulse_rate, "bin_ns_one_way": args.bin_ns,
        "scene_cache": "loaded .scene" if cache_hit else "built from OBJ (and .scene written)",
        "scene_xml_rewritten": rewrote,
        "wall_s": round(wall, 2), "scene_load_s": _float(r"Scene loaded in ([0-9.eE+-]+)s", text),
        "sim_s": _float(r"Pulse computation tasks finished in ([0-9.eE+-]+) sec", text),
        "scene_parts_s": _float(r"sceneparts loaded in ([0-9.eE+-]+)s", text),
        "kdtree_s": _float(r"KDG built in ([0-9.eE+-]+)s", text),
        "sim_steps": _float(r"Elapsed simulation steps = ([0-9]+)", text),
        "peak_rss_mb": round(rss_kb / 1024, 1),
        "pulses": geo["pulses"], "pulse_file_rows": n_pulse_rows, "waveforms": n_fw_rows, "waveforms_read": n_read,
        "samples_per_waveform_median": int(np.median(samples)) if samples else None,
        "dt_ns": float(np.median(dt)) if len(dt) else None, "points": n_points,
        "triangles": meta["n_triangles"],
        "fullwave": [str(f) for f in fw], "points_file": [str(f) for f in pts], "pulse_file": [str(f) for f in pul], "pulses_exact": str(exact_file),
        "trajectory_file": [str(f) for f in traj], "survey_xml": str(survey), "scene_xml": str(scene),
        "obj": str(obj), "log": str(logfile), "geometry": geo,
    }
    print(json.dumps(res), flush=True)


if __name__ == "__main__":
    main()
