"""The probe's picture: the weak systems against the training prior (issue 18)."""
from __future__ import annotations

import numpy as np

from mjxsysid import params as P

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
