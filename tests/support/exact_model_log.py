"""A flight log made in numpy by the log-grounded likelihood's own equations (the rotor lag's exact
mean square speed, Euler's equation, the specific force), step by step: a log on which that model is
exact. Open loop around hover, a rate damper and a chirp-like excitation; the same forward model as
tests/identify/test_identify.py's ``synthetic_log``."""
import numpy as np

from mjxsysid import theta as P

DT = 0.002


def exact_model_log(theta, seconds: float = 4.0, gyro_noise: float = 0.0, acc_noise: float = 0.0,
                    seed: int = 0) -> dict:
    """Fly θ (19,) for ``seconds`` -> {'imu' (T, 6) gyro rad/s and specific force m/s², 'motor' (T, 4)
    commands Ω_cmd / Ω_max}, white noise of the given stds added to the gyro and accelerometer."""
    rng = np.random.default_rng(seed)
    t = np.asarray(theta, np.float64)
    eta, tau, wmax = t[P.ETA], t[P.TAU_M], t[P.OMEGA_MAX]
    kt, m, arm, inertia = t[P.KT], t[P.MASS], t[P.ARM], t[P.INERTIA]
    kappa = t[P.KTAU] / kt
    d = P.ROTOR_DIRECTIONS.astype(np.float64)
    n = int(seconds / DT)
    hover = np.sqrt(m * P.GRAVITY / (4 * kt * eta)) / wmax
    w = np.zeros(3)
    s = hover.copy()
    imu, mot = np.zeros((n, 6)), np.zeros((n, 4))
    imu[0, 5] = P.GRAVITY
    a = np.exp(-DT / tau)
    for k in range(n):
        tt = k * DT
        exc = 0.08 * np.array([np.sin(7 * tt), np.sin(5 * tt + 1), np.sin(3 * tt + 2)]) + 0.03 * rng.standard_normal(3)
        cmd = -0.02 * w + exc                                   # roll, pitch, yaw effort
        u = np.clip(hover * (1 + 0.05 * np.sin(2 * tt) + d[:, 1] * cmd[0] - d[:, 0] * cmd[1]
                             + P.YAW_SIGNS * cmd[2]), 0, 1)
        mot[k] = u
        d0 = s - u
        ms = u * u + 2 * u * d0 * tau / DT * (1 - a) + d0 * d0 * tau / (2 * DT) * (1 - a * a)   # exact mean of s²
        s = u + d0 * a
        thrust = eta * kt * wmax ** 2 * ms
        torque = np.array([arm * d[:, 1] @ thrust, -arm * d[:, 0] @ thrust, kappa * P.YAW_SIGNS @ thrust]) + t[P.TAU_EXT]
        w = w + DT * (torque - np.cross(w, inertia * w)) / inertia
        if k + 1 < n:
            sf = (eta * kt * wmax ** 2 * s * s).sum() / m
            imu[k + 1] = np.concatenate([w + gyro_noise * rng.standard_normal(3),
                                         acc_noise * rng.standard_normal(2), [sf + acc_noise * rng.standard_normal()]])
    return {"imu": imu, "motor": mot}
