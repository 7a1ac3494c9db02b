"""The map from motor commands to measured rotor speeds, fitted from a log that carries them
(``rotor_speed`` (T, 4) rad/s: a Crazyflie RPM deck, Indiflight's eRPM): for each τ of
:data:`SPEED_TAU_GRID`, the commands through a first-order lag, Ω_i ≈ a_i · lag_τ(u_i)(t − D) + c_i (per
rotor, or one map for the four), a, c and a transport delay D of :data:`SPEED_DELAYS` profiled. What
``check-log`` reports and what the log-grounded likelihood reads (:mod:`mjxsysid.identify.speeds`).

The fit starts at :func:`first_row` (:data:`SKIP_S`): a log whose rotors start at another speed than
its first command (a take-off, a simulator's hover start) is wrong there for about 5 τ_m.
"""
from __future__ import annotations

import numpy as np

from mjxsysid.logs.checks.signals import DT, lagged

SKIP_S = (0.2, 1.0)
"""s: the start of the log not used — a tenth of it, within these bounds. The rotor speeds are
reconstructed from the commands starting at the first command; a log that starts with rotors at
another speed (a take-off, a simulator's hover start) is wrong there for about 5 τ_m, and those
windows would dominate the residuals (a 10 s MJX flight's rate residuals are 10× larger with
0.2 s skipped than with 1 s)."""
SPEED_TAU_GRID = np.exp(np.linspace(np.log(0.0015), np.log(0.35), 8 * 63 + 1))
"""s: the time constants the speed term is computed at: :data:`~.logdata.TAU_GRID`'s range and nodes,
8× finer (1.1 % apart). The term is sharp (thousands of samples), and it is interpolated linearly in
log τ: on the rate features' grid (9 % apart) its maximum would sit on a node."""
SPEED_DELAYS = np.arange(0, 21)
"""Speed samples (0–40 ms at 500 Hz): the transport delays between command and measured speed the fit profiles out
(the speed at t follows the commands up to t − delay through the lag; measured on the Indiflight log's
filtered ``omega`` field: 16–20 ms, docs/logs.md)."""
MAX_SPEED_S = 30.0
"""s: the stretch of speeds the fit reads at most, from the first row it reads (as the innovations' 30 s): the
fit costs 505 lags of the rows it reads (1.4 s for 24 s of Indiflight's log on 2 cores), and a longer log's
speeds would only narrow a band the model floor (:data:`~mjxsysid.identify.speeds.SPEED_MODEL_SD`) already sets."""
MIN_SPEED_SAMPLES = 500
"""Speed samples per rotor the fit needs (1 s at 500 Hz)."""
MIN_SPEED_R2 = 0.5
"""The command→speed fit's R² below which the speeds are not used (another motor model, or not speeds)."""
SPEED_RESOLUTION = 1.0
"""rad/s: a logged speed's resolution (Indiflight logs whole rad/s; an RPM deck 1 rpm): its rounding
variance (q² / 12 per sample) floors the sum of squares, so an exact simulated speed is not infinitely sharp."""


def lag_steps(u, tau: float):
    """Commands u (T, 4) held over each 2 ms step through the lag of time constant ``tau``, s_0 = u_0 ->
    (s at each step's start (T, 4), s at its end (T, 4), the exact mean of s over each step (T, 4), the
    exact mean of s² (T, 4)): s_{k+1} = a s_k + (1 − a) u_k, a = exp(−dt/τ)."""
    a = np.exp(-DT / tau)
    s_end = lagged(u, tau)
    s0 = np.concatenate([u[:1], s_end[:-1]], 0)
    d = s0 - u                                                   # start of each step − command
    r1, r2 = tau / DT * (1 - a), tau / (2 * DT) * (1 - a * a)
    return s0, s_end, u + d * r1, u * u + 2 * u * d * r1 + d * d * r2


def row_speed(u, tau: float):
    """Commands u (T, 4) held over each 2 ms step through the lag of time constant ``tau``, starting at
    u[0] -> the speed at each row's time (T, 4): row k sees the commands of rows < k."""
    return np.concatenate([u[:1], lagged(u, tau)[:-1]], 0)


