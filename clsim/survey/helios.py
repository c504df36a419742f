"""A ``clsim survey`` job as HELIOS++ files: the same flight, scan pattern and pulses over the same voxels.

:func:`write_helios_survey` writes, into one folder, what HELIOS++ (Winiwarter
et al. 2022) needs to fly the pulses ``first .. first + count - 1`` of a
:class:`~clsim.survey.distributed.SurveyJob` (``clsim survey --helios DIR``):

``scene.vox``
    The voxel scene in AMAPVox's column order (HELIOS++'s detailed-voxel
    loader parses by position; :func:`tlsvox.voxel.amapvox.write_vox` with
    ``amapvox_columns=True``).  HELIOS++ takes ``PadBVTotal`` as the leaf
    area density of a transmittive voxel; it has no wood in voxels.
``ground.obj``
    The flat ground at the job's ``ground_z`` under the whole swath (two
    triangles).
``scene.xml``, ``scanner.xml``, ``platform.xml``, ``survey.xml``
    The scene (ground and voxels), the instrument (deflector from the scan
    pattern: ``polygon`` -> ``rotating``, ``mirror`` -> ``oscillating``,
    ``palmer`` -> ``conic``; pulse rate, scan angle and rate, beam
    divergence as the half-angle HELIOS++ takes, pulse length, wavelength),
    a straight-line platform looking down, and the survey: one waypoint at
    the platform's position when the job's first pulse fires and one where
    its last pulse has fired, for each leg of the trajectory the job spans.
``helios_job.json``
    How the two runs' pulses correspond: HELIOS++'s pulse ``k`` of the survey
    (its ``fullwaveIndex``) is fired at the time and platform position of
    the job's pulse ``first + k``; its direction follows HELIOS++'s own
    deflector phase, which may differ from clsim's at the start of a line.

The XML follows HELIOS++'s schemas (``python/pyhelios/util/xsd`` in its
repository; tested against them when a checkout is at hand).  Run it with
``helios++ survey.xml --assets <helios>/python/pyhelios --fullwave``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from voxlidar.errors import InputError
from voxlidar.safeio import atomic_write

__all__ = ["HeliosFiles", "write_helios_survey"]

#: HELIOS++ deflector of each scan pattern
OPTICS = {"polygon": "rotating", "mirror": "oscillating", "palmer": "conic"}


@dataclass(frozen=True)
class HeliosFiles:
    """The files :func:`write_helios_survey` wrote."""

    survey: Path
    scene: Path
    scanner: Path
    platform: Path
    vox: Path
    ground: Path
    job: Path
    first: int  #: the job's first pulse: HELIOS++'s pulse k is the job's first + k
    count: int


def _text(path: Path, text: str) -> Path:
    def write(tmp):
        Path(tmp).write_text(text, encoding="utf-8")

    return atomic_write(path, write)


def _attrs(**kw) -> str:
    return " ".join(f"{k}={quoteattr(v if isinstance(v, str) else f'{v:.10g}')}" for k, v in kw.items())


def _waypoints(job) -> list[tuple[np.ndarray, float, bool]]:
    """(position, speed, scanning from here) for each waypoint spanning the job's pulses."""
    rate = job.pattern.pulse_rate_hz
    tr = job.trajectory
    t0, t1 = job.first / rate, (job.first + job.count) / rate
    t1 = min(t1, tr.duration_s)
    points = []
    for i, leg in enumerate(tr.legs):
        a, b = max(t0, tr.leg_start_s[i]), min(t1, tr.leg_start_s[i + 1])
        if b <= a:
            continue
        start, end = np.asarray(leg.start, dtype=np.float64), np.asarray(leg.end, dtype=np.float64)
        pa, pb = (start + (t - tr.leg_start_s[i]) / leg.duration_s * (end - start) for t in (a, b))
        points.append((pa, leg.speed_mps, True))
        points.append((pb, leg.speed_mps, False))
    return points


def _scene_box(scene) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(scene.origin, dtype=np.float64)
    return lo, lo + scene.voxel_size * np.asarray(scene.shape)


