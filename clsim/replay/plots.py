"""Pictures of a replay: measured and predicted waveforms, radargrams, score scatter plots.

Each function takes a :class:`~clsim.replay._echoes.Prepared` and one scheme's
:class:`~clsim.replay._replay.ReplayResult`, draws with Matplotlib (Agg) and
writes the picture atomically in the format of its file name.
"""

from __future__ import annotations

import numpy as np

from voxlidar.safeio import finish_figure, save_figure

__all__ = ["plot_overlay", "plot_radargrams", "plot_scores", "sample_pulses"]

_STYLE = {"simulation": ("tab:red", "-", "clsim simulation"),
          "blair_hofton": ("tab:blue", "--", "Blair-Hofton (training echoes)"),
          "blair_hofton_samples": ("tab:cyan", ":", "Blair-Hofton (training samples)"),
          "nearest": ("tab:green", "-.", "nearest training pulse")}


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def sample_pulses(result, count: int = 6, *, seed: int = 0) -> np.ndarray:
    """Pulses to show: half single-peaked, half with two or more peaks, drawn with ``seed``."""
    first = next(iter(result.predictions))
    rows = [r for r in result.rows if r["method"] == first]
    single = np.array([r["pulse"] for r in rows if r["peaks"] < 2 and r["covered"]])
    multi = np.array([r["pulse"] for r in rows if r["peaks"] >= 2 and r["covered"]])
    rng = np.random.default_rng(seed)
    k_multi = min(len(multi), count // 2)
    k_single = min(len(single), count - k_multi)
    pick = np.concatenate([rng.choice(single, k_single, replace=False) if k_single else [],
                           rng.choice(multi, k_multi, replace=False) if k_multi else []]).astype(int)
    return np.sort(pick)


def _heights(prepared, i):
    p = prepared.pulses
    n = int(p.n_samples[i])
    return p.bin0[i, 2] + np.arange(n) * p.step[i, 2], n


def plot_overlay(prepared, result, path, *, pulses=None, count: int = 6):
    """Measured and predicted waveforms of a few pulses, amplitude against elevation."""
    plt = _plt()
    pick = sample_pulses(result, count) if pulses is None else np.asarray(pulses, dtype=int)
    cols = min(3, len(pick))
    rows = int(np.ceil(len(pick) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.4 * rows), squeeze=False)
    score = {(r["pulse"], r["method"]): r for r in result.rows}
    for ax, i in zip(axes.flat, pick):
        z, n = _heights(prepared, i)
        m = prepared.mask[i, :n]
        ax.plot(np.where(m, prepared.signal[i, :n], np.nan), z, "k.", ms=3, label="measured")
        for meth, pred in result.predictions.items():
            c, ls, label = _STYLE[meth]
            r = score[(i, meth)]["r"]
            ax.plot(pred[i, :n], z, color=c, ls=ls, lw=1.2, label=f"{label}, r={r:.3f}")
        peaks = score[(i, next(iter(result.predictions)))]["peaks"]
        ax.set_title(f"pulse {i} (line {int(prepared.pulses.line[i])}, {peaks} peak{'s' if peaks != 1 else ''})",
                     fontsize=9)
        ax.set_xlabel("return above baseline (counts)")
        ax.set_ylabel("elevation (m)")
        ax.legend(fontsize=6, loc="best")
    for ax in list(axes.flat)[len(pick):]:
        ax.axis("off")
    fig.suptitle(f"{prepared.pulses.name}: measured and held-out predicted waveforms ({result.scheme} folds)",
                 fontsize=10)
    return finish_figure(fig, path, caption="Each prediction was made without the pulse shown: from the other "
                                            "folds' pulses only (scene, calibration, footprint width).")


def _radargram(prepared, values, order, z_edges):
    img = np.full((len(z_edges) - 1, len(order)), np.nan)
    for col, i in enumerate(order):
        z, n = _heights(prepared, i)
        m = prepared.mask[i, :n]
        row = np.digitize(z[m], z_edges) - 1
        ok = (row >= 0) & (row < img.shape[0])
        acc = np.zeros(img.shape[0])
        cnt = np.zeros(img.shape[0])
        np.add.at(acc, row[ok], values[i, :n][m][ok])
        np.add.at(cnt, row[ok], 1)
        img[cnt > 0, col] = acc[cnt > 0] / cnt[cnt > 0]
    return img


def plot_radargrams(prepared, result, path, *, line=None, methods=("simulation", "blair_hofton")):
    """Measured and predicted radargrams of one scan line side by side (default: the longest line)."""
    plt = _plt()
    p = prepared.pulses
    if line is None:
        line = int(np.bincount(p.line).argmax())
    order = np.flatnonzero(p.line == line)
    order = order[np.argsort(p.bin0[order, 1])]
    zs = np.concatenate([_heights(prepared, i)[0] for i in order])
    z_edges = np.arange(np.floor(zs.min()), np.ceil(zs.max()) + 0.15, 0.15)
    panels = [("measured", prepared.signal)] + [(m, result.predictions[m]) for m in methods
                                                if m in result.predictions]
    imgs = [_radargram(prepared, v, order, z_edges) for _, v in panels]
    vmax = np.nanpercentile(imgs[0], 99.5)
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.2), sharey=True, squeeze=False)
    y = p.bin0[order, 1] - p.bin0[order, 1].min()
    extent = (y.min(), y.max(), z_edges[0], z_edges[-1])
    for ax, (name, _), img in zip(axes[0], panels, imgs):
        im = ax.imshow(img, origin="lower", aspect="auto", extent=extent, vmin=0, vmax=vmax, cmap="viridis",
                       interpolation="nearest")
        ax.set_title(name if name == "measured" else _STYLE[name][2], fontsize=9)
        ax.set_xlabel("across-track distance (m)")
    axes[0, 0].set_ylabel("elevation (m)")
    fig.colorbar(im, ax=axes[0].tolist(), label="return above baseline (counts)", shrink=0.85)
    fig.suptitle(f"{p.name}, scan line {line}: measured and held-out predicted radargrams ({result.scheme} folds)",
                 fontsize=10)
    try:  # laid out by hand: the shared colour bar does not go with tight_layout
        return save_figure(fig, path)
    finally:
        plt.close(fig)


