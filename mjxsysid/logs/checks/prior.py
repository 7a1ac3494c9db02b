"""What the log alone says about the vehicle (thrust-to-weight, motor time constant, the weakest
rotor) against the decoders' training prior."""
from __future__ import annotations

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.checks.findings import Finding
from mjxsysid.logs.checks.noise import estimate_imu_noise
from mjxsysid.logs.checks.rates import MIN_ORDER_RATE_HZ, column_rates, reaches
from mjxsysid.logs.checks.rotors import estimate_thrust_lag, rotor_order_fit
from mjxsysid.logs.checks.signals import DT, fit_rows, lagged


def estimate_vehicle(rec: dict, fit: dict | None = None) -> dict:
    """What the log alone says about the vehicle. From the thrust equation, specific force
    acc_z = (T/W · g / 4) Σ η_i ū_i² with ū the commands lagged by τ_m (drag along body z
    averages out over a flight), and the hover balance (each rotor of an X layout delivers the same
    thrust, so η_i ∝ 1 / mean ū_i²): ``thrust_to_weight`` = mean(acc_z) / g · mean_i(1 / mean ū_i²),
    the one thrust-to-weight of the reports, 4 η̄ k_t Ω_max² / (m g) (:func:`mjxsysid.theta.thrust_to_weight`),
    and ``min_motor_effectiveness``, the weakest rotor's η relative to the mean; from Euler's equation
    (the rotor order fit, ``fit`` of :func:`rotor_order_fit` if already computed)
    ``motor_time_constant``, the lag of the angular acceleration behind the commands, and
    ``torque_fit_r2``, how well that fit explains it; ``gyro_noise`` and ``accel_noise`` from
    :func:`estimate_imu_noise`."""
    full = rec
    motor_rate = column_rates(rec)["motor"][0]
    fit = rotor_order_fit(rec) if fit is None else fit
    rec = fit_rows(rec)
    acc_z = np.asarray(rec["imu"], np.float64)[:, 5]
    # Thrust follows the rotor speed, the command lagged by τ_m: its mean square is below the
    # command's when the commands chatter (the lag removes variance), so lag them first.
    u2 = lagged(np.asarray(rec["motor"], np.float64), fit["tau"]) ** 2
    skip = min(100, len(acc_z) // 4)   # the first 0.2 s: the log may start before take-off settles
    ms = np.maximum(u2[skip:].mean(0), 1e-12)
    twr = float(acc_z[skip:].mean()) / P.GRAVITY * float(np.mean(1.0 / ms))
    eta = (1.0 / ms) / np.mean(1.0 / ms)
    lag = estimate_thrust_lag(rec) if reaches(motor_rate, MIN_ORDER_RATE_HZ) else {"tau": float("nan"), "r2": 0.0}
    torque_r2 = fit["given_r2"] if reaches(motor_rate, MIN_ORDER_RATE_HZ) else 0.0
    return {"thrust_to_weight": twr, "motor_time_constant": float(fit["tau"]), "torque_fit_r2": torque_r2,
            "motor_time_constant_thrust": lag["tau"], "thrust_fit_r2": lag["r2"], "motor_rate_hz": float(motor_rate),
            "min_motor_effectiveness": float(eta.min()), **estimate_imu_noise(full)}


TAU_FIT_R2 = 0.5
"""R² a fit (torque or thrust) must reach for its lag to count as the motor time constant."""


def motor_time_constant(est: dict):
    """τ_m from :func:`estimate_vehicle`'s estimates: the torque fit's lag where it explains the
    angular acceleration (R² > :data:`TAU_FIT_R2`), else the thrust fit's (the lag of the specific
    force behind Σ ū²) where that explains acc_z -> (τ s, 'torque' | 'thrust'), or (None, why not)."""
    if est.get("torque_fit_r2", 0.0) > TAU_FIT_R2:
        return float(est["motor_time_constant"]), "torque"
    if est.get("thrust_fit_r2", 0.0) > TAU_FIT_R2 and np.isfinite(est.get("motor_time_constant_thrust", np.nan)):
        return float(est["motor_time_constant_thrust"]), "thrust"
    rate = est.get("motor_rate_hz", 1.0 / DT)
    if not reaches(rate, MIN_ORDER_RATE_HZ):
        return None, (f"the motor time constant is not estimable from this log: motor commands at {rate:.3g} Hz "
                      f"(≥ {MIN_ORDER_RATE_HZ:g} Hz needed)")
    return None, (f"the motor time constant is not estimable from this log: neither the angular acceleration "
                  f"(R² {est.get('torque_fit_r2', 0.0):.2f}) nor the specific force (R² "
                  f"{est.get('thrust_fit_r2', 0.0):.2f}) follows the lagged motor commands; the "
                  f"motor_time_constant estimate is not a measurement")


PRIOR_MARGIN = {"thrust_to_weight": 1.0, "motor_time_constant": 1.4, "motor_effectiveness": 1.0}
"""How far past the training prior's physical range (a factor) a log-only estimate must lie to
be flagged. Thrust-to-weight and the weakest rotor: none (the prior's extremes — every rotor's
η·T/W ≤ 8.5, one rotor at η's floor with three at its top — are already beyond what its
vehicles reach on average); τ_m: one step of the estimator's grid of lags. Their false-alarm
and hit rates are measured in docs/decoding.md, 'Out of prior'."""


def prior_bounds(prior="wide_actuators") -> dict:
    """The ranges of the decoders' training prior that :func:`prior_check` compares with: the
    largest thrust-to-weight any rotor reaches (T/W × η), τ_m and η."""
    p = P.get_prior(prior)
    lo, hi = p.eta
    return {"thrust_to_weight": (p.twr_min_eff, p.twr_max_eff), "motor_time_constant": p.motor_time_constant,
            # the weakest rotor relative to the mean of four: one at the floor, three at the top
            "motor_effectiveness": (lo / ((lo + 3 * hi) / 4), hi / ((hi + 3 * lo) / 4))}


def prior_check(rec: dict, prior="wide_actuators", est: dict | None = None) -> list[Finding]:
    """Whether the logged vehicle lies outside the decoders' training ``prior`` by the log-only
    estimates of :func:`estimate_vehicle` (each beyond the prior's range by :data:`PRIOR_MARGIN`)
    -> 'out_of_prior' findings (empty: inside)."""
    est = estimate_vehicle(rec) if est is None else est
    b = prior_bounds(prior)
    out = []
    twr = est["thrust_to_weight"]
    lo, hi = b["thrust_to_weight"]
    m = PRIOR_MARGIN
    if twr > hi * m["thrust_to_weight"] or twr < lo / m["thrust_to_weight"]:
        out.append(Finding("out_of_prior", "acc_z, motor_1..4",
                           f"thrust-to-weight about {twr:.3g} from the log (specific force per Σ motor²), outside "
                           f"the decoders' training prior ({lo:g}–{hi:g}): the decoded bands are not calibrated here"))
    tau, src = motor_time_constant(est)
    tlo, thi = b["motor_time_constant"]
    if tau is not None and (tau < tlo / m["motor_time_constant"] or tau > thi * m["motor_time_constant"]):
        what = ("lag of the angular acceleration behind the commands" if src == "torque"
                else "lag of the specific force behind the commands")
        out.append(Finding("out_of_prior", "acc_z, motor_1..4",
                           f"motor time constant about {tau * 1e3:.3g} ms from the log ({what}), outside the decoders' training prior ({tlo * 1e3:g}–{thi * 1e3:g} "
                           f"ms): the decoded bands are not calibrated here"))
    eta = est["min_motor_effectiveness"]
    if eta < b["motor_effectiveness"][0] / m["motor_effectiveness"]:
        out.append(Finding("out_of_prior", "motor_1..4",
                           f"one motor needs {1 / eta:.2g}× the mean squared command to hold its share (effectiveness "
                           f"about {eta:.2g} of the others'), beyond the decoders' training prior (at least "
                           f"{b['motor_effectiveness'][0]:.2g}): the decoded bands are not calibrated here"))
    return out
