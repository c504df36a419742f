"""Write docs/benchmarks.md: one index of the pages the benchmark scripts write.

Each script in benchmarks/ writes its own page to docs/bench/<topic>.md, with
the command that made it and its figures. This script lists them, grouped by
the stage they measure, one row each: the page's title, what it measures, the
command and the date it was written (the first date the page states, else the
date git last saw it change). A page that no group names fails the script, so
a new benchmark gets its row and its sentence.

    .venv/bin/python benchmarks/collect.py
"""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: (group title, [(page stem, what it measures)]) in reading order; a stem also
#: takes its variants (``devices`` takes ``devices-nvidia-h100``).
GROUPS: list[tuple[str, list[tuple[str, str]]]] = [
    ("Terrestrial scans and voxels", [
        ("scanner", "the TLS scanner simulator's pulses per second against its sub-rays per pulse"),
        ("register_classify", "registration error and time; leaf/wood classification against the synthetic truth"),
        ("classify_mixture", "the leaf/wood threshold from two Gaussians or BIC's choice, per scan"),
        ("classify_modes", "leaf/wood F1 by what the cloud holds: reflectance, raw intensity (relative or "
                           "calibrated), x, y, z only; a merged cloud classified by geometry and voxelised"),
        ("relabel", "leaf echoes on fitted cylinders relabelled wood: classification and leaf area"),
        ("voxelize", "beams traced per second; LAD error and time against voxel size"),
        ("memory", "peak memory and time against voxel size, dense and sparse layouts"),
        ("echo_weights", "the leaf box's LAD with each echo-weight rule against the exact leaf area"),
        ("merged", "merged clouds without pulses (scan positions given or not) against the full-pulse pipeline and "
                   "the truth; the real VZ-400i scan without its angular grid"),
        ("lad_terms", "where the oak's leaf area goes: the estimators' assumptions one at a time"),
        ("qsm", "solid wood from fitted cylinders against the true cylinders"),
        ("pipeline", "the whole pipeline: waveform accuracy against time, per voxel size"),
    ]),
    ("Leaf angles", [
        ("leaf_angles", "the leaf inclination measured from the scans against the true distribution"),
        ("leaf_angle_layers", "each crown layer's measured G in its own voxels"),
        ("leaf_angle_kernel", "the measurement kernel against the scans, per true inclination"),
        ("leaf_angle_speed", "time against accuracy of the leaf-angle measurement"),
    ]),
    ("Photon transport", [
        ("clsim", "photons per second per device; paper against exact physics; error against time"),
        ("mitransient", "clsim against Mitsuba 3's transient renderer on the same slab and oak"),
        ("devices", "both kernels on every OpenCL device of a machine, side by side"),
        ("walk_profile", "where the voxel walk spends its time"),
        ("kernel_ab", "the transport kernel against its base tree, alternating runs"),
        ("waveform_terms", "the exact-LAD twin's waveform error, term by term (leaves, wood, hot spot)"),
        ("plot", "a plot of many trees: shared voxel bricks against copies"),
    ]),
    ("Measured waveforms", [
        ("decompose", "Gaussian decomposition: waveforms per second and echoes against known answers"),
        ("decompose_loop", "a loop of single decompose calls against scipy's curve_fit and the batch path"),
        ("decompose_returns", "the decomposition against the instruments' own discrete returns"),
        ("replay_neon", "NEON Harvard Forest pulses replayed over a scene of the other pulses"),
        ("replay_leica", "a Leica LAS 1.3 tile's pulses replayed"),
        ("replay_oak", "airborne waveforms replayed over the synthetic oak's TLS scene"),
    ]),
    ("Airborne surveys", [
        ("survey", "survey pulses per second, a direct loop and Dask"),
        ("first_order", "the deterministic first order: pulses per second against agreement with the mesh"),
        ("helios", "clsim and HELIOS++ on the same pulses: speed, memory and agreement with the mesh"),
        ("million", "a million-pulse flight with its LAS written as it goes, killed and resumed"),
    ]),
]

HEADER = """# Benchmarks

Every speed and accuracy figure in these pages comes from a script in
`benchmarks/`; each page below states the command that made it, the machine
and its load. Ratios are measured side by side in one run; times are medians
of several runs. Unless a page says otherwise the machine is the project's
standard one: 2 CPU cores, 24 GB, no GPU, OpenCL on the best working CPU
runtime ([devices](devices.md)). Re-run them all with `make bench`, then
`.venv/bin/python benchmarks/collect.py` rewrites this index.
"""

DATE = re.compile(r"20\d\d-\d\d-\d\d")
COMMAND = re.compile(r"`((?:[^`]*\s)?(?:\.venv/bin/)?python3? benchmarks/[^`]+|benchmarks/[^`]+\.py[^`]*)`")


def title(text: str) -> str:
    return text.splitlines()[0].lstrip("#").strip()


def command(text: str) -> str:
    found = COMMAND.search(text)
    return f"`{found.group(1)}`" if found else "on the page"


def written(page: Path, text: str) -> str:
    found = DATE.search(text)
    if found:
        return found.group(0)
    try:
        out = subprocess.run(["git", "log", "-1", "--format=%cs", "--", str(page)], cwd=ROOT, capture_output=True,
                             text=True, check=False).stdout.strip()
    except OSError:
        out = ""
    return out or "-"


def variants(stem: str, names: list[str]) -> list[str]:
    return [n for n in names if n == stem or n.startswith(stem + "-")]


def main() -> int:
    pages = {p.stem: p for p in sorted((ROOT / "docs" / "bench").glob("*.md"))}
    listed: list[str] = []
    out = [HEADER]
    for group, rows in GROUPS:
        out += [f"\n## {group}\n", "| page | what it measures | command | written |", "|---|---|---|---|"]
        for stem, what in rows:
            for k, name in enumerate(variants(stem, sorted(pages))):
                text = pages[name].read_text(encoding="utf-8")
                said = what if k == 0 else "as above, for the case its title names"
                out.append(f"| [{title(text)}](bench/{name}.md) | {said} | {command(text)} | {written(pages[name], text)} |")
                listed.append(name)
    missing = sorted(set(pages) - set(listed))
    if missing:
        print(f"collect.py: no group names {', '.join(missing)}; add each to GROUPS with what it measures")
        return 1
    target = ROOT / "docs" / "benchmarks.md"
    tmp = target.with_suffix(".tmp")
    tmp.write_text("\n".join(out) + "\n", encoding="utf-8")
    os.replace(tmp, target)
    print(f"wrote {target}: {len(listed)} pages in {len(GROUPS)} groups")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