def _samples(rec: dict, start: int, end: int):
    """The speed samples the fit reads: (their times (N,) s, speeds (N, 4) rad/s, rows' times (end,), what
    they are). The native samples where the log says the speeds were resampled, else the rows; from
    row ``start`` to row ``end``."""
    T = len(rec["motor"])
    t = (np.asarray(rec["t"], np.float64) if "t" in rec else DT * np.arange(T))[:end]
    nat = (rec.get("native") or {}).get("rotor_speed")
    if nat is not None and len(nat[0]) > 2:
        tn, wn = np.asarray(nat[0], np.float64), np.asarray(nat[1], np.float64)
        keep = (tn >= t[start]) & (tn <= t[-1])
        rate = 1.0 / max(float(np.median(np.diff(tn))), 1e-9)
        return tn[keep], wn[keep], t, f"native samples ({rate:.0f} Hz)"
    return t[start:], np.asarray(rec["rotor_speed"], np.float64)[start:end], t, "the log's 2 ms rows"


def _not_used(why: str, **kw) -> dict:
    return {"used": False, "why": why, **kw}


def _sums(x, y, dm: int, N: int):
    """Per delay of :data:`SPEED_DELAYS` and rotor, the sums least squares of y (N − dm, 4) on the lag at
    the samples x (N, 4) read d samples earlier needs -> (Σx, Σx², Σxy) (D, 4) each, Σy (4,), Σy² (4,)."""
    c1 = np.concatenate([np.zeros((1, 4)), np.cumsum(x, 0)])
    c2 = np.concatenate([np.zeros((1, 4)), np.cumsum(x * x, 0)])
    a0, a1 = dm - SPEED_DELAYS, N - SPEED_DELAYS                # a delay of d samples: x[k − d] against y[k]
    sxy = np.stack([np.einsum("ij,ij->j", x[b0:b1], y) for b0, b1 in zip(a0, a1)])
    return c1[a1] - c1[a0], c2[a1] - c2[a0], sxy, y.sum(0), (y * y).sum(0)


def _least_squares(sx, sxx, sxy, sy, syy, m):
    """y ≈ a x + c from the sums of m pairs (any shape, broadcast) -> (SSE, a, c); a 0 where x does not vary."""
    sxx_c, sxy_c = sxx - sx * sx / m, sxy - sx * sy / m
    a = np.where(sxx_c > 0, sxy_c / np.where(sxx_c > 0, sxx_c, 1.0), 0.0)
    return np.stack([syy - sy * sy / m - a * sxy_c, a, (sy - a * sx) / m])


_LAST: list = []
"""The last :func:`speed_fit`: (rotor_speed, motor, start, per_rotor, result), reused for the same arrays."""


def speed_fit(rec: dict, start: int = 0, per_rotor: bool = True) -> dict:
    """:func:`_speed_fit`, the last fit reused for the same ``rotor_speed`` and ``motor`` arrays (by identity),
    ``start`` and ``per_rotor``: a log's checks and its posterior read one fit (a copy of the dict)."""
    rs, mo = rec.get("rotor_speed"), rec.get("motor")
    for c in _LAST:
        if c[0] is rs and c[1] is mo and c[2] == start and c[3] == per_rotor:
            return dict(c[4])
    out = _speed_fit(rec, start, per_rotor)
    if rs is not None:
        _LAST[:] = [(rs, mo, start, per_rotor, out)]
    return dict(out)


