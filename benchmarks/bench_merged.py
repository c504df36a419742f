"""Merged point clouds without pulses: the demo's oak merged, its pulses and poses dropped.

The demo's synthetic oak (seed 1, 500 m2 of leaves, leaves facing outwards)
scanned from the paper's two positions by the VZ-400 at 0.06 deg, as the
full-pulse pipeline sees it (pulse tables, true poses, true classes), and as
one merged LAS file of x, y, z, return numbers, point_source_id and the true
classes at 1 mm, with no pulse table and no pose, voxelised the way
``tlsvox voxelize --scan-positions`` does (tlsvox.voxel.merged):

- positions known, each point given to its position by point_source_id or to
  the nearest position, the empty pulses from the scanner's step (given) or
  from the cloud (estimated);
- the same cloud thinned at random to half its points (a gate must fire);
- positions unknown: occupancy of fine cells, no beams.

Every run: 20 cm voxels, bcmle (the occupancy mode has no estimator), the
ground at z = 0, scored against the mesh's leaf area.  Writes
docs/bench/merged.md.

    .venv/bin/python benchmarks/bench_merged.py [--out docs/bench/merged.md]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
from _bench import machine_line, write_page

ROOT = Path(__file__).resolve().parents[1]


def write_merged_las(scans, path, *, keep=None) -> Path:
    """The scans' echoes in the world frame as one LAS file: x, y, z at 1 mm, return numbers,
    point_source_id = 7 + scan id, the true material as an extra byte; no pulse table, no pose."""
    import laspy

    xyz = np.vstack([s.world_xyz(s.pose_true) for s in scans])
    cols = {"return_number": np.concatenate([s.return_number for s in scans]),
            "number_of_returns": np.concatenate([s.number_of_returns for s in scans]),
            "point_source_id": np.concatenate([np.full(len(s), 7 + s.scan_id) for s in scans]),
            "truth_material": np.concatenate([s.truth_material for s in scans])}
    if keep is not None:
        xyz = xyz[keep]
        cols = {k: v[keep] for k, v in cols.items()}
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, 1e-3)
    header.offsets = np.floor(xyz.min(axis=0))
    header.add_extra_dims([laspy.ExtraBytesParams(name="truth_material", type=np.uint8)])
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    for k, v in cols.items():
        setattr(las, k, v)
    las.write(str(path))
    return Path(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(ROOT / "docs" / "bench" / "merged.md"))
    args = ap.parse_args(argv)
    from bench_lad_terms import _oak_scans

    from tlsvox.voxel.merged import merged_warnings, read_merged, split_by_positions, voxelize_occupancy
    from tlsvox.voxel.stages import voxelize
    from tlsvox.voxel.trace import Tracer

    load0 = os.getloadavg()
    tracer = Tracer()
    t0 = time.perf_counter()
    tree, scans = _oak_scans("outward", 0.35, -20.0)
    print(f"oak scanned in {time.perf_counter() - t0:.0f} s: {[len(s) for s in scans]} echoes")
    positions = np.array([s.pose_true[:3, 3] for s in scans])
    common = dict(voxel_size=0.2, leaf_angle="uniform", leaf_azimuth="outward", ground=0.0, progress=False)
    truth_area = tree.leaf_area()
    rows = []

    def record(label, res, sec, parts=None):
        area = res.scene.total_leaf_area()
        warnings = list(res.scene.meta["warnings"]) + ([] if parts is None else merged_warnings(parts))
        empty = "" if parts is None else f"{sum(p.meta['merged']['empty_pulses'] for p in parts) / 1e6:.2f} M"
        rows.append((label, area, sec, empty, warnings))
        print(f"{label}: {area:.1f} m2 ({100 * (area / truth_area - 1):+.1f} %), {sec:.1f} s, {len(warnings)} "
              f"warning(s) {warnings[:1]}")

    for rule in ("fraction", "uniform"):
        t = time.perf_counter()
        res = voxelize(scans, echo_weights=rule, tracer=tracer, **common)
        record(f"full pulses, true poses, echo weights {rule}", res, time.perf_counter() - t)
    with tempfile.TemporaryDirectory() as tmp:
        whole = write_merged_las(scans, Path(tmp) / "oak_merged.las")
        half = write_merged_las(scans, Path(tmp) / "oak_half.las",
                                keep=np.random.default_rng(0).random(sum(len(s) for s in scans)) < 0.5)
        for path, assign, step, label in (
                (whole, "source-id", 0.06, "merged, positions given, by point_source_id, step given"),
                (whole, "source-id", None, "merged, positions given, by point_source_id, step estimated"),
                (whole, "nearest", 0.06, "merged, positions given, nearest position, step given"),
                (whole, "nearest", None, "merged, positions given, nearest position, step estimated"),
                (half, "source-id", None, "merged and thinned to half at random, by point_source_id, step "
                                          "estimated")):
            t = time.perf_counter()
            merged, source = read_merged([path])
            parts = split_by_positions(merged, positions, source_id=source, assign=assign, step=step)
            res = voxelize(parts, echo_weights="uniform", tracer=tracer, **common)
            record(label, res, time.perf_counter() - t, parts)
        for cell in (None, 0.05, 0.1):
            t = time.perf_counter()
            merged, _ = read_merged([whole])
            res = voxelize_occupancy(merged, cell=cell, **common)
            used = res.scene.meta["occupancy"]["cell_m"]
            record(f"merged, positions unknown: occupancy of {100 * used:g} cm cells"
                   + (" (the default: the leaf points' spacing)" if cell is None else ""), res,
                   time.perf_counter() - t)
    real = real_rows(tracer)
    load1 = os.getloadavg()
    lines = ["## Merged point clouds without pulses: the demo's oak", "",
             "The demo's synthetic oak (seed 1, leaves facing outwards, "
             f"{truth_area:.0f} m2 of leaves) scanned from the paper's two positions by the VZ-400 at 0.06 deg; "
             "then its echoes merged into one LAS file (world frame, 1 mm, return numbers, point_source_id, the "
             "true classes), with no pulse table and no pose, voxelised as `tlsvox voxelize --scan-positions` "
             "does (`tlsvox.voxel.merged`). 20 cm voxels, `bcmle`, ground at z = 0; leaf area against the "
             "mesh's.", "",
             f"Command: `.venv/bin/python benchmarks/bench_merged.py` ({time.strftime('%Y-%m-%d')}). "
             f"{machine_line(load0, load1)}", "",
             "| input | total leaf area (m2) | against the truth | empty pulses estimated | time (s) | "
             "quality warnings |", "|---|---|---|---|---|---|"]
    for label, area, sec, empty, warnings in rows:
        said = "; ".join(w.split(":")[0] if len(w) > 120 else w for w in warnings) or "none"
        lines.append(f"| {label} | {area:.1f} | {100 * (area / truth_area - 1):+.1f} % | {empty or '-'} | "
                     f"{sec:.1f} | {said} |")
    lines += ["", "The full-pulse rows are the reference: `fraction` weights each echo by its share of the beam "
              "(a simulated scan's column, which no shared cloud has), `uniform` by 1/n as every merged row must. "
              "The occupancy rows count only leaves a scanner saw, with no occlusion correction, and depend on the "
              "cell (from -72 % with 2 cm cells to +61 % with 10 cm on the oak): an index of where leaves were seen, not a "
              "measure of how much."]
    lines += real
    write_page(args.out, lines)
    return 0


def real_rows(tracer) -> list[str]:
    """The real VZ-400i plot scan with its empty pulses rebuilt from its documented angular grid, and as
    a cloud without pulses from the position 0,0,0 (step estimated); their profiles in one picture."""
    data = Path(os.environ.get("VOXLIDAR_SHARED_DATA", ROOT.parent / "shared" / "data")) / "tls-vz400i-scan"
    path = data / "tls_scan.laz"
    if not path.is_file():
        print(f"skipped the real scan: {path} is absent")
        return ["", f"(The real VZ-400i scan was skipped: {path} is absent.)"]
    from tlsvox.scan import AngularGrid, Scan
    from tlsvox.voxel.merged import read_merged, split_by_positions
    from tlsvox.voxel.profile import lad_profile, lad_profile_figure
    from tlsvox.voxel.pulses import rotation_from_rpy
    from tlsvox.voxel.stages import voxelize

    common = dict(voxel_size=0.2, leaf_angle="spherical", progress=False, tracer=tracer)
    t = time.perf_counter()
    grid_res = voxelize([Scan.read(path)], scanner_frame=True, angular_grid=AngularGrid(30.0, 0.048, 2082, 0.0, 0.622, 580),
                        socs_rotation=rotation_from_rpy(1.026, 0.746, -110.019), **common)
    t_grid = time.perf_counter() - t
    t = time.perf_counter()
    merged, source = read_merged([path])
    parts = split_by_positions(merged, "0,0,0", source_id=source)
    merged_res = voxelize(parts, **common)
    t_merged = time.perf_counter() - t
    m = parts[0].meta["merged"]
    profiles = {"empty pulses from the documented angular grid": lad_profile(grid_res.scene, radius=8.0),
                "as a cloud without pulses (--scan-positions 0,0,0)": lad_profile(merged_res.scene, radius=8.0)}
    picture = ROOT / "docs" / "img" / "realscan_merged_profile.png"
    lad_profile_figure(profiles, picture, title="Real VZ-400i plot scan, 20 cm voxels, within 8 m",
                       caption="benchmarks/bench_merged.py; every non-ground echo counted as plant (no intensity)")
    rows = ["", "## The real VZ-400i plot scan without its angular grid", "",
            "`../shared/data/tls-vz400i-scan/tls_scan.laz` (one scan, 1.05 M returns with return numbers; no "
            "intensity, so plant area), 20 cm voxels, spherical leaves, `bcmle`: its empty pulses rebuilt from the "
            "documented angular grid and scanner tilt (the reference here: no truth exists), against the same file "
            "taken as a cloud without pulses from the scanner position 0,0,0, its step estimated "
            f"({m['expected_from'].split(' (')[0].replace('the angular step ', '')}; documented 0.048 x 0.622) and "
            "its empty pulses counted per angular cell.", "",
            "| empty pulses from | empty pulses | plant area (m2) | PAI of the seen voxels within 8 m | time (s) |",
            "|---|---|---|---|---|"]
    for label, res, prof, sec, empty in (
            ("the documented angular grid (`--angular-grid ... --scanner-rpy ...`)", grid_res,
             profiles["empty pulses from the documented angular grid"], t_grid, grid_res.scene.meta["scans"][0]["empty"]),
            ("the cloud (`--scan-positions 0,0,0`)", merged_res,
             profiles["as a cloud without pulses (--scan-positions 0,0,0)"], t_merged, m["empty_pulses"])):
        rows.append(f"| {label} | {empty:,} | {res.scene.total_leaf_area():.1f} | {prof.leaf_area_index:.2f} | "
                    f"{sec:.1f} |")
        print(label, empty, round(res.scene.total_leaf_area(), 1), round(prof.leaf_area_index, 3))
    rows += ["", "![LAD profiles of the real scan](../img/realscan_merged_profile.png)"]
    return rows


if __name__ == "__main__":
    raise SystemExit(main())
