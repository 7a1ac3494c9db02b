"""Static figures (PNG, matplotlib Agg) of rollouts and of θ priors.

Figures are built with :class:`matplotlib.figure.Figure` directly (no pyplot), so they neither
need a display nor change the pyplot backend of a notebook.
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from mjxsysid import theta as P

ROTOR_COLORS = ("#d9472b", "#2f6fd6", "#e8963a", "#35a3c4")  # ccw red-ish, cw blue-ish
ROTOR_STYLES = ("-", "-", "--", "--")  # rotors 3, 4 dashed so overlapping curves stay visible
AXIS_COLORS = ("#1f77b4", "#2ca02c", "#d62728")


def _figure(figsize):
    from matplotlib.figure import Figure
    return Figure(figsize=figsize, layout="constrained")


def _save(fig, path) -> Path:
    path = Path(path)
    if path.suffix.lower() not in (".png", ".pdf", ".svg"):
        raise ValueError(f"path must end in .png (or .pdf/.svg); got {path}")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def _arr(x, what, last=None):
    try:
        import jax
        if isinstance(x, jax.core.Tracer):
            raise TypeError(f"{what} is a traced JAX value; plot outside jax.jit")
    except ImportError:  # pragma: no cover
        pass
    a = np.asarray(x, np.float64)
    if last is not None and (a.ndim != 2 or a.shape[-1] != last):
        raise ValueError(f"{what} must have shape (T, {last}); got {a.shape}")
    return a


def _field(frames, name, width, n):
    v = getattr(frames, name, None)
    if v is None:
        return None
    a = _arr(v, f"frames.{name}", width)
    if a.shape[0] != n:
        raise ValueError(f"frames.{name} has {a.shape[0]} samples but frames.pos has {n} "
                         f"(shape {a.shape})")
    return a


def plot_trajectory(frames, path, *, reference=None, title=None, dt: float = 0.002,
                    theta=None) -> Path:
    """Six-panel PNG of a rollout; returns the path.

    frames: :class:`mjxsysid.sim.Frame` (leaves (T, ...)) or any object with ``.pos`` (T, 3) and
    optionally ``.omega`` (T, 3), ``.motor_cmd`` (T, 4), ``.rotor_speed`` (T, 4),
    ``.diverged`` (T,). Sample k is the state at t = (k + 1) dt. reference: optional positions
    (T_r, 3) (or an object with ``.pos``, e.g. a sampled RefPoint) on the same clock, drawn
    dashed. theta: optional vehicle (19,); rotor speeds are then shown as Ω / Ω_max.
    Panels: 3-D path, top-down path, position vs time, body rates, motor commands, rotor speeds.
    """
    if not hasattr(frames, "pos"):
        raise TypeError("frames must be a mjxsysid.sim.Frame or an object with .pos (T, 3); "
                        f"got {type(frames).__name__}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a finite number > 0; got {dt!r}")
    pos = _arr(frames.pos, "frames.pos", 3)
    n = pos.shape[0]
    if n < 1:
        raise ValueError("frames.pos is empty")
    omega = _field(frames, "omega", 3, n)
    cmd = _field(frames, "motor_cmd", 4, n)
    speed = _field(frames, "rotor_speed", 4, n)
    div = getattr(frames, "diverged", None)
    div = None if div is None else np.asarray(div, bool).reshape(-1)
    ref = None
    if reference is not None:
        ref = _arr(getattr(reference, "pos", reference), "reference", 3)
    omega_max = None
    if theta is not None:
        th = P.validate_theta(theta)
        if th.shape != (P.N_PARAMS,):
            raise ValueError(f"theta must have shape ({P.N_PARAMS},); got {th.shape}")
        omega_max = float(th[P.OMEGA_MAX])

    t = (np.arange(n) + 1) * dt
    t_ref = None if ref is None else (np.arange(ref.shape[0]) + 1) * dt
    t_div = float(t[np.argmax(div)]) if div is not None and div.size == n and div.any() else None

    fig = _figure((15, 8.2))
    gs = fig.add_gridspec(2, 3)
    ax3 = fig.add_subplot(gs[0, 0], projection="3d")
    ax3.plot(pos[:, 0], pos[:, 1], pos[:, 2], color="k", lw=1.5, label="flown")
    if ref is not None:
        ax3.plot(ref[:, 0], ref[:, 1], ref[:, 2], "--", color="C1", lw=1.2, label="reference")
    ax3.scatter(*pos[0], color="C2", s=25, label="start", depthshade=False)
    ax3.scatter(*pos[-1], color="C3", s=25, marker="s", label="end", depthshade=False)
    ax3.set_xlabel("x [m]")
    ax3.set_ylabel("y [m]")
    ax3.set_zlabel("z [m]")
    _equal_3d(ax3, pos if ref is None else np.concatenate([pos, ref]))
    ax3.legend(loc="upper left", fontsize=8)
    ax3.set_title("3-D path")

    ax = fig.add_subplot(gs[0, 1])
    ax.plot(pos[:, 0], pos[:, 1], color="k", lw=1.5, label="flown")
    if ref is not None:
        ax.plot(ref[:, 0], ref[:, 1], "--", color="C1", lw=1.2, label="reference")
    ax.plot(*pos[0, :2], "o", color="C2", ms=5, label="start")
    ax.plot(*pos[-1, :2], "s", color="C3", ms=5, label="end")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("top-down path")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)

    ax = fig.add_subplot(gs[0, 2])
    for k, lab in enumerate("xyz"):
        ax.plot(t, pos[:, k], color=AXIS_COLORS[k], lw=1.4, label=lab)
        if ref is not None:
            ax.plot(t_ref, ref[:, k], "--", color=AXIS_COLORS[k], lw=1.1, alpha=0.8)
    if ref is not None:
        ax.plot([], [], "--", color="gray", label="reference")
    _finish_time_axis(ax, "position [m]", "position", t_div)

    ax = fig.add_subplot(gs[1, 0])
    if omega is not None:
        for k, lab in enumerate(("p (roll)", "q (pitch)", "r (yaw)")):
            ax.plot(t, omega[:, k], color=AXIS_COLORS[k], lw=1.2, label=lab)
    else:
        _na(ax)
    _finish_time_axis(ax, "body rate [rad/s]", "body rates", t_div)

    ax = fig.add_subplot(gs[1, 1])
    if cmd is not None:
        for k in range(4):
            ax.plot(t, cmd[:, k], color=ROTOR_COLORS[k], ls=ROTOR_STYLES[k], lw=1.2,
                    label=f"rotor {k + 1}")
        ax.set_ylim(-0.03, 1.03)
    else:
        _na(ax)
    _finish_time_axis(ax, "command  Ω_cmd / Ω_max", "motor commands", t_div)

    ax = fig.add_subplot(gs[1, 2])
    if speed is not None:
        scale = 1.0 if omega_max is None else omega_max
        for k in range(4):
            ax.plot(t, speed[:, k] / scale, color=ROTOR_COLORS[k], ls=ROTOR_STYLES[k], lw=1.2,
                    label=f"rotor {k + 1}")
        if omega_max is not None:
            ax.set_ylim(-0.03, 1.03)
    else:
        _na(ax)
    _finish_time_axis(ax, "Ω / Ω_max" if omega_max is not None else "rotor speed [rad/s]",
                      "rotor speeds", t_div)

    if title:
        fig.suptitle(title)
    return _save(fig, path)


def _na(ax):
    ax.text(0.5, 0.5, "not recorded", ha="center", va="center", transform=ax.transAxes,
            color="gray")


def _finish_time_axis(ax, ylabel, title, t_div):
    if t_div is not None:
        ax.axvline(t_div, color="r", lw=1, ls=":", label="diverged")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8, loc="best")


def _equal_3d(ax, pts):
    lo, hi = pts.min(0), pts.max(0)
    mid, half = (lo + hi) / 2, max(float((hi - lo).max()) / 2, 0.05)
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)


def _log_ticks(ax, lo, hi):
    """Readable log-axis ticks: plain labels at 1-2-5 (1-2 decades) or at round linear values
    (< 1 decade) instead of crowded minor-tick labels."""
    from matplotlib import ticker
    decades = np.log10(hi / lo)
    if decades >= 2:
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        return
    if decades >= 1:
        ax.xaxis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    else:
        ax.xaxis.set_major_locator(ticker.MaxNLocator(nbins=4))
    ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.xaxis.set_minor_formatter(ticker.NullFormatter())


def plot_prior_marginals(theta_samples, path, *, mark=None, names: Sequence[str] | None = None,
                         mark_label: str = "mark", bins: int = 40, title: str | None = None) -> Path:
    """Histograms of the 19 marginals of θ samples (n, 19) in a 4 × 5 grid; returns the path.

    Entries of :data:`mjxsysid.theta.LOG_MASK` (positive scale parameters) use a log x axis
    (log-spaced bins) when all their samples are > 0. mark: optional vehicle (19,) drawn as a
    vertical line in every panel with its percentile among the samples (e.g. the paper
    vehicle). names: 19 panel titles (default :data:`mjxsysid.theta.PARAM_NAMES` with units).
    """
    th = _arr(theta_samples, "theta_samples")
    if th.ndim != 2 or th.shape[1] != P.N_PARAMS or th.shape[0] < 2:
        raise ValueError(f"theta_samples must have shape (n >= 2, {P.N_PARAMS}); got {th.shape}")
    if not np.all(np.isfinite(th)):
        raise ValueError("theta_samples contain non-finite values")
    if mark is not None:
        mark = _arr(mark, "mark")
        if mark.shape != (P.N_PARAMS,):
            raise ValueError(f"mark must have shape ({P.N_PARAMS},); got {mark.shape}")
    if names is None:
        names = [f"{nm} [{u}]" if u != "-" else nm for nm, u in zip(P.PARAM_NAMES, P.PARAM_UNITS)]
    names = list(names)
    if len(names) != P.N_PARAMS:
        raise ValueError(f"names must have {P.N_PARAMS} entries; got {len(names)}")
    if int(bins) != bins or bins < 2:
        raise ValueError(f"bins must be an integer >= 2; got {bins!r}")

    fig = _figure((17, 11))
    axes = fig.subplots(4, 5)
    for j in range(P.N_PARAMS):
        ax = axes.flat[j]
        x = th[:, j]
        log = bool(P.LOG_MASK[j]) and bool(np.all(x > 0))
        lo, hi = float(x.min()), float(x.max())
        if mark is not None and (not log or mark[j] > 0):
            lo, hi = min(lo, float(mark[j])), max(hi, float(mark[j]))
        if hi <= lo:
            hi = lo + (abs(lo) * 1e-3 or 1e-9)
        edges = np.geomspace(lo, hi, int(bins) + 1) if log else np.linspace(lo, hi, int(bins) + 1)
        ax.hist(x, bins=edges, color="#4c78a8", alpha=0.85, edgecolor="white", linewidth=0.3)
        if log:
            ax.set_xscale("log")
            _log_ticks(ax, lo, hi)
        if mark is not None:
            ax.axvline(mark[j], color="#d62728", lw=1.6)
            q = 100.0 * float(np.mean(x < mark[j]))
            ax.text(0.98, 0.95, f"percentile {q:.0f}", transform=ax.transAxes, ha="right", va="top",
                    fontsize=8, color="#d62728")
        ax.set_title(names[j], fontsize=10)
        ax.set_yticks([])
        ax.tick_params(axis="x", labelsize=8)
        if not log:
            ax.ticklabel_format(axis="x", style="sci", scilimits=(-2, 3))
    legend_ax = axes.flat[-1]
    legend_ax.axis("off")
    lines = [f"{th.shape[0]:,} samples", "log x: positive scale parameters"]
    legend_ax.text(0.05, 0.75, "\n".join(lines), transform=legend_ax.transAxes, va="top",
                   fontsize=10)
    if mark is not None:
        legend_ax.plot([0.05, 0.2], [0.35, 0.35], color="#d62728", lw=1.6,
                       transform=legend_ax.transAxes)
        legend_ax.text(0.25, 0.35, mark_label, transform=legend_ax.transAxes, va="center",
                       fontsize=10)
    if title:
        fig.suptitle(title, fontsize=13)
    return _save(fig, path)


ENSEMBLE_COLORS = {"true": "k", "decoded": "#1f77b4", "±20 %": "#ff7f0e"}


def plot_error_envelopes(times, true, ensembles: dict, path, *, rows=("lateral error (m)", "vertical error (m)"),
                         cols=None, onset=None, q=(5.0, 95.0), title=None, notes=None) -> Path:
    """Error envelopes over time, R rows × C columns of panels.

    times (T,) s; true (R, C, T) one true trace per panel (drawn on top), or (R, C, n, T) a true
    ensemble (drawn as a grey q-band with its median); ensembles {label: (R, C, S, T)} drawn as
    q[0]–q[1] % bands with their medians (colours from :data:`ENSEMBLE_COLORS`). onset: s, a
    vertical marker; notes: (R, C) strings written in the panels.
    """
    times = np.asarray(times)
    true = np.asarray(true)
    r_n, c_n = true.shape[:2]
    fig = _figure((4.6 * c_n + 0.6, 2.9 * r_n + 0.4))
    axs = fig.subplots(r_n, c_n, squeeze=False)
    for r in range(r_n):
        for c in range(c_n):
            ax = axs[r, c]
            for i, (label, ens) in enumerate(ensembles.items()):
                e = np.asarray(ens)[r, c]
                lo, med, hi = np.percentile(e, [q[0], 50, q[1]], 0)
                col = ENSEMBLE_COLORS.get(label, f"C{i + 2}")
                ax.fill_between(times, lo, hi, color=col, alpha=0.25 if i else 0.35, lw=0,
                                label=f"{label} {q[0]:g}–{q[1]:g} %")
                ax.plot(times, med, color=col, lw=1.0, ls="--", label=f"{label} median")
            tr = true[r, c]
            if tr.ndim == 1:
                ax.plot(times, tr, color="k", lw=1.6, label="true", zorder=5)
            else:
                lo, med, hi = np.percentile(tr, [q[0], 50, q[1]], 0)
                ax.fill_between(times, lo, hi, color="0.4", alpha=0.3, lw=0, zorder=4,
                                label=f"true {q[0]:g}–{q[1]:g} %")
                ax.plot(times, med, color="k", lw=1.4, zorder=5, label="true median")
            if onset is not None:
                ax.axvline(onset, color="0.5", lw=0.8, ls=":")
            if notes is not None:
                ax.text(0.02, 0.97, notes[r][c], transform=ax.transAxes, va="top", fontsize=8,
                        bbox=dict(boxstyle="round", fc="w", ec="0.8", alpha=0.85))
            if cols is not None and r == 0:
                ax.set_title(cols[c])
            if c == 0:
                ax.set_ylabel(rows[r])
            if r == r_n - 1:
                ax.set_xlabel("time (s)")
            ax.grid(alpha=0.3)
    axs[0, -1].legend(fontsize=7, loc="upper right")
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_final_histograms(finals: dict, path, *, rows=("final lateral error (m)", "final vertical error (m)"),
                          cols=None, notes=None, title=None, bins: int = 30) -> Path:
    """Histograms (densities) of final errors, R rows × C columns: finals {label: (R, C, S)}
    ('true' drawn as a black outline on top); notes (R, C) strings written in the panels."""
    labels = list(finals)
    first = np.asarray(finals[labels[0]])
    r_n, c_n = first.shape[:2]
    fig = _figure((4.2 * c_n + 0.6, 2.7 * r_n + 0.4))
    axs = fig.subplots(r_n, c_n, squeeze=False)
    for r in range(r_n):
        for c in range(c_n):
            ax = axs[r, c]
            allv = np.concatenate([np.asarray(finals[k])[r, c].ravel() for k in labels])
            hi = np.percentile(allv, 99.5)
            edges = np.linspace(0.0, hi if hi > 0 else 1e-3, bins + 1)
            for i, k in enumerate(sorted(labels, key=lambda k: k == "true")):
                v = np.clip(np.asarray(finals[k])[r, c].ravel(), 0, edges[-1])
                col = ENSEMBLE_COLORS.get(k, f"C{i + 2}")
                if k == "true":
                    ax.hist(v, edges, density=True, histtype="step", color=col, lw=1.6, label=k, zorder=5)
                else:
                    ax.hist(v, edges, density=True, color=col, alpha=0.4, label=k)
            if notes is not None:
                ax.text(0.98, 0.97, notes[r][c], transform=ax.transAxes, va="top", ha="right", fontsize=8,
                        bbox=dict(boxstyle="round", fc="w", ec="0.8", alpha=0.85))
            if cols is not None and r == 0:
                ax.set_title(cols[c])
            ax.set_xlabel(rows[r])
            if c == 0:
                ax.set_ylabel("density")
            ax.grid(alpha=0.3)
    axs[0, 0].legend(fontsize=7, loc="center right")
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_noise_sensitivity(labels: Sequence[str], coverage: dict, widths: dict, path, *,
                           names: Sequence[str], target: float = 0.9, band: float = 0.05,
                           title: str | None = None) -> Path:
    """Decoder calibration against IMU noise: one row per decoder (the keys of ``coverage``), the
    90 % coverage (left) and the mean 90 % width (right) of each quantity in ``names`` per noise
    level. labels (L,) the levels; coverage[decoder] and widths[decoder] (L, len(names)). The
    target band target ± band is shaded."""
    kinds = list(coverage)
    if not kinds or set(kinds) != set(widths):
        raise ValueError("coverage and widths must name the same decoders, at least one")
    n_lv = len(labels)
    fig = _figure((11, 3.2 * len(kinds)))
    axes = fig.subplots(len(kinds), 2, squeeze=False)
    x = np.arange(n_lv)
    for r, kind in enumerate(kinds):
        cov = _arr(coverage[kind], f"coverage[{kind!r}]")
        wid = _arr(widths[kind], f"widths[{kind!r}]")
        if cov.shape != (n_lv, len(names)) or wid.shape != cov.shape:
            raise ValueError(f"coverage and widths of {kind!r} must be ({n_lv}, {len(names)}); got {cov.shape}, {wid.shape}")
        a, b = axes[r]
        a.axhspan(target - band, target + band, color="0.9")
        a.axhline(target, color="0.5", lw=0.8)
        for j, nm in enumerate(names):
            a.plot(x, cov[:, j], "o-", label=nm)
            b.plot(x, wid[:, j], "o-", label=nm)
        a.set_ylabel(f"{kind}\n90 % coverage")
        a.set_ylim(min(0.0, float(np.nanmin(cov)) - 0.05), 1.0)
        b.set_ylabel("mean 90 % width (log units)")
        for ax in (a, b):
            ax.set_xticks(x, labels, rotation=25, ha="right", fontsize=8)
            ax.grid(alpha=0.3)
    axes[0, 1].legend(fontsize=7)
    if title:
        fig.suptitle(title)
    return _save(fig, path)
