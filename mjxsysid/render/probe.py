"""The probe's picture: the weak systems against the training prior."""
from __future__ import annotations

import numpy as np

from mjxsysid import theta as P

QUANTITIES = ("thrust-to-weight", "roll authority (rad/s²)", "yaw authority (rad/s²)",
              "motor time constant τ_m (s)", "weakest motor η_min", "mass (kg)")


def quantities(theta) -> np.ndarray:
    """θ (n, 19) -> (n, 6): the identifiable combinations and the parameters the probe reports
    (in the order of :data:`QUANTITIES`)."""
    th = np.asarray(theta, np.float64)
    auth = np.asarray(P.angular_authority(th))
    return np.stack([np.asarray(P.thrust_to_weight(th)), auth[:, 0], auth[:, 2], th[:, P.TAU_M],
                     th[:, P.ETA].min(1), th[:, P.MASS]], 1)


def plot_weak_vs_prior(weak_theta, prior_theta, path, *, title="weak systems vs the training prior"):
    """Histograms (log axes where the quantity spans decades) of the weak systems' quantities
    over the prior's, one panel each."""
    import matplotlib
    import matplotlib.ticker
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    w, p = quantities(weak_theta), quantities(prior_theta)
    fig, axes = plt.subplots(2, 3, figsize=(12, 6.5))
    for j, ax in enumerate(axes.ravel()):
        both = np.concatenate([w[:, j], p[:, j]])
        log = both.min() > 0 and both.max() / both.min() > 20
        lo = min(np.percentile(w[:, j], 0.5), np.percentile(p[:, j], 0.5))     # each set's own range
        hi = max(np.percentile(w[:, j], 99.5), np.percentile(p[:, j], 99.5))
        bins = np.geomspace(lo, hi, 40) if log else np.linspace(lo, hi, 40)
        ax.hist(p[:, j], bins=bins, density=True, alpha=0.5, color="0.5", label="training prior")
        ax.hist(w[:, j], bins=bins, density=True, alpha=0.6, color="C3", label="weak systems")
        if log:
            ax.set_xscale("log")
            ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_title(QUANTITIES[j], fontsize=10)
        ax.set_yticks([])
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_probe_loop(ev: dict, on_weak: dict, path):
    """The probe loop at a glance: per policy (the given one, each round's probed one, the uniform
    control) and evaluation set, the RMSE ratio to the oracle (bars; the success rate in the bar
    where below 100 %), and each policy's mean badness on each probe round's weak systems."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    policies = list(ev)
    sets = [s for s in ("default", "stress", "stress_wide", "paper") if s in ev[policies[0]]]
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(13, 4.4), gridspec_kw={"width_ratios": [3, 1.4]})
    w = 0.8 / len(policies)
    for i, p in enumerate(policies):
        x = np.arange(len(sets)) + (i - (len(policies) - 1) / 2) * w
        r = [ev[p][s]["rmse_ratio"] or np.nan for s in sets]
        ax.bar(x, r, w, color=f"C{i}", label=p)
        for xx, s in zip(x, sets):
            succ = ev[p][s]["success_policy"]
            if succ < 1:
                ax.text(xx, 0.05, f"{succ:.1%}", ha="center", va="bottom", fontsize=7, rotation=90, color="w")
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.axhline(1.3, color="C3", lw=0.8, ls=":", label="1.3× (stress target)")
    ax.set_xticks(np.arange(len(sets)))
    ax.set_xticklabels(sets)
    ax.set_ylabel("position RMSE / oracle's (both flew)")
    ax.legend(fontsize=8)
    ax.set_title("10 s lemniscate vs the oracle K_θ (success rate in the bar where < 100 %)", fontsize=9)
    rounds = sorted(on_weak)
    w2 = 0.8 / len(policies)
    for i, p in enumerate(policies):
        x = np.arange(len(rounds)) + (i - (len(policies) - 1) / 2) * w2
        ax2.bar(x, [on_weak[r][p]["badness_mean"] for r in rounds], w2, color=f"C{i}")
    ax2.axhline(1.0, color="k", lw=0.8, ls="--")
    ax2.set_xticks(np.arange(len(rounds)))
    ax2.set_xticklabels([f"round {r}" for r in rounds])
    ax2.set_title("mean badness on each round's weak systems", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
