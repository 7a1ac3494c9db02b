"""Figures of the online tuner: gains over time and tracking error per method."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from mjxsysid.control.high_level import GAIN_BOUNDS, GAIN_NAMES, PRESETS


def plot_gains(res: dict, path, *, labels: dict, tuned: Sequence[str], title: str = "") -> Path:
    """Gains over time of every tuned method (``tuned``; mean over vehicles, 5–95 % band if
    several) against the fixed naive and baseline presets. ``res``: method -> {"tuned": TunedFlight},
    as :func:`mjxsysid.tune.compare.compare_methods` returns; ``labels``: method -> legend label."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 4, figsize=(14, 5.5), sharex=True)
    for j, ax in enumerate(axes.ravel()):
        for m, r in res.items():
            tf = r["tuned"]
            g = tf.gains[..., j]                      # (B, U)
            t = tf.update_times
            if m in tuned:
                line, = ax.step(t, g.mean(0), where="post", label=labels[m])
                if g.shape[0] > 1:
                    lo, hi = np.percentile(g, [5, 95], 0)
                    ax.fill_between(t, lo, hi, step="post", alpha=0.15, color=line.get_color())
        for name, ls in (("naive", ":"), ("baseline", "--")):
            ax.axhline(PRESETS[name][j], color="k", ls=ls, lw=0.8, label=name if j == 0 else None)
        ax.set_ylim(GAIN_BOUNDS[j, 0] - 0.05 * GAIN_BOUNDS[j, 1], GAIN_BOUNDS[j, 1] * 1.05)
        ax.set_title(GAIN_NAMES[j])
        if j >= 4:
            ax.set_xlabel("time (s)")
    axes[0, 0].legend(fontsize=7)
    fig.suptitle(title or "high-level gains applied over time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_tracking(res: dict, path, *, labels: dict, index: int = 0, title: str = "") -> Path:
    """Position error over time per method (vehicle ``index``; mean and 5–95 % over vehicles
    if several) and the x–y path of vehicle ``index``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(13, 4.8), gridspec_kw={"width_ratios": [1.6, 1]})
    ref_drawn = False
    for m, r in res.items():
        fl = r["tuned"].flight
        err = np.linalg.norm(fl.frame.pos - fl.ref_pos, axis=-1)    # (B, T)
        t = fl.time[0]
        if err.shape[0] > 1:
            line, = a0.plot(t, np.median(err, 0), label=f"{labels[m]} (median)")
            lo, hi = np.percentile(err, [5, 95], 0)
            a0.fill_between(t, lo, hi, alpha=0.12, color=line.get_color())
        else:
            a0.plot(t, err[0], label=labels[m])
        if not ref_drawn:
            a1.plot(fl.ref_pos[index, :, 0], fl.ref_pos[index, :, 1], "k--", lw=1, label="reference")
            ref_drawn = True
        a1.plot(fl.frame.pos[index, :, 0], fl.frame.pos[index, :, 1], lw=1, label=labels[m])
    a0.set_xlabel("time (s)")
    a0.set_ylabel("position error (m)")
    a0.set_yscale("log")
    a0.legend(fontsize=8)
    a1.set_aspect("equal", "datalim")
    a1.set_xlabel("x (m)")
    a1.set_ylabel("y (m)")
    a1.legend(fontsize=7)
    fig.suptitle(title or "tracking")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)


def plot_prediction_error(cases: dict, path, *, title: str = "") -> Path:
    """Position error of the tuner's predictive rollout (true θ) against the flight it predicts,
    over the horizon: one panel per case {name: {'time' (H,), mode: {'pos_err' (B, H)}}}, a line
    per rotor-state start (median over vehicles, 5–95 % shaded)."""
    from mjxsysid.render.plots import _figure, _save

    names = list(cases)
    fig = _figure((4.2 * len(names), 3.4))
    axes = fig.subplots(1, len(names), squeeze=False)[0]
    colors = {"estimate": "C0", "steady": "C3", "true": "k"}
    for ax, name in zip(axes, names):
        c = cases[name]
        t = np.asarray(c["time"])
        for mode, col in colors.items():
            if mode not in c:
                continue
            e = np.maximum(np.asarray(c[mode]["pos_err"]), 1e-7) * 1e3
            ax.plot(t, np.median(e, 0), color=col, label=mode, ls="--" if mode == "true" else "-")
            ax.fill_between(t, np.percentile(e, 5, 0), np.percentile(e, 95, 0), color=col, alpha=0.15)
        ax.set_yscale("log")
        ax.set_xlabel("time into the prediction (s)")
        ax.set_title(name, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("position error (mm, floor 1e-4)")
    axes[0].legend(fontsize=8, title="rotors start", title_fontsize=8)
    if title:
        fig.suptitle(title, fontsize=10)
    return _save(fig, path)
