"""Benchmark: the leaf-angle deconvolution's time against its accuracy, this tree's code beside an older one.

The synthetic oak (``make_tree(TreeParams(leaf_angle=KIND), seed=0)``, outward
leaf azimuths) scanned from the paper's two positions by the simulated RIEGL
VZ-400 with the true poses, once; then, on the same scans and in one process,
:func:`tlsvox.leafangles.measure_leaf_angles` (4 layers, the defaults) of this
working tree with ``samples`` 1, 3 (the default) and 6, and that of an older
revision (``--base``, default 31ec0d7: every echo scanned by the pulse grid
its nearest echo needs) with the default, each run ``--repeats`` times in
turn.  Per setting: the median wall time, and the accuracy against the tree's
own leaf normals as ``bench_leaf_angles.py`` scores it (mean inclination and
G of every layer and the crown; every repeat gives the same numbers, the
seed being fixed).

    .venv/bin/python benchmarks/bench_leaf_angle_speed.py [--kind uniform] [--repeats 3]

Writes docs/bench/leaf_angle_speed.md (``--out``), its numbers in a JSON
beside it, and a time-against-error figure (``--png``; ``--replot`` redraws
it from the JSON without running anything).
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _bench import machine_line, write_page  # noqa: E402
from bench_leaf_angles import score  # noqa: E402


def module_at(rev: str):
    """``tlsvox/leafangles.py`` as it was at ``rev`` (a revision before it became a package), imported under
    another name."""
    text = subprocess.run(["git", "show", f"{rev}:tlsvox/leafangles.py"], cwd=ROOT, check=True,
                          capture_output=True, text=True).stdout
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "leafangles_base.py"
        path.write_text(text)
        spec = importlib.util.spec_from_file_location("leafangles_base", path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules["leafangles_base"] = mod  # its dataclasses look their module up
        spec.loader.exec_module(mod)
    return mod


def summary(rows) -> dict:
    layers = rows[:-1]
    return {"worst_mean_deg": max(abs(r["measured_mean_deg"] - r["true_mean_deg"]) for r in layers),
            "worst_G_pct": max(r["G_error_beta_pct"] for r in layers),
            "crown_mean_deg": rows[-1]["measured_mean_deg"] - rows[-1]["true_mean_deg"],
            "crown_G_pct": rows[-1]["G_error_beta_pct"],
            "layers_ok": sum(abs(r["measured_mean_deg"] - r["true_mean_deg"]) <= 5 and r["G_error_beta_pct"] <= 5
                             for r in layers),
            "per_layer": [(round(r["measured_mean_deg"] - r["true_mean_deg"], 1), round(r["G_error_beta_pct"], 1))
                          for r in layers]}


def draw(png, data) -> None:
    """The time-against-error chart of a run's ``data`` (as written to the page's JSON)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from voxlidar.safeio import atomic_write

    fig, ax = plt.subplots(figsize=(7.0, 4.6))
    for j, name in enumerate(data["settings"]):
        t, a = data["median_s"][name], data["accuracy"][name]
        colour = f"C{j}"
        ax.plot(t, a["worst_G_pct"], "o", ms=8, color=colour, label=f"{name}: worst layer's G error (%)")
        ax.plot(t, abs(a["crown_mean_deg"]), "s", ms=7, mfc="none", color=colour,
                label=f"{name}: crown's mean inclination error (deg)")
    ax.axhline(5, color="grey", lw=0.8, ls="--", label="goal (5 % / 5 deg)")
    ax.set_xlabel("wall time, two scans (s, 2 CPU cores; median)")
    ax.set_ylabel("error (% for G, degrees for the mean)")
    ax.set_title(f"Leaf-angle deconvolution: time against error ({data['kind']} leaves, oak seed 0)")
    ax.set_xlim(left=0)
    ax.set_ylim(0, 7)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2, frameon=False)
    fig.tight_layout()
    atomic_write(png, lambda tmp: fig.savefig(tmp, dpi=120, format="png", bbox_inches="tight"))
    plt.close(fig)
    print(f"wrote {png}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kind", default="uniform", help="true leaf inclination distribution (default uniform)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--base", default="31ec0d7", help="older revision to compare with (default 31ec0d7)")
    ap.add_argument("--out", default=str(ROOT / "docs/bench/leaf_angle_speed.md"))
    ap.add_argument("--png", default=str(ROOT / "docs/img/leaf_angle_speed.png"))
    ap.add_argument("--replot", action="store_true", help="redraw the chart from the page's JSON; run nothing")
    args = ap.parse_args(argv)
    if args.replot:
        import json

        draw(args.png, json.loads(Path(args.out).with_suffix(".json").read_text()))
        return 0

    from tlsvox import leafangles
    from tlsvox.truth.scanner import paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import TreeParams, make_tree

    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                          text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "tlsvox/leafangles"], cwd=ROOT, capture_output=True,
                           text=True).stdout.strip()
    this = f"{head}{' + working-tree changes' if dirty else ''}"
    base = module_at(args.base)
    tree = make_tree(TreeParams(leaf_angle=args.kind), seed=0)
    scans = [simulate_scan(tree, pose=pose, seed=10 + i, scan_id=i, progress=False)
             for i, pose in enumerate(paper_scan_poses(tree))]
    for s in scans:
        s.pose = s.pose_true
    settings = [(f"{args.base} (before)", base, 3), ("this tree, samples 1", leafangles, 1),
                ("this tree, samples 3 (default)", leafangles, 3), ("this tree, samples 6", leafangles, 6)]
    load0 = os.getloadavg()
    times = {name: [] for name, *_ in settings}
    acc = {}
    t_all = time.perf_counter()
    for rep in range(args.repeats):
        for name, mod, samples in settings:
            t = time.perf_counter()
            res = mod.measure_leaf_angles(scans, layers=4, samples=samples)
            times[name].append(time.perf_counter() - t)
            acc[name] = summary(score(tree, res))
            print(f"repeat {rep + 1}: {name}: {times[name][-1]:.1f} s, {acc[name]}", flush=True)
    load1 = os.getloadavg()
    med = {name: statistics.median(v) for name, v in times.items()}
    ref = med[settings[0][0]]
    lines = [f"# Leaf angles: time against accuracy ({args.kind} leaves)", "",
             f"Command: `.venv/bin/python benchmarks/bench_leaf_angle_speed.py --kind {args.kind} --repeats "
             f"{args.repeats}` ({(time.perf_counter() - t_all) / 60:.1f} min). {machine_line(load0, load1)}", "",
             f"The synthetic oak (seed 0, {args.kind} leaves facing outwards) scanned from the paper's two positions "
             "by the simulated VZ-400, true poses; `measure_leaf_angles(scans, layers=4, samples=N)` with every "
             f"other setting at its default, on the same scans in one process: this tree's code ({this}) beside "
             f"revision {args.base}'s `tlsvox/leafangles.py` (imported beside today's other modules), whose kernel "
             "scanned every sampled echo with the pulse grid its nearest echo needed (this tree's scans each echo "
             "only with the pulses whose rays pass within the 2.5 cm radius of it). Each setting ran "
             f"{args.repeats} times in turn; the median wall time. Errors against the "
             "tree's own leaf normals (as in bench_leaf_angles.py): mean inclination (measured - true) and G "
             "(the largest relative error over the scanned zenith angles), the worst of the 4 layers and the "
             "crown; the same seed gives the same numbers on every repeat.", "",
             "| setting | median time (s) | x faster than before | layers within 5 deg and 5 % | worst layer mean "
             "(deg) | worst layer G (%) | crown mean (deg) | crown G (%) | per layer (deg, G %) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for name, *_ in settings:
        a = acc[name]
        lines.append(f"| {name} | {med[name]:.1f} | {ref / med[name]:.2f} | {a['layers_ok']}/4 | "
                     f"{a['worst_mean_deg']:.1f} | {a['worst_G_pct']:.1f} | {a['crown_mean_deg']:+.1f} | "
                     f"{a['crown_G_pct']:.1f} | {'; '.join(f'{m:+.1f}, {g:.1f}' for m, g in a['per_layer'])} |")
    lines += ["", f"![time against error](../img/{Path(args.png).name})"]
    write_page(args.out, lines, echo=True)

    import json

    from voxlidar.safeio import atomic_write

    data = {"kind": args.kind, "settings": [name for name, *_ in settings], "median_s": med, "accuracy": acc}
    atomic_write(Path(args.out).with_suffix(".json"), lambda tmp: Path(tmp).write_text(json.dumps(data, indent=1)))
    draw(args.png, data)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
