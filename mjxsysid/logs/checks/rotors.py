"""What the motor columns drive: the rotor order (Euler's equation, every one of the 24 orders
fitted, each under its own lag, the autopilots' orders named), the thrust model (rotor-speed commands or throttles) and the lag of thrust behind them."""
from __future__ import annotations

import itertools

import numpy as np

from mjxsysid.logs.checks.findings import Finding
from mjxsysid.logs.checks.noise import estimate_imu_noise
from mjxsysid.logs.checks.rates import MIN_ORDER_RATE_HZ, column_rates, reaches
from mjxsysid.logs.checks.signals import (DT, KNOWN_ORDERS, LAGS, SMOOTH_STEPS, fit_line, fit_rows, lagged,
                                          order_name, smooth, torque_basis)

EXCITED_ALPHA = 1.0
"""rad/s²: the spread of the (smoothed) angular acceleration below which a flight is too still
to tell the rotor order (a hover in still air)."""


KNOWN_MARGIN = 0.02
"""Mean R² by which an order of :data:`KNOWN_ORDERS` may trail the best of the 24 and still be
named as the fit (an autopilot's order before an arbitrary permutation)."""


def _order_scores(uf, alpha, basis):
    """Every rotor order's fit of the angular acceleration ``alpha`` (N, 3) on the torque of the
    lagged commands ``uf`` (N, 4) (squared, smoothed) -> {order: (score, gains (3,), R² (3,))}; score
    the mean R² over roll, pitch, yaw with an axis of negative gain counted −1. From the
    cross-moments: 24 orders cost one pass over the rows."""
    uc, ac = uf - uf.mean(0), alpha - alpha.mean(0)
    C, D, syy = uc.T @ uc, uc.T @ ac, (ac * ac).sum(0)
    out = {}
    for order in itertools.permutations(range(4)):
        b = basis[:, list(order)]                               # column j is rotor order[j]
        sxx = np.einsum("ki,ij,kj->k", b, C, b)
        sxy = np.einsum("ki,ik->k", b, D)
        ok = (sxx > 0) & (syy > 0)
        k = np.where(ok, sxy / np.where(ok, sxx, 1.0), 0.0)
        r2 = np.where(ok, sxy * sxy / np.where(ok, sxx * syy, 1.0), 0.0)
        out[order] = (float(np.mean(np.where(k > 0, r2, -1.0))), k, r2)
    return out


def rotor_order_fit(rec: dict) -> dict:
    """Fit the angular acceleration (gyro, differentiated and smoothed) to the torque the motor
    commands imply for each of the 24 rotor orders, each under its own best lag of :data:`LAGS`
    (the rotor time constant: a lag fitted under a wrong order would spoil the right one's fit).
    -> dict: ``scores`` {order: mean R² over roll, pitch, yaw (an axis with a negative gain counts
    −1)}, ``gains`` {order: (3,)}, ``taus`` {order: lag s}, ``best`` order (an autopilot's order of
    :data:`KNOWN_ORDERS` where it fits within :data:`KNOWN_MARGIN` of the best), ``given`` score of
    the log's own order (0, 1, 2, 3), ``tau`` its lag and ``given_r2`` its mean R², ``excited``
    whether the flight moved the vehicle enough to tell (rate changes above noise). A long log
    is fitted on :func:`fit_rows` of it."""
    rec = fit_rows(rec)
    u2 = np.asarray(rec["motor"], np.float64) ** 2
    gyro = np.asarray(rec["imu"], np.float64)[:, :3]
    alpha = smooth(np.diff(gyro, axis=0) / DT)                           # (T−n, 3)
    basis = torque_basis()
    scores, gains, taus, r2s = {}, {}, {}, {}
    for tau in LAGS:
        uf = smooth(lagged(u2, tau)[:-1])  # row t: the rotors over step t, which alpha[t] spans
        for order, (s, k, r2) in _order_scores(uf, alpha, basis).items():
            if order not in scores or s > scores[order]:
                scores[order], gains[order], taus[order], r2s[order] = s, k, tau, float(np.mean(r2))
    best = max(scores, key=scores.get)
    known = max(KNOWN_ORDERS.values(), key=lambda o: scores[o])
    if scores[known] >= scores[best] - KNOWN_MARGIN:
        best = known
    # Excited: the angular acceleration varies well above what the gyro's noise makes of it
    # (a moving average of n differences of white noise σ has std σ √2 / (n dt)).
    sigma = estimate_imu_noise({"imu": np.asarray(rec["imu"])})["gyro_noise"]
    floor = sigma * np.sqrt(2.0) / (SMOOTH_STEPS * DT)
    excited = bool(np.std(alpha) > max(3.0 * floor, EXCITED_ALPHA))
    given = (0, 1, 2, 3)
    return {"scores": scores, "gains": gains, "taus": taus, "best": best, "given": scores[given],
            "tau": taus[given], "excited": excited, "given_r2": r2s[given]}


