"""Measured rotor speeds in the log-grounded likelihood (:mod:`.likelihood`), from the command→speed
map fitted by :mod:`mjxsysid.logs.speedmap`.

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

from mjxsysid.logs.checks.signals import DT
from mjxsysid.logs.speedmap import SPEED_TAU_GRID, lag_steps

SPEED_MODEL_SD = 0.03
"""The least standard deviation of log τ_m the speed term gives alone (90 % half-width 5 %): the fit's linear
map from lag to speed is one model of several. A √ term in the map (Ω = a √x + b x + c) moved Indiflight's
τ_m by about 1 ms of 21 (5 %); a band narrower than that would hold the linear map's τ_m only."""
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
    s0, s_end, m1, m2 = (_delayed(x, d) for x in lag_steps(u, tau))
    e0, e1 = al * s0 + be, al * s_end + be
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