def _speed_fit(rec: dict, start: int = 0, per_rotor: bool = True) -> dict:
    """A log's rotor speeds (``rotor_speed`` (T, 4) rad/s on the rows, ``native``'s where resampled) against
    its commands ``motor`` (T, 4), from row ``start`` for at most :data:`MAX_SPEED_S`; a map per rotor (``per_rotor``) or one map for the
    four -> {used, why, and where fitted: per_rotor (the map used: per rotor
    unless a rotor's map is ill-posed), tau_m_s (the best τ), delay_s (the best delay), tau_m_s_no_delay and
    r2_no_delay (the fit without a delay), omega_ref_rad_s (the mean over rotors of a_i + c_i), idle_rad_s
    (the mean c_i), gain_rad_s and offset_rad_s (a_i, c_i: 4 each), r2, r2_shared and r2_per_rotor (one
    map, per-rotor maps), r2_no_lag (τ at the grid's smallest), n (samples × rotors), phi (lag-1
    autocorrelation of the residuals), n_eff, samples (what was read), and, used or not, the arrays
    ``log_sse`` (Gs,) log SSE(τ) on :data:`SPEED_TAU_GRID` and ``model`` (Gs, 9) each τ's
    [a_i (4) rad/s, c_i (4) rad/s, delay D s] (D profiled, a_i and c_i least squares)}."""
    if rec.get("rotor_speed") is None:
        return _not_used("the log carries no rotor speeds")
    w_rows = np.asarray(rec["rotor_speed"], np.float64)
    T = len(rec["motor"])
    if w_rows.shape != (T, 4):
        return _not_used(f"rotor_speed has shape {w_rows.shape}, not ({T}, 4)")
    end = min(T, start + int(round(MAX_SPEED_S / DT)))
    if not np.all(np.isfinite(w_rows[start:end])):
        bad = int((~np.all(np.isfinite(w_rows[start:end]), 1)).sum())
        return _not_used(f"{bad} of the {end - start} rows read have a rotor speed that is not finite")
    u = np.clip(np.asarray(rec["motor"], np.float64)[:end], 0.0, 1.0)
    ts, w, t, what = _samples(rec, start, end)
    ok = np.all(np.isfinite(w), 1)
    ts, w = ts[ok], w[ok]
    if len(ts) < MIN_SPEED_SAMPLES + SPEED_DELAYS[-1]:
        return _not_used(f"{len(ts)} speed samples per rotor; the fit needs {MIN_SPEED_SAMPLES + SPEED_DELAYS[-1]}")
    dm = int(SPEED_DELAYS[-1])
    y = w[dm:]                                      # (N − dm, 4): the samples every delay reads
    n = y.size
    syy_c = float(((y - y.mean()) ** 2).sum())
    if not syy_c > 0:
        return _not_used("the rotor speeds do not vary (all equal: zeros, or a held value)")
    floor = n * SPEED_RESOLUTION ** 2 / 12.0
    idx, wt = _interpolator(t, ts)
    N = len(ts)
    Gs, D = len(SPEED_TAU_GRID), len(SPEED_DELAYS)
    per, shared = np.empty((Gs, 3, D, 4)), np.empty((Gs, 3, D))
    for i, tau in enumerate(SPEED_TAU_GRID):
        s_rows = row_speed(u, tau)
        x = (1 - wt) * s_rows[idx] + wt * s_rows[idx + 1]            # (N, 4) the lag at the samples' times
        sx, sxx, sxy, sy, syy = _sums(x, y, dm, N)
        per[i] = _least_squares(sx, sxx, sxy, sy, syy, len(y))                       # a map per rotor
        shared[i] = _least_squares(sx.sum(-1), sxx.sum(-1), sxy.sum(-1), sy.sum(), syy.sum(), y.size)   # one map
    sse_p = np.maximum(per[:, 0].sum(-1), 0.0) + floor              # (Gs, D)
    sse_s = np.maximum(shared[:, 0], 0.0) + floor
    r2_p, r2_s = 1 - (sse_p.min() - floor) / syy_c, 1 - (sse_s.min() - floor) / syy_c
    gp, dp = np.unravel_index(int(np.argmin(sse_p)), sse_p.shape)
    ap, cp = per[gp, 1, dp], per[gp, 2, dp]
    posed = bool(np.all(ap > 0) and np.all(ap + cp > 0))
    use_p = per_rotor and posed
    if use_p:
        sse, coef = sse_p, per[:, 1:]                                   # (Gs, D), (Gs, 2, D, 4)
    else:
        sse, coef = sse_s, np.repeat(shared[:, 1:, :, None], 4, -1)
    g, dj = np.unravel_index(int(np.argmin(sse)), sse.shape)
    dbest = np.argmin(sse, 1)                      # (Gs,) each τ's delay
    ab = coef[np.arange(Gs), :, dbest]             # (Gs, 2, 4)
    dt_s = float(np.median(np.diff(ts)))
    model = np.concatenate([ab[:, 0], ab[:, 1], dbest[:, None] * dt_s], 1)
    sse_d0, sse = sse[:, 0], sse.min(1)            # the delay profiled out
    tau = float(SPEED_TAU_GRID[g])
    a, c = ab[g]
    s_rows = row_speed(u, tau)
    x = ((1 - wt) * s_rows[idx] + wt * s_rows[idx + 1])[dm - int(SPEED_DELAYS[dj]):N - int(SPEED_DELAYS[dj])]
    r = y - (a * x + c)
    r = r - r.mean(0)
    den = float((r * r).sum())
    phi = float((r[1:] * r[:-1]).sum()) / den if den > 0 else 0.0
    n_eff = n * ((1 - phi) / (1 + phi) if phi > 0 else 1.0)
    g0 = int(np.argmin(sse_d0))
    w_ref = float(np.mean(a + c))
    out = {"per_rotor": use_p, "tau_m_s": tau, "delay_s": float(SPEED_DELAYS[dj] * dt_s), "omega_ref_rad_s": w_ref,
           "idle_rad_s": float(np.mean(c)), "gain_rad_s": [float(v) for v in a], "offset_rad_s": [float(v) for v in c],
           "r2": float(1 - (sse[g] - floor) / syy_c), "r2_shared": float(r2_s), "r2_per_rotor": float(r2_p),
           "r2_no_lag": float(1 - (sse[0] - floor) / syy_c),
           "tau_m_s_no_delay": float(SPEED_TAU_GRID[g0]), "r2_no_delay": float(1 - (sse_d0[g0] - floor) / syy_c), "n": int(n),
           "phi": phi, "n_eff": float(n_eff), "samples": what, "log_sse": np.log(sse), "model": model}
    if not np.all(a > 0) or not w_ref > 0:
        return _not_used(f"the rotor speeds do not rise with the command (Ω ≈ {np.mean(a):.3g} · lag(u) "
                         f"{np.mean(c):+.3g})", **out)
    if out["r2"] < MIN_SPEED_R2:
        return _not_used(f"the rotor speeds do not follow the commands through a first-order lag (R² {out['r2']:.2f} "
                         f"< {MIN_SPEED_R2}: another motor model, or not speeds)", **out)
    maps = "per-rotor maps" if use_p else ("one map" + ("" if not per_rotor else " (a rotor's own map is ill-posed)"))
    return {"used": True, "why": f"τ_m from command to speed ({maps}, R² {out['r2']:.3f}, {what}); the thrust and "
                                 f"torque terms read the fitted speeds over Ω_ref {w_ref:.0f} rad/s", **out}


def _interpolator(t, ts):
    """Linear interpolation from the rows' times t (T,) to the times ts (N,) (clamped to the rows):
    (index (N,), weight (N,)), a value at ts = (1 − weight) · row[index] + weight · row[index + 1]."""
    x = np.clip(ts, t[0], t[-1])
    i = np.clip(np.searchsorted(t, x, side="right") - 1, 0, len(t) - 2)
    w = np.clip((x - t[i]) / np.maximum(t[i + 1] - t[i], 1e-12), 0.0, 1.0)
    return i, w[:, None]


def first_row(T: int) -> int:
    """The first row of a log of T rows that the fits read (:data:`SKIP_S`)."""
    return int(round(float(np.clip(0.1 * T * DT, *SKIP_S)) / DT))


def check_fit(rec: dict) -> dict | None:
    """The :func:`speed_fit` the checks and ``check-log``'s report read (from :func:`first_row`, a map per
    rotor); None for a log without rotor speeds."""
    return None if rec.get("rotor_speed") is None else speed_fit(rec, first_row(len(rec["motor"])))