THRUST_MODEL_RATIO = 0.3
"""The hover-balance ratio (:func:`thrust_model_fit`) below which the motor columns are taken as
throttles: thrust ∝ Ω² gives 1 without drag and about 0.5 with the vertical drag of the prior's
vehicles (the paper vehicle 0.54); columns that are throttles (thrust ∝ the column, read as Ω)
give half of that (0.12–0.14 on the same flights)."""


def thrust_model_fit(rec, tau: float = 0.02) -> dict:
    """The thrust model against the hover balance: acc_z ≈ k Σ ū² fitted on the changes along the
    flight (ū the motor columns lagged by ``tau``) and the balance of the means,
    mean acc_z / mean Σ ū². For columns Ω_cmd/Ω_max (thrust ∝ ū²) the two agree (``ratio``
    k / balance about 1, less with vertical drag); for throttles (thrust ∝ ū: the columns' square is
    the thrust's) the changes are twice as steep in Σ ū² as the balance: the ratio halves.
    -> ``ratio``, ``r2`` of the fit."""
    rec = fit_rows(rec)
    x = smooth((lagged(np.asarray(rec["motor"], np.float64), tau) ** 2).sum(1))
    y = smooth(np.asarray(rec["imu"], np.float64)[:, 5])
    k, r2 = fit_line(x, y)
    return {"ratio": float(k * x.mean() / max(float(y.mean()), 1e-12)), "r2": float(r2)}


def check_thrust_model(rec) -> list[Finding]:
    fit = thrust_model_fit(rec)
    if fit["r2"] > 0.5 and fit["ratio"] < THRUST_MODEL_RATIO:
        return [Finding("warning", "motor_1, motor_2, motor_3, motor_4",
                        f"the specific force changes along the flight with Σ motor² at {fit['ratio']:.2f} of the "
                        f"gain the hover balance gives (mean acc_z / mean Σ motor²; R² {fit['r2']:.2f}); rotor-speed "
                        f"commands give 0.5–1, throttles half that: the motor columns look like throttles (thrust linear in the column), "
                        f"not rotor-speed commands. Thrust ∝ Ω²: for an ESC whose thrust is linear in throttle, "
                        f"Ω_cmd/Ω_max = √throttle (PX4: √((1 − f) u + f u²) with THR_MDL_FAC f; docs/px4.md)")]
    return []


def estimate_thrust_lag(rec) -> dict:
    """The motor time constant from the specific force: the lag (of :data:`LAGS`) with which
    Σ ū² (the commands lagged, squared) best fits acc_z -> ``tau`` (s) and ``r2``."""
    rec = fit_rows(rec)
    u = np.asarray(rec["motor"], np.float64)
    y = smooth(np.asarray(rec["imu"], np.float64)[:, 5])
    best = (LAGS[0], -np.inf)
    for tau in LAGS:
        r2 = fit_line(smooth((lagged(u, tau) ** 2).sum(1)), y)[1]
        if r2 > best[1]:
            best = (tau, r2)
    return {"tau": float(best[0]), "r2": float(best[1])}


