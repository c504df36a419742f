"""A replay's files: per-pulse metrics (CSV), summary (JSON), waveforms (NPZ), pictures; all or none."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from voxlidar.safeio import json_text, staged

__all__ = ["output_paths", "write_replay"]


def _columns(rows):
    cols = []
    for r in rows:
        for k in r:
            if k not in cols:
                cols.append(k)
    return cols


def output_paths(out: Path, schemes, *, plots: bool = True) -> dict:
    """The files :func:`write_replay` writes into ``out``."""
    paths = {"metrics": out / "metrics.csv", "summary": out / "summary.json", "waveforms": out / "waveforms.npz"}
    if plots:
        for s in schemes:
            for kind in ("overlay", "radargram", "scores"):
                paths[f"{kind}-{s}"] = out / f"{kind}-{s}.png"
    return paths


def write_replay(prepared, results, out, *, plots: bool = True, plot_count: int = 6, extra: dict | None = None) -> dict:
    """Write the replay of ``results`` (one :class:`ReplayResult` per scheme) into the folder ``out``.

    Files: ``metrics.csv`` (one row per scheme, pulse and method),
    ``summary.json`` (the overall and multi-echo scores, the settings, what
    each fold fitted on its training pulses, the file's geometry),
    ``waveforms.npz`` (measured records above the baseline, their masks and
    every method's held-out prediction, per scheme), and per scheme the
    pictures ``overlay-*.png``, ``radargram-*.png``, ``scores-*.png``.
    Written to temporary names and renamed together: a failure leaves none.

    Returns
    -------
    dict
        name -> path written.
    """
    out = Path(out)
    paths = output_paths(out, [r.scheme for r in results], plots=plots)
    p = prepared.pulses
    with staged(list(paths.values())) as tmp:
        rows = [dict(scheme=r.scheme, **row) for r in results for row in r.rows]
        cols = _columns(rows)
        with open(tmp[paths["metrics"]], "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=cols)
            w.writeheader()
            for row in rows:
                w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
        summary = {"file": p.name, "pulses": len(p), "geometry": p.meta.get("geometry"),
                   "sensor": {"divergence_mrad": float(p.divergence_mrad), "wavelength_nm": float(p.wavelength_nm),
                              **({"defaults": p.meta["sensor"]["defaults"]} if "sensor" in p.meta else {})},
                   "pulse_shape": prepared.shape_source,
                   "echoes_per_pulse": float(prepared.echo_counts().mean()),
                   "schemes": {r.scheme: {"summary": r.summary, "settings": r.settings, "seconds": r.seconds,
                                          "folds": [{k: v for k, v in f.items() if k != "test_pulses"}
                                                    for f in r.folds]} for r in results}}
        if extra:
            summary.update(extra)
        Path(tmp[paths["summary"]]).write_text(json_text(summary, indent=1) + "\n")
        arrays = {"signal": prepared.signal.astype(np.float32), "mask": prepared.mask,
                  "n_samples": p.n_samples, "bin0": p.bin0, "step": p.step, "origin": p.origin, "line": p.line}
        for r in results:
            for m, pred in r.predictions.items():
                arrays[f"{r.scheme}/{m}"] = pred.astype(np.float32)
        with open(tmp[paths["waveforms"]], "wb") as fh:
            np.savez_compressed(fh, **arrays)
        if plots:
            from clsim.replay.plots import plot_overlay, plot_radargrams, plot_scores

            for r in results:
                plot_overlay(prepared, r, tmp[paths[f"overlay-{r.scheme}"]], count=plot_count)
                plot_radargrams(prepared, r, tmp[paths[f"radargram-{r.scheme}"]])
                plot_scores(r, tmp[paths[f"scores-{r.scheme}"]])
    return paths