def plot_scores(result, path):
    """Predicted against measured RH50, RH98, canopy cover; energy ratio and r per method."""
    plt = _plt()
    fig, axes = plt.subplots(2, 3, figsize=(11.5, 7.0))
    by = {}
    for r in result.rows:
        if r["covered"]:
            by.setdefault(r["method"], []).append(r)
    for (key, label, unit), ax in zip((("rh50", "RH50", "m"), ("rh98", "RH98", "m"), ("cover", "canopy cover", "")),
                                      axes[0]):
        lo, hi = np.inf, -np.inf
        for meth, rows in by.items():
            c, _, name = _STYLE[meth]
            x = np.array([r[f"{key}_measured"] for r in rows])
            y = np.array([r[key] for r in rows])
            ax.scatter(x, y, s=5, color=c, alpha=0.5, label=name)
            ok = np.isfinite(x) & np.isfinite(y)
            if ok.any():
                lo, hi = min(lo, x[ok].min(), y[ok].min()), max(hi, x[ok].max(), y[ok].max())
        if np.isfinite(lo):
            ax.plot([lo, hi], [lo, hi], "k-", lw=0.8, label="1:1")
        u = f" ({unit})" if unit else ""
        ax.set_xlabel(f"measured {label}{u}")
        ax.set_ylabel(f"predicted {label}{u}")
        ax.set_title(f"{label}: predicted against measured", fontsize=9)
        ax.legend(fontsize=6)
    names = list(by)
    for ax, (key, label) in zip(axes[1], (("energy_ratio", "energy ratio (predicted / measured)"),
                                          ("r", "Pearson r, as predicted"), ("r_best", "Pearson r, best lag"))):
        data = [np.array([r[key] for r in by[m]]) for m in names]
        data = [d[np.isfinite(d)] for d in data]
        ax.boxplot(data, showfliers=False)
        ax.set_xticks(range(1, len(names) + 1), [_STYLE[m][2].replace(" (", "\n(") for m in names], fontsize=6)
        ax.set_ylabel(label)
        ax.set_title(label, fontsize=9)
        if key == "energy_ratio":
            ax.axhline(1.0, color="k", lw=0.8)
    fig.suptitle(f"Held-out scores per pulse ({result.scheme} folds); boxes: quartiles, whiskers 1.5 IQR",
                 fontsize=10)
    return finish_figure(fig, path)
