"""The signal tools every log check shares: the 2 ms step, smoothing, the rotors' first-order
lag, a line fit, the rotor layout's torque basis and known rotor orders, and the rows a fit reads."""
from __future__ import annotations

import numpy as np

from mjxsysid import theta as P

DT = 0.002
"""s: one control step (500 Hz)."""

SMOOTH_STEPS = 10
"""Moving-average length (20 ms) applied alike to both sides of the torque and rate fits: it
removes sensor noise above 25 Hz while keeping the rotor dynamics (τ_m ≥ a few ms)."""

LAGS = (0.003, 0.005, 0.0075, 0.01, 0.0125, 0.015, 0.02, 0.03, 0.04, 0.06, 0.08, 0.1, 0.13)
"""s: the rotor time constants tried when fitting the commands to what the IMU shows."""

KNOWN_ORDERS = {
    "mjxsysid (front-right, front-left, back-left, back-right)": (0, 1, 2, 3),
    "Crazyflie (M1 front-right, M2 back-right, M3 back-left, M4 front-left)": (0, 3, 2, 1),
    "Betaflight quad-X (M1 back-right, M2 front-right, M3 back-left, M4 front-left)": (3, 0, 2, 1),
    "PX4/ArduPilot quad-X (M1 front-right, M2 back-left, M3 front-left, M4 back-right)": (0, 2, 1, 3),
    "RotorPy (front-left, front-right, back-right, back-left)": (1, 0, 3, 2),
}
"""Rotor orders of the autopilots and tools logs come from: the mjxsysid rotor (0 front-right,
1 front-left, 2 back-left, 3 back-right) in each of the log's columns motor_1..motor_4."""


def smooth(x, n: int = SMOOTH_STEPS):
    """Moving average over ``n`` rows along axis 0 (valid part only)."""
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), x], 0), 0)
    return (c[n:] - c[:-n]) / n


def lagged(x, tau: float):
    """First-order lag with time constant ``tau`` (s) at 500 Hz along axis 0, starting at x[0]
    (the rotor speed following its command, exactly discretised)."""
    from scipy.signal import lfilter
    a = np.exp(-DT / tau)
    zi = (a * x[0])[None] if x.ndim > 1 else np.array([a * x[0]])
    return lfilter([1 - a], [1, -a], x, axis=0, zi=zi)[0]


def fit_line(x, y):
    """Least squares y ≈ k x + b -> (k, R²)."""
    xc, yc = x - x.mean(0), y - y.mean(0)
    sxx, syy = float((xc * xc).sum()), float((yc * yc).sum())
    if sxx <= 0 or syy <= 0:
        return 0.0, 0.0
    k = float((xc * yc).sum()) / sxx
    return k, 1.0 - float(((yc - k * xc) ** 2).sum()) / syy


def torque_basis():
    """(3, 4): roll, pitch and yaw torque per unit thrust-like Ω² of each mjxsysid rotor
    (positions ±1/√2, reaction yaw signs), without the vehicle's scale."""
    d = P.ROTOR_DIRECTIONS
    return np.stack([d[:, 1], -d[:, 0], P.YAW_SIGNS]).astype(np.float64)


def order_name(order) -> str:
    order = tuple(int(i) for i in order)
    for name, o in KNOWN_ORDERS.items():
        if o == order:
            return name
    return "columns motor_1..4 = " + ", ".join(P.ROTOR_NAMES[i] for i in order)


FIT_ROWS = 30_000
"""Rows (60 s) the dynamics fits use at most: a longer log contributes evenly spaced contiguous
pieces of that many rows in all (physics does not change along a flight; the cost stays bounded)."""


def fit_rows(rec: dict, max_rows: int = FIT_ROWS) -> dict:
    """``rec`` itself, or for a log longer than ``max_rows`` six evenly spaced contiguous pieces of
    it, ``max_rows`` rows in all, joined (imu and motor only: what the fits read)."""
    t = len(rec["imu"])
    if t <= max_rows:
        return rec
    k, n = 6, max_rows // 6
    idx = np.concatenate([np.arange(s, s + n) for s in np.linspace(0, t - n, k).astype(int)])
    out = {k: np.asarray(rec[k])[idx] for k in ("imu", "motor") if k in rec}
    for key in ("native", "resampled"):    # what the checks know of the columns' own rates
        if key in rec:
            out[key] = rec[key]
    return out
