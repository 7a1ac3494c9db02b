"""Measured rotor speeds in the log-grounded likelihood (:mod:`.likelihood`).

A log that carries the rotor speeds (``rotor_speed`` (T, 4) rad/s: a Crazyflie RPM deck, Indiflight's
eRPM) gives two things the motor commands alone do not:

- the thrust and torque terms read the fitted motor model's speeds, ŝ_i,τ = max(0, a_i,τ · lag_τ(u_i)(t − D_τ)
  + c_i,τ) / Ω_ref, at every τ of the features' grid (:func:`model_features`): each motor's real map (idle
  offset, gain) and the shared delay, without the sensor's noise in the regressors (measured speeds as
  regressors are errors in variables: their noise attenuates the fitted authorities);
- τ_m comes from command to speed directly: for each τ of :data:`SPEED_TAU_GRID`, the commands
  through the first-order lag, Ω_i ≈ a_i · lag_τ(u_i)(t − D) + c_i, a_i and c_i per rotor and a transport
  delay D of :data:`SPEED_DELAYS` profiled (τ and D shared: one motor type); the concentrated Gaussian
  log-likelihood −(n_eff / 2) log SSE(τ), with n_eff the samples discounted
  for the residuals' lag-1 autocorrelation φ by (1 − φ) / (1 + φ): a motor model that does not fit
  leaves correlated residuals and a broad band. n_eff is capped where the term alone would pin log τ
  tighter than :data:`SPEED_MODEL_SD` (the map's form, not only its noise, sets how well τ_m is known).

**Per-rotor maps, one Ω_ref.** The four motors differ (a Crazyflie's RPM deck: idle offsets −221 to −633
rad/s; one map for the four fits it at R² 0.856, a map each at 0.976), so each rotor has its own gain and
offset. They are normalised by one Ω_ref, the mean over rotors of a_i + c_i (each speed at full command) at
the best τ, the same at every τ: a rotor's faster or slower speed stays in its ŝ_i, so ρ_i (thrust per Ω²
relative to the others) keeps its meaning, and the authorities and thrust-to-weight keep theirs (per
Ω_ref² of thrust). One map for the four replaces them where a rotor's own map is ill-posed (its gain not
positive, or its speed at full command not), or with ``per_rotor=False``; both fits' R² are reported.

The speeds are used where they are finite from the first row the likelihood reads on, there are at
least :data:`MIN_SPEED_SAMPLES` of them, the speed rises with the command and the fit's R² is at
least :data:`MIN_SPEED_R2`; otherwise the report says why not and the log is read as one without speeds.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

DT = 0.002
"""s: the log's row spacing (500 Hz)."""
SPEED_TAU_GRID = np.exp(np.linspace(np.log(0.0015), np.log(0.35), 8 * 63 + 1))
"""s: the time constants the speed term is computed at: :data:`~.logdata.TAU_GRID`'s range and nodes,
8× finer (1.1 % apart). The term is sharp (thousands of samples), and it is interpolated linearly in
log τ: on the rate features' grid (9 % apart) its maximum would sit on a node."""
SPEED_DELAYS = np.arange(0, 21)
"""Speed samples (0–40 ms at 500 Hz): the transport delays between command and measured speed the fit profiles out
(the speed at t follows the commands up to t − delay through the lag; measured on the Indiflight log's
filtered ``omega`` field: 16–20 ms, docs/logs.md)."""
MIN_SPEED_SAMPLES = 500
"""Speed samples per rotor the fit needs (1 s at 500 Hz)."""
MIN_SPEED_R2 = 0.5
"""The command→speed fit's R² below which the speeds are not used (another motor model, or not speeds)."""
SPEED_MODEL_SD = 0.03
"""The least standard deviation of log τ_m the speed term gives alone (90 % half-width 5 %): the fit's linear
map from lag to speed is one model of several. A √ term in the map (Ω = a √x + b x + c) moved Indiflight's
τ_m by about 1 ms of 21 (5 %); a band narrower than that would hold the linear map's τ_m only."""
SPEED_RESOLUTION = 1.0
"""rad/s: a logged speed's resolution (Indiflight logs whole rad/s; an RPM deck 1 rpm): its rounding
variance (q² / 12 per sample) floors the sum of squares, so an exact simulated speed is not infinitely sharp."""


