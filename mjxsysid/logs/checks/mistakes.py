"""Common mistakes made on purpose to a correct log: what the checks must catch (the log-checks
experiment, tests/logs/test_logcheck.py)."""
from __future__ import annotations

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.checks.signals import KNOWN_ORDERS

MISTAKES = ("acc_in_g", "gyro_in_deg_s", "time_in_ms", "motor_pwm", "rotorpy_order", "px4_order",
            "omega_cmd_other", "frd_frame", "imu_after_step")

"""The mistakes :func:`make_mistake` makes to a correct log (what the checks must catch)."""


def make_mistake(rec: dict, kind: str, *, imu_after=None) -> dict:
    """A correct log ``rec`` (the arrays of ``read_log``) with one common mistake made -> a new
    dict: ``acc_in_g`` (accelerometer in g), ``gyro_in_deg_s``, ``time_in_ms``, ``motor_pwm``
    (1000–2000 µs pulses), ``rotorpy_order`` / ``px4_order`` (motor columns in that tool's rotor
    order), ``omega_cmd_other`` (the rate command of another controller than the policy's: here
    the measured body rates), ``frd_frame`` (body frame FRD: y right, z down), ``imu_after_step`` (each row's IMU read
    after the step: ``imu_after`` (T, 6), the reading after each step, else the next row's)."""
    r = {k: np.array(v, copy=True) for k, v in rec.items()}
    if kind == "acc_in_g":
        r["imu"][:, 3:6] /= P.GRAVITY
    elif kind == "gyro_in_deg_s":
        r["imu"][:, :3] = np.rad2deg(r["imu"][:, :3])
    elif kind == "time_in_ms":
        r["t"] = r["t"] * 1000.0
    elif kind == "motor_pwm":
        r["motor"] = 1000.0 + 1000.0 * r["motor"]
    elif kind in ("rotorpy_order", "px4_order"):
        order = KNOWN_ORDERS[next(n for n in KNOWN_ORDERS if n.lower().startswith(kind.split("_")[0]))]
        r["motor"] = r["motor"][:, list(order)]
    elif kind == "omega_cmd_other":
        r["omega_cmd"] = r["imu"][:, :3].copy()
    elif kind == "frd_frame":
        r["imu"][:, [1, 2, 4, 5]] *= -1
        r["omega_cmd"][:, [1, 2]] *= -1
    elif kind == "imu_after_step":
        r["imu"] = (np.concatenate([r["imu"][1:], r["imu"][-1:]]) if imu_after is None
                    else np.array(imu_after, copy=True))
    else:
        raise ValueError(f"unknown mistake {kind!r}; choose from {MISTAKES}")
    return r