def write_helios_survey(job, out_dir: str | os.PathLike, *, name: str = "voxlidar") -> HeliosFiles:
    """Write the HELIOS++ scene, scanner, platform and survey that fly ``job``'s pulses (see the module).

    Parameters
    ----------
    job : SurveyJob
        Its scene: a voxel scene (``.npz`` or AMAPVox ``.vox``), or a plot of
        trees (:class:`~clsim.scenes.PlotScene`, its trees' voxels merged
        into one grid).
    out_dir : path-like
        Created if missing; files in it are replaced atomically.
    name : str
        The survey's and scene's name in the XML.

    Returns
    -------
    HeliosFiles
    """
    from clsim.scenes import load_scene
    from tlsvox.voxel.amapvox import write_vox
    from voxlidar.scene import Scene

    scene = load_scene(job.scene_path)
    if not isinstance(scene, Scene):  # a plot of trees: its trees' voxels in one grid
        scene = scene.to_scene()
    kind = str(getattr(job.pattern.kind, "value", job.pattern.kind))
    if kind not in OPTICS:
        raise InputError(f"scan pattern {kind!r} has no HELIOS++ deflector; one of {sorted(OPTICS)}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    out = out.resolve()
    ground_z = float(job.ground_z if job.ground_z is not None else
                     (scene.ground_z if scene.ground_z is not None else scene.origin[2]))
    # the ground under the whole swath: the scene's box widened by the farthest a beam reaches off nadir
    lo, hi = _scene_box(scene)
    points = _waypoints(job)
    if not points:
        raise InputError("the job has no pulses to write HELIOS++ files for (count 0)")
    heights = [p[2] - ground_z for p, _, _ in points]
    reach = max(heights) * np.tan(np.radians(min(job.pattern.fov_deg / 2 + 5.0, 85.0)))
    xy = np.array([p[:2] for p, _, _ in points])
    g_lo = np.minimum(lo[:2], xy.min(axis=0)) - reach
    g_hi = np.maximum(hi[:2], xy.max(axis=0)) + reach
    ground = _text(out / "ground.obj", "# the flat ground of a voxlidar survey (clsim.survey.helios)\n"
                   + "".join(f"v {x:.4f} {y:.4f} {ground_z:.4f}\n"
                             for x, y in ((g_lo[0], g_lo[1]), (g_hi[0], g_lo[1]), (g_hi[0], g_hi[1]), (g_lo[0], g_hi[1])))
                   + "f 1 2 3\nf 1 3 4\n")
    vox = write_vox(scene, out / "scene.vox", metadata=False, amapvox_columns=True)

    scene_xml = _text(out / "scene.xml", f"""<?xml version="1.0" encoding="UTF-8"?>
<document>
  <scene {_attrs(id=name, name=f"{name}: voxel scene and flat ground")}>
    <part>
      <filter type="objloader">
        <param type="string" key="filepath" value={quoteattr(str(ground))}/>
      </filter>
    </part>
    <part>
      <filter type="detailedvoxels">
        <param type="string" key="filepath" value={quoteattr(str(vox))}/>
      </filter>
    </part>
  </scene>
</document>
""")
    s, p = job.sensor, job.pattern
    half = p.fov_deg / 2
    scanner_xml = _text(out / "scanner.xml", f"""<?xml version="1.0" encoding="UTF-8"?>
<document>
  <scanner {_attrs(id=name, name=f"{s.name} (voxlidar)", optics=OPTICS[kind], accuracy_m=0.0,
                   beamDivergence_rad=0.5e-3 * s.divergence_mrad, pulseFreqs_Hz=f"{p.pulse_rate_hz:.10g}",
                   pulseLength_ns=s.pulse_fwhm_ns, wavelength_nm=f"{int(round(s.wavelength_nm))}",
                   scanAngleMax_deg=half, scanAngleEffectiveMax_deg=half,
                   scanFreqMin_Hz=min(1.0, p.scan_rate_hz), scanFreqMax_Hz=max(1000.0, p.scan_rate_hz))}>
    <FWFSettings {_attrs(binSize_ns=1.0 / s.sampling_ghz, beamSampleQuality="3")}/>
  </scanner>
</document>
""")
    platform_xml = _text(out / "platform.xml", f"""<?xml version="1.0" encoding="UTF-8"?>
<document>
  <!-- a straight-line platform, the scanner looking down and scanning across track, no lever arm -->
  <platform {_attrs(id=name, name="straight line, no offset", type="linearpath")}>
    <scannerMount x="0" y="0" z="0">
      <rot axis="x" angle_deg="-90"/>
      <rot axis="z" angle_deg="90"/>
    </scannerMount>
  </platform>
</document>
""")
    legs = "".join(f"""    <leg>
      <platformSettings {_attrs(x=q[0], y=q[1], z=q[2], onGround="false", movePerSec_m=v)}/>
      <scannerSettings {_attrs(template="settings", active="true" if on else "false")}/>
    </leg>
""" for q, v, on in points)
    survey_xml = _text(out / "survey.xml", f"""<?xml version="1.0" encoding="UTF-8"?>
<document>
  <scannerSettings {_attrs(id="settings", active="true", pulseFreq_hz=p.pulse_rate_hz, scanAngle_deg=half,
                            scanFreq_hz=p.scan_rate_hz)}/>
  <survey {_attrs(name=name, scene=f"{out / 'scene.xml'}#{name}", platform=f"{out / 'platform.xml'}#{name}",
                  scanner=f"{out / 'scanner.xml'}#{name}", seed=f"{int(job.seed)}")}>
    <FWFSettings {_attrs(binSize_ns=1.0 / s.sampling_ghz, beamSampleQuality="3")}/>
{legs}  </survey>
</document>
""")
    info = {"format": "voxlidar-helios-1", "first": int(job.first), "count": int(job.count),
            "pulse_rate_hz": float(p.pulse_rate_hz), "scan_pattern": kind, "helios_optics": OPTICS[kind],
            "pulses": "HELIOS++'s pulse k (fullwaveIndex) is fired at the time and platform position of the job's "
                      "pulse first + k; its direction follows HELIOS++'s deflector",
            "scene": str(job.scene_path), "ground_z": ground_z,
            "not_in_helios": "wood voxels, multiple scattering, the voxel scene's leaf angle model (HELIOS++'s "
                             "transmittive voxels take PadBVTotal as their extinction)",
            "run": f"helios++ {out / 'survey.xml'} --assets <helios>/python/pyhelios --fullwave"}
    job_json = _text(out / "helios_job.json", json.dumps(info, indent=1) + "\n")
    return HeliosFiles(survey_xml, scene_xml, scanner_xml, platform_xml, vox, ground, job_json, int(job.first),
                       int(job.count))