def row_speed(u, tau: float):
    """Commands u (T, 4) held over each 2 ms step through the lag of time constant ``tau``, starting at
    u[0] -> the speed at each row's time (T, 4): row k sees the commands of rows < k."""
    a = np.exp(-DT / tau)
    s_end = lfilter([1 - a], [1, -a], u, axis=0, zi=(a * u[0])[None])[0]
    return np.concatenate([u[:1], s_end[:-1]], 0)


def _samples(rec: dict, start: int):
    """The speed samples the fit reads: (their times (N,) s, speeds (N, 4) rad/s, rows' times (T,), what
    they are). The native samples where the log says the speeds were resampled, else the rows; from
    row ``start`` on."""
    T = len(rec["motor"])
    t = np.asarray(rec["t"], np.float64) if "t" in rec else DT * np.arange(T)
    nat = (rec.get("native") or {}).get("rotor_speed")
    if nat is not None and len(nat[0]) > 2:
        tn, wn = np.asarray(nat[0], np.float64), np.asarray(nat[1], np.float64)
        keep = (tn >= t[start]) & (tn <= t[-1])
        rate = 1.0 / max(float(np.median(np.diff(tn))), 1e-9)
        return tn[keep], wn[keep], t, f"native samples ({rate:.0f} Hz)"
    return t[start:], np.asarray(rec["rotor_speed"], np.float64)[start:], t, "the log's 2 ms rows"


def _not_used(why: str, **kw) -> dict:
    return {"used": False, "why": why, **kw}


def _regress(x, y, dm: int, N: int):
    """Per delay of :data:`SPEED_DELAYS` and rotor, least squares of y (N − dm, 4) on the lag at the samples
    x (N, 4) read d samples earlier -> (SSE (D, 4), gain a (D, 4), offset c (D, 4)); a 0 where a rotor's
    lag does not vary."""
    m = len(y)
    sy, syy = y.sum(0), (y * y).sum(0)
    c1 = np.concatenate([np.zeros((1, 4)), np.cumsum(x, 0)])
    c2 = np.concatenate([np.zeros((1, 4)), np.cumsum(x * x, 0)])
    out = np.empty((3, len(SPEED_DELAYS), 4))
    for j, d in enumerate(SPEED_DELAYS):           # a delay of d samples: x[k − d] against y[k]
        a0, a1 = dm - d, N - d
        sx, sxx = c1[a1] - c1[a0], c2[a1] - c2[a0]
        sxy = np.einsum("ij,ij->j", x[a0:a1], y)
        sxx_c, sxy_c = sxx - sx * sx / m, sxy - sx * sy / m
        a = np.where(sxx_c > 0, sxy_c / np.where(sxx_c > 0, sxx_c, 1.0), 0.0)
        out[:, j] = syy - sy * sy / m - a * sxy_c, a, (sy - a * sx) / m
    return out


def _pooled(x, y, dm: int, N: int):
    """:func:`_regress` with one a and c for the four rotors -> (SSE (D,), a (D,), c (D,))."""
    m = y.size
    sy, syy = float(y.sum()), float((y * y).sum())
    c1 = np.concatenate([[0.0], np.cumsum(x.sum(1))])
    c2 = np.concatenate([[0.0], np.cumsum((x * x).sum(1))])
    out = np.empty((3, len(SPEED_DELAYS)))
    for j, d in enumerate(SPEED_DELAYS):
        a0, a1 = dm - d, N - d
        sx, sxx = c1[a1] - c1[a0], c2[a1] - c2[a0]
        sxy = float(np.einsum("ij,ij->", x[a0:a1], y))
        sxx_c, sxy_c = sxx - sx * sx / m, sxy - sx * sy / m
        a = sxy_c / sxx_c if sxx_c > 0 else 0.0
        out[:, j] = syy - sy * sy / m - a * sxy_c, a, (sy - a * sx) / m
    return out


