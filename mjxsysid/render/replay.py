"""Figures of action replay: motor commands of the policy against K_θ̂ per decoder, and the
RMSE / PCC summary."""
from __future__ import annotations

from typing import Sequence

import numpy as np


def plot_replay(r: dict, rec: dict, path, *, labels: dict, title: str = "", events=()):
    """The paper's action-replay figure: trajectory, latent, and per-motor commands of the
    policy, CFM, Regression and Random over time. ``labels``: method -> legend label (the
    replay study's ``LABELS``); ``events``: times (s) marked on the time axes."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = r["times"]
    fig = plt.figure(figsize=(14, 7))
    gs = fig.add_gridspec(3, 3)
    ax = fig.add_subplot(gs[0:2, 0])
    ax.plot(rec["ref_pos"][:, 0], rec["ref_pos"][:, 1], "k--", lw=1, label="reference")
    ax.plot(rec["pos"][:, 0], rec["pos"][:, 1], lw=1.2, label="flown")
    ax.set_aspect("equal", "datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.legend(fontsize=8)
    ax.set_title("trajectory (top view)")
    axl = fig.add_subplot(gs[2, 0])
    axl.plot(t, r["latent"], lw=0.8)
    axl.set_title("latent ẑ")
    for te in events:
        axl.axvline(te, color="m", lw=1.0, ls="--")
    axl.set_xlabel("time (s)")
    styles = {"policy": dict(color="k", lw=1.0), "true": dict(color="0.5", lw=0.8, ls=":"), "cfm": dict(color="C0", lw=0.9),
              "cfm_mean": dict(color="C2", lw=0.9), "regression": dict(color="C1", lw=0.9, ls="--"),
              "random": dict(color="C3", lw=0.6, alpha=0.5)}
    for i in range(4):
        a = fig.add_subplot(gs[i // 2, 1 + i % 2])
        for m in ("random", "regression", "true", "cfm", "cfm_mean", "policy"):
            y = r["policy"] if m == "policy" else r[m]
            lab = labels[m] + ("" if m == "policy" else
                               f" ({r['metrics'][m]['rmse']:.3f}, {r['metrics'][m]['pcc']:.2f})")
            a.plot(t, y[:, i], label=lab if i == 0 else None, **styles[m])
        for te in events:
            a.axvline(te, color="m", lw=1.0, ls="--")
        a.set_title(f"motor {i + 1} Ω/Ω_max")
        a.grid(alpha=0.3)
        if i == 0:
            handles, names = a.get_legend_handles_labels()
    fig.legend(handles, names, loc="lower right", bbox_to_anchor=(0.98, 0.04), fontsize=9,
               title="method (RMSE, PCC)", ncol=2)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0, 1, 0.96))
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_summary(res: dict, path, *, labels: dict, methods: Sequence[str]):
    """Bar charts of RMSE and PCC per flight and method (``methods``, in order; paper vehicle;
    prior mean as dots). ``labels``: method -> legend label."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    names = [n for n, e in res["flights"].items() if e.get("paper_vehicle")]
    fig, ax = plt.subplots(1, 2, figsize=(12, 3.8))
    w = 0.8 / len(methods)
    for j, m in enumerate(methods):
        x = np.arange(len(names)) + (j - (len(methods) - 1) / 2) * w
        for a, k in zip(ax, ("rmse", "pcc")):
            a.bar(x, [res["flights"][n]["paper_vehicle"][m][k] for n in names], w, label=labels[m],
                  color=f"C{[3, 1, 0, 2, 7][j]}")
            pr = [res["flights"][n].get("prior_vehicles") for n in names]
            if all(pr):
                a.errorbar(x, [p[m][k]["mean"] for p in pr], [p[m][k]["std"] for p in pr], fmt="ko",
                           ms=3, lw=0.8, label="prior vehicles (mean ± std)" if j == 0 else None)
    for a, k in zip(ax, ("motor-command RMSE ↓", "PCC after low-pass ↑")):
        a.set_xticks(np.arange(len(names)), names)
        a.set_title(k)
        a.grid(axis="y", alpha=0.3)
    ax[0].legend(fontsize=8)
    fig.suptitle(f"action replay, {res['policy']['policy']} policy (bars: paper vehicle)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
