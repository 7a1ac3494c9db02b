"""Figures of decoded posteriors: marginals against the truth and the prior, the decoded
parameters over a flight, and SBC rank histograms."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from mjxsysid import theta as P


DERIVED_LABELS = {"thrust_to_weight": "thrust-to-weight 4 η̄ k_t Ω_max² / (m g)  [–]",
                       "torque_ratio": "torque ratio κ = k_τ / k_t  [m]",
                       "angular_authority[0]": "roll authority l k_t Ω_max² / J_x  [rad/s²]",
                       "angular_authority[1]": "pitch authority l k_t Ω_max² / J_y  [rad/s²]",
                       "angular_authority[2]": "yaw authority l k_t Ω_max² / J_z  [rad/s²]"}


def plot_decoded_over_time(dec: dict, truth, path, window_label: str = "flight-level", title: str | None = None,
                           caption: str | None = None):
    """ẑ and the derived quantities (:data:`~mjxsysid.theta.DERIVED_NAMES`; median, 5–95 % band) over
    time: the single-latent (instant) posterior and, if decoded, the window's (flight-level) one (at
    its own decode times ``times_window`` when given); ``title`` above all in red (a warning),
    ``caption`` below it in black (what the bands are)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter
    t = dec["times"]
    tw = dec.get("times_window", t)
    ident = np.asarray(P.derived(dec["samples"]))  # (K, S, 5)
    identw = np.asarray(P.derived(dec["samples_window"])) if "samples_window" in dec else None
    fig, ax = plt.subplots(2, 3, figsize=(14, 7.2))
    ax = ax.flat
    ax[0].plot(t, dec["zhat"], lw=1)
    ax[0].set_title(f"policy latent ẑ (8 dims, at the {len(t)} decode times)", fontsize=10)
    reg = np.asarray(P.derived(dec["regression"]))
    mark = dict(marker="o", ms=3) if identw is not None and len(tw) < len(t) else {}
    for j, n in enumerate(P.DERIVED_NAMES):
        a = ax[j + 1]
        lo, med, hi = np.percentile(ident[:, :, j], [5, 50, 95], 1)
        a.fill_between(t, lo, hi, alpha=0.2, color="tab:blue", lw=0, label="instant p(θ | ẑ(t)) 5–95 %")
        a.plot(t, med, color="tab:blue", lw=1.2, label="instant median")
        if identw is not None:
            lo, med, hi = np.percentile(identw[:, :, j], [5, 50, 95], 1)
            a.fill_between(tw, lo, hi, alpha=0.3, color="tab:green", lw=0, label=f"{window_label} 5–95 %")
            a.plot(tw, lo, color="tab:green", lw=0.8, ls=":")
            a.plot(tw, hi, color="tab:green", lw=0.8, ls=":")
            a.plot(tw, med, color="darkgreen", lw=1.8, label=f"{window_label} median", **mark)
        a.plot(t, reg[:, j], "--", color="tab:orange", lw=1, label="regression (point)")
        if truth is not None:
            a.axhline(float(np.asarray(P.derived(truth))[j]), color="k", lw=1.5, label="true")
        a.set_title(DERIVED_LABELS.get(n, n), fontsize=10)
        if n != "torque_ratio":
            a.set_yscale("log")
            lo_, hi_ = a.get_ylim()
            if hi_ / lo_ < 30:   # within about a decade: plain numbers 1–9 × 10^k (not 3×10²)
                a.yaxis.set_major_locator(LogLocator(subs=np.arange(1.0, 10.0)))
                a.yaxis.set_major_formatter(FormatStrFormatter("%g"))
                a.yaxis.set_minor_formatter(NullFormatter())
    for a in ax:
        a.set_xlabel("time (s)")
        a.grid(alpha=0.3)
    handles, labels = ax[1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9, frameon=False)
    top = 0.97
    if title:
        fig.suptitle(title, color="tab:red", y=0.995)
        top = 0.93
    if caption:
        fig.text(0.5, top, caption, ha="center", va="top", fontsize=9.5, wrap=True)
        top -= 0.045 * (caption.count("\n") + 1)
    # fixed margins (tight_layout measured every tick label): what it found for this grid, room for five-character tick labels
    fig.subplots_adjust(left=0.05, right=0.99, bottom=0.13, top=top - 0.05, wspace=0.19, hspace=0.37)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_marginals(samples, truth, path, *, point=None, title="decoded posterior vs truth"):
    """Histograms of decoded θ samples (n, 19), the truth (19,) marked where known (None, or NaN entries, for a
    real log: no line and no "true" in the legend); optional point estimate."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator, NullLocator
    fig, axes = plt.subplots(4, 5, figsize=(17, 11))
    for j, ax in enumerate(axes.flat):
        if j >= P.N_PARAMS:
            ax.axis("off")
            continue
        x = samples[:, j]
        log = P.LOG_MASK[j] and np.all(x > 0)
        bins = np.geomspace(x.min(), x.max(), 30) if log and x.min() < x.max() else 30
        ax.hist(x, bins=bins, color="tab:blue", alpha=0.7, histtype="stepfilled")
        if log:
            ax.set_xscale("log")
        if truth is not None and np.isfinite(truth[j]):
            ax.axvline(truth[j], color="k", lw=2, label="true")
        if point is not None:
            ax.axvline(point[j], color="tab:orange", ls="--", label="regression")
        if log:
            # three labelled ticks over the axis (the samples, the truth and the point estimate) and no minor ticks
            # (log axes' minor labels overlap)
            ax.xaxis.set_minor_locator(NullLocator())
            lo, hi = np.log(ax.get_xlim())
            ticks = np.exp(lo + (hi - lo) * np.array([0.15, 0.5, 0.85]))
            ax.set_xticks(ticks, [f"{v:.3g}" for v in ticks])
        else:          # four ticks; small or large values as a mantissa and a power of ten at the axis' end
            ax.xaxis.set_major_locator(MaxNLocator(4))
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-3, 4), useMathText=True)
        ax.set_title(f"{P.PARAM_NAMES[j]} [{P.PARAM_UNITS[j]}]", fontsize=9)
        ax.set_yticks([])
    if axes.flat[0].get_legend_handles_labels()[0]:
        axes.flat[0].legend(fontsize=8)
    fig.suptitle(title)
    # fixed margins (tight_layout measured every tick label: half the time of this plot)
    fig.subplots_adjust(left=0.02, right=0.99, bottom=0.05, top=0.92, wspace=0.15, hspace=0.45)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_rank_histograms(ranks, n_samples: int, path, *, pvalues, names: Sequence[str] | None = None,
                         bins: int | None = None, title: str | None = None, ncols: int = 5) -> Path:
    """Save SBC rank histograms (one panel per dimension, grey 99 % band of a uniform
    histogram, KS p-value in each title) as a PNG. Returns the path."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy import stats

    r = np.asarray(ranks)
    m, d = r.shape
    names = list(names) if names is not None else [f"dim {j}" for j in range(d)]
    if len(names) != d:
        raise ValueError(f"{len(names)} names for {d} dimensions")
    nb = bins or int(min(n_samples + 1, max(5, m // 20), 20))
    edges = np.linspace(-0.5, n_samples + 0.5, nb + 1)
    pv = np.asarray(pvalues)
    lo, hi = stats.binom.ppf([0.005, 0.995], m, 1.0 / nb)
    nrows = -(-d // ncols)
    fig, axes = plt.subplots(nrows, min(ncols, d), figsize=(3.0 * min(ncols, d), 2.4 * nrows),
                             squeeze=False)
    for j, ax in enumerate(axes.ravel()):
        if j >= d:
            ax.axis("off")
            continue
        ax.axhspan(lo, hi, color="0.85", zorder=0)
        ax.axhline(m / nb, color="0.5", lw=0.8, zorder=1)
        ax.hist(r[:, j], bins=edges, color="C0", zorder=2)
        ax.set_title(f"{names[j]}  p={pv[j]:.2g}", fontsize=8)
        ax.set_xticks([0, n_samples])
        ax.tick_params(labelsize=7)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _log_ticks(lo: float, hi: float, ticks: int = 4) -> list[float]:
    """At most ``ticks`` round values (1, 2, 5 × 10ᵏ, thinned evenly; decades first) in [lo, hi]."""
    k0, k1 = int(np.floor(np.log10(lo))), int(np.ceil(np.log10(hi)))
    cand = [m * 10.0 ** k for k in range(k0, k1 + 1) for m in (1, 2, 5) if lo <= m * 10.0 ** k <= hi]
    if len(cand) <= ticks:
        return cand
    step = int(np.ceil(len(cand) / ticks))
    decades = [c for c in cand if np.isclose(np.log10(c), round(np.log10(c)))]
    return decades if 2 <= len(decades) <= ticks else cand[::step]


def _log_x(ax, ticks: int = 4) -> None:
    """Log-scale x with at most ``ticks`` labelled ticks as plain numbers and unlabelled minor
    ticks: what keeps a narrow panel's labels apart (call after plotting)."""
    from matplotlib.ticker import FixedLocator, FuncFormatter, NullFormatter
    ax.set_xscale("log")
    lo, hi = ax.get_xlim()
    ax.xaxis.set_major_locator(FixedLocator(_log_ticks(lo, hi, ticks)))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


UNSEEN_COLOR = "0.7"
"""The log-grounded band's colour in :func:`plot_information_gap` where the log does not see the quantity."""


def plot_information_gap(gap: dict, path, title: str = "what the policy's latent knows vs what the log shows"):
    """One panel per log-identifiable quantity (``gap`` of
    :func:`mjxsysid.identify.gap.information_gap`): the decoder-only 5–95 % band (blue) against the
    log-grounded one (green, its median as a dot; grey, titled "not seen by the log", where the log does not pin
    the quantity: ``seen_by_log`` False), the truth as a black line if known; log scale for positive quantities."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator
    names = list(gap)
    cols = 5
    rows = int(np.ceil(len(names) / cols))
    height = 1.9 * rows + 0.8
    fig, axes = plt.subplots(rows, cols, figsize=(3.4 * cols, height))
    for ax, n in zip(axes.flat, names):
        g = gap[n]
        ax.plot([g["decoder_q05"], g["decoder_q95"]], [1, 1], lw=7, color="tab:blue", solid_capstyle="butt")
        seen = g.get("seen_by_log", True)
        ax.plot([g["log_q05"], g["log_q95"]], [0, 0], lw=7, color="tab:green" if seen else UNSEEN_COLOR,
                solid_capstyle="butt")
        ax.plot([g["log_median"]], [0], "o", color="darkgreen" if seen else "0.35", ms=4)
        if "true" in g:
            ax.axvline(g["true"], color="k", lw=1.5)
        vals = [g["decoder_q05"], g["decoder_q95"], g["log_q05"], g["log_q95"]] + ([g["true"]] if "true" in g else [])
        if min(vals) > 0 and max(vals) / min(vals) > 3:
            _log_x(ax)
        else:
            ax.xaxis.set_major_locator(MaxNLocator(4))
        ax.set_yticks([0, 1], ["log", "decoder"], fontsize=8)
        ax.set_ylim(-0.7, 1.7)
        ax.set_title(f"{n} [{g['unit']}]\n" + (f"width ratio {g['width_ratio']:.2g}" if seen else "not seen by the log"),
                     fontsize=9)
        ax.tick_params(axis="x", labelsize=8)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    fig.suptitle(title, fontsize=11)
    # fixed margins (tight_layout measured every tick label), in inches above and below: what it found for 2 and 3 rows
    fig.subplots_adjust(left=0.045, right=0.99, bottom=0.37 / height, top=1 - 0.84 / height, wspace=0.32, hspace=0.57)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