def check_motors(rec) -> list[Finding]:
    cols = "motor_1, motor_2, motor_3, motor_4"
    rate = column_rates(rec)["motor"][0]
    if not reaches(rate, MIN_ORDER_RATE_HZ):
        return [Finding("warning", cols, f"cannot tell the rotor order at this motor rate ({rate:.3g} Hz): the rotors "
                        f"follow their commands within a few tens of ms, commands {1e3 / rate:.3g} ms apart do not "
                        f"show which rotor turned the vehicle; the order is taken as given (for a ULog: from its "
                        f"parameters). Log the motor commands at ≥ {MIN_ORDER_RATE_HZ:g} Hz to have it checked "
                        f"(PX4: docs/px4.md, 'Logging rates')")]
    fit = rotor_order_fit(rec)
    if not fit["excited"]:
        return []
    given, best, sbest = fit["given"], fit["best"], fit["scores"][fit["best"]]
    gains = fit["gains"][(0, 1, 2, 3)]
    if best != (0, 1, 2, 3) and sbest > 0.5 and sbest - given > 0.25:
        wrong_sign = [a for a, k in zip(("roll", "pitch", "yaw"), gains) if k <= 0]
        lvl = "error" if any(a in ("roll", "pitch") for a in wrong_sign) else "warning"
        what = (f"in this order the motors' torque turns the vehicle against its measured "
                f"{'/'.join(wrong_sign)} acceleration" if wrong_sign else "")
        reorder = ", ".join(f"motor_{j + 1} = column {best.index(j) + 1}" for j in range(4))
        return [Finding(lvl, cols, f"the angular acceleration fits the torque of another rotor order clearly better "
                        f"(mean R² {sbest:.2f} vs {given:.2f} for mjxsysid's order{'; ' + what if what else ''}): "
                        f"the columns look like {order_name(best)}; mjxsysid's order is front-right, front-left, "
                        f"back-left, back-right: reorder ({reorder})")]
    if sbest < 0.2:
        return [Finding("warning", cols, f"the motor commands do not explain the angular acceleration under any rotor "
                        f"order (best mean R² {sbest:.2f}): are motor_1..4 normalised rotor-speed commands Ω_cmd/Ω_max "
                        f"(not body rates, torques or PWM)? See docs/decoding.md, 'Converting autopilot outputs'")]
    return []


def check_rotor_speed(rec, fit: dict | None = None) -> list[Finding]:
    """A warning where a log carries rotor speeds that the log-grounded likelihood will not use
    (:func:`~mjxsysid.logs.speedmap.speed_fit`: not finite, too few, not rising with the command, or not
    following it through a first-order lag, R² < 0.5: another motor model, or not speeds); where used, the
    fit is reported by ``check-log`` and ``decode`` (``_log_grounded.rotor_speed``). ``fit``: the log's
    :func:`~mjxsysid.logs.speedmap.check_fit` where the caller has it (then not fitted again)."""
    from mjxsysid.logs.speedmap import check_fit
    if rec.get("rotor_speed") is None:
        return []
    fit = check_fit(rec) if fit is None else fit
    if fit["used"]:
        return []
    msg = f"measured rotor speeds not used by the likelihood: {fit['why']}"
    if "tau_m_s" in fit:
        msg += (f" (best fit: τ_m {1e3 * fit['tau_m_s']:.1f} ms, R² {fit['r2']:.2f}, {fit['r2_no_lag']:.2f} without a "
                f"lag, Ω ≈ {fit['omega_ref_rad_s']:.0f} rad/s at full command, {fit['idle_rad_s']:.0f} rad/s offset)")
    return [Finding("warning", "rotor_speed", msg)]