def speed_fit(rec: dict, start: int = 0, per_rotor: bool = True) -> dict:
    """A log's rotor speeds (``rotor_speed`` (T, 4) rad/s on the rows, ``native``'s where resampled) against
    its commands ``motor`` (T, 4), from row ``start``; a map per rotor (``per_rotor``) or one map for the
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
    if not np.all(np.isfinite(w_rows[start:])):
        bad = int((~np.all(np.isfinite(w_rows[start:]), 1)).sum())
        return _not_used(f"{bad} of the {T - start} rows read have a rotor speed that is not finite")
    u = np.clip(np.asarray(rec["motor"], np.float64), 0.0, 1.0)
    ts, w, t, what = _samples(rec, start)
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
        per[i], shared[i] = _regress(x, y, dm, N), _pooled(x, y, dm, N)
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


def _moments(ll):
    """The mean and standard deviation of log τ under a term ll (Gs,) on :data:`SPEED_TAU_GRID` alone."""
    lt = np.log(SPEED_TAU_GRID)
    p = np.exp(ll - ll.max())
    p /= p.sum()
    mu = float(p @ lt)
    return mu, max(float(np.sqrt(p @ (lt - mu) ** 2)), float(np.diff(lt).min()) / np.sqrt(12.0))


def speed_term(fit: dict) -> tuple[np.ndarray, np.ndarray]:
    """What :class:`~.logdata.LogData` carries of a :func:`speed_fit`: the term's log-likelihood (Gs,) on
    :data:`SPEED_TAU_GRID`, −(n / 2) (log SSE(τ) − its minimum), and (3,) [n, the mean and the standard
    deviation of log τ under the term alone] (a Gaussian summary for the mode's least squares); zeros,
    and [0, 0, 1], where the speeds are not used. n is n_eff, capped where the term alone would put
    log τ's standard deviation below :data:`SPEED_MODEL_SD` (n then the one that puts it there, by bisection).
    The term is log SSE: far from its minimum it is flatter than a parabola, so n is not scaled by (sd / floor)²."""
    G = len(SPEED_TAU_GRID)
    if not fit.get("used"):
        return np.zeros(G), np.array([0.0, 0.0, 1.0])
    dl = fit["log_sse"] - fit["log_sse"].min()
    n = fit["n_eff"]
    if _moments(-0.5 * n * dl)[1] < SPEED_MODEL_SD:      # bisect log n: sd falls as n grows
        lo, hi = np.log(n) - 14.0, np.log(n)
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if _moments(-0.5 * np.exp(mid) * dl)[1] > SPEED_MODEL_SD else (lo, mid)
        n = float(np.exp(lo))
    ll = -0.5 * n * dl
    return ll, np.array([n, *_moments(ll)])


def _model_at(fit: dict, tau: float):
    """The fitted map at the node of :data:`SPEED_TAU_GRID` nearest ``tau``: (a_i / Ω_ref (4,), c_i / Ω_ref (4,),
    the delay in whole rows)."""
    i = int(np.argmin(np.abs(np.log(SPEED_TAU_GRID) - np.log(tau))))
    m, w = fit["model"][i], fit["omega_ref_rad_s"]
    return m[:4] / w, m[4:8] / w, int(round(m[8] / DT))


def _delayed(rows, d: int):
    """``rows`` (T, 4) d rows late: row k holds rows[k − d] (rows[0] before)."""
    return rows if d <= 0 else np.concatenate([np.repeat(rows[:1], d, 0), rows[:len(rows) - d]], 0)


def model_steps(u, fit: dict, tau: float):
    """Commands u (T, 4) through the fitted map at τ (:func:`speed_fit`'s ``model``), ŝ_i = max(0, a_i · lag_τ(u_i)(t − D)
    + c_i) / Ω_ref, the lag starting at u[0] -> (each step's mean ŝ² (T, 4), ŝ at each step's end (T, 4)).
    The mean is exact where ŝ stays positive over the step (ŝ is affine in the lag), else the mean of
    its two ends' squares."""
    al, be, d = _model_at(fit, tau)
    a = np.exp(-DT / tau)
    s_end = lfilter([1 - a], [1, -a], u, axis=0, zi=(a * u[0])[None])[0]
    s0 = np.concatenate([u[:1], s_end[:-1]], 0)
    dd = s0 - u
    r1, r2 = tau / DT * (1 - a), tau / (2 * DT) * (1 - a * a)
    m1 = _delayed(u + dd * r1, d)
    m2 = _delayed(u * u + 2 * u * dd * r1 + dd * dd * r2, d)
    e0, e1 = al * _delayed(s0, d) + be, al * _delayed(s_end, d) + be
    q = al * al * m2 + 2 * al * be * m1 + be * be
    neg = np.minimum(e0, e1) < 0
    e0, e1 = np.maximum(e0, 0.0), np.maximum(e1, 0.0)
    return np.where(neg, 0.5 * (e0 * e0 + e1 * e1), q), e1


def model_features(u, fit: dict, taus, steps, tri, bsteps) -> tuple[np.ndarray, np.ndarray]:
    """The fitted speeds (:func:`model_steps`) of commands u (T, 4) at every τ of ``taus`` (G,) -> what the
    likelihood's lag features hold (:func:`~.logdata._lag_features`): the windows' triangle-weighted sums
    of each step's mean ŝ² × dt (G, n, 4) (``steps`` (n, S), weights ``tri`` (S,)) and the blocks' mean ŝ²
    at the steps' ends (G, nb, 4) (``bsteps`` (nb, B))."""
    fg, fa = [], []
    for tau in taus:
        q, e1 = model_steps(u, fit, float(tau))
        fg.append(np.einsum("nsr,s->nr", q[steps], tri) * DT)
        fa.append((e1[bsteps] ** 2).mean(1))
    return np.stack(fg), np.stack(fa)


def model_step_integrals(u, fit: dict, tau: float, start: int, n: int) -> np.ndarray:
    """Each step's ∫ ŝ_i² dt (n, 4) of the rows ``start`` … ``start + n`` under the fitted map at τ: what the
    innovations read in place of :func:`~.logdata.step_lag`."""
    return model_steps(u, fit, tau)[0][start:start + n] * DT


def speed_features(s, steps, tri, bsteps) -> tuple[np.ndarray, np.ndarray]:
    """Measured s = Ω / Ω_ref at the rows (T, 4) (``prepare(..., speeds="raw")``, a diagnostic: their noise
    biases the authorities low) -> what the likelihood's lag features hold
    (:func:`~.logdata._lag_features` at one τ): the windows' triangle-weighted sums of each step's mean
    s² (the mean of its two ends' squares) × dt (n, 4) (``steps`` (n, S), weights ``tri`` (S,)), and
    the blocks' mean s² at the rows the accelerometer reads, one after each step (nb, 4) (``bsteps`` (nb, B))."""
    s2 = np.asarray(s, np.float64) ** 2
    ms = 0.5 * (s2[steps] + s2[steps + 1])
    return np.einsum("nsr,s->nr", ms, tri) * DT, s2[bsteps + 1].mean(1)


def speed_step_integrals(s, start: int, n: int, tau=None) -> np.ndarray:
    """Each step's ∫ s_i² dt (n, 4) of the rows ``start`` … ``start + n`` from measured s (T, 4) (the mean of
    its two ends' squares), the same at every ``tau``: what the innovations read in place of
    :func:`~.logdata.step_lag` with ``speeds="raw"``."""
    s2 = np.asarray(s, np.float64)[start:start + n + 1] ** 2
    return 0.5 * (s2[:-1] + s2[1:]) * DT


def report(fit: dict) -> dict:
    """A :func:`speed_fit` without its arrays: what ``decode``'s ``_log_grounded.rotor_speed`` and
    ``check-log`` say (``rotor_speed_used`` and why, the fit's τ_m, Ω_ref, idle offset, R², n_eff)."""
    out = {"rotor_speed_used": bool(fit.get("used")), **{k: v for k, v in fit.items() if k not in ("used", "log_sse", "model")}}
    return out
