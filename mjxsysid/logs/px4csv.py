"""PX4 flights as CSV tables of data-driven-dynamics (ethz-asl/data-driven-dynamics' ``resources/*.csv``: a
ULog's topics resampled onto one clock) -> the log contract of :mod:`mjxsysid.logs.formats`.

The table's columns, one row per sample (100 Hz in the sample of Gazebo-classic's Iris):

- ``timestamp`` µs; ``u0..u3`` the motor outputs of ``actuator_outputs``, PWM µs, PX4's quad-X order
  (front-right, back-left, front-left, back-right);
- ``ang_vel_x/y/z`` the gyro, rad/s, and ``acc_b_x/y/z`` the specific force, m/s², both body FRD;
  ``ang_acc_b_x/y/z`` their angular acceleration, derived (not read: the likelihood differentiates the gyro
  itself);
- optional: ``vx, vy, vz`` the local velocity, NED m/s, with ``q0..q3`` the attitude (w, x, y, z, body FRD to
  NED), read as the body velocity; ``landed`` (1 on the ground), which bounds the segment.

PWM is read as PX4's: throttle u = (pwm − 1000) / (2000 − 1000) (PWM_MAIN_MIN/MAX's defaults; the table
carries no parameters) and PX4's thrust model with THR_MDL_FAC 0, thrust ∝ u, so Ω_cmd/Ω_max = √u, as
:mod:`~mjxsysid.logs.ulog` reads a ULog without THR_MDL_FAC. A simulator or an ESC whose rotor speed is linear in
PWM instead (Gazebo-classic's motor plugin: Ω = 100 + 1000 u rad/s) gives another command→speed map, which
the posterior's motor-map check tests (:mod:`mjxsysid.identify.idlecheck`). The table carries no setpoints:
``omega_cmd`` and ``a_cmd`` are filled from the IMU and said missing.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mjxsysid.logs.grid import world_to_body
from mjxsysid.logs.record import HELD, LINEAR, assemble, native_rates, pick_segment, sorted_unique
from mjxsysid.logs.ulog import PX4_QUADX_ORDER, pwm_limits, throttle_to_rotor_speed

FORMAT = "PX4 CSV (data-driven-dynamics)"
REQUIRED = ("timestamp", "u0", "u1", "u2", "u3", "ang_vel_x", "ang_vel_y", "ang_vel_z", "acc_b_x", "acc_b_y",
            "acc_b_z")
"""The columns a table must have."""
VELOCITY = ("vx", "vy", "vz", "q0", "q1", "q2", "q3")
"""The columns that give the body velocity, all or none."""
FLU_FROM_FRD = np.array([1.0, -1.0, -1.0])


def _header(head: bytes) -> list[str]:
    line = head.split(b"\n", 1)[0].decode("utf-8", "replace").lstrip("\ufeff").strip()
    return [c.strip() for c in line.split(",")]


def sniff(head: bytes) -> bool:
    """Is ``head`` (a file's first bytes) a data-driven-dynamics table: a CSV header naming :data:`REQUIRED`?"""
    return set(REQUIRED) <= set(_header(head))


def _longest(mask) -> tuple[int, int] | None:
    """The longest run of True in ``mask`` (N,) -> (first, last) index, or None."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    edges = np.flatnonzero(np.diff(m.astype(np.int8)))
    if not len(edges):
        return None
    runs = edges.reshape(-1, 2)
    k = int(np.argmax(runs[:, 1] - runs[:, 0]))
    return int(runs[k, 0]), int(runs[k, 1]) - 1


def read(path, segment=None) -> dict:
    """Read a data-driven-dynamics table -> the log contract (:mod:`mjxsysid.logs.formats`) over the airborne
    part of its longest stretch off the ground (or ``segment`` 't0:t1', seconds of its clock). ValueError naming
    the file: a required column missing, a value that is not a number, too short."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    with open(path, "rb") as f:
        cols = _header(f.read(4096))
    missing = [c for c in REQUIRED if c not in cols]
    if missing:
        raise ValueError(f"{path}: not a data-driven-dynamics table: no column(s) {missing} in its header")
    try:
        data = np.genfromtxt(path, delimiter=",", skip_header=1, dtype=np.float64, ndmin=2, invalid_raise=True)
    except ValueError as e:
        raise ValueError(f"{path}: a row of the table does not read as numbers ({e})") from None
    if data.shape[1] != len(cols):
        raise ValueError(f"{path}: {data.shape[1]} values a row against {len(cols)} columns in the header")
    col = {c: data[:, i] for i, c in enumerate(cols)}
    for c in REQUIRED:
        bad = np.flatnonzero(~np.isfinite(col[c]))
        if len(bad):
            raise ValueError(f"{path}: column {c} is empty or not a number on {len(bad)} rows (the first: data row "
                             f"{bad[0] + 1})")
    t = col["timestamp"] * 1e-6
    conv = ["time: the timestamp column, µs to s",
            "body frame: PX4's FRD (x forward, y right, z down) to FLU (x forward, y left, z up): gyro "
            "(ang_vel_x/y/z) and accelerometer (acc_b_x/y/z) y and z negated"]
    imu = np.concatenate([np.stack([col[f"ang_vel_{a}"] for a in "xyz"], -1) * FLU_FROM_FRD,
                          np.stack([col[f"acc_b_{a}"] for a in "xyz"], -1) * FLU_FROM_FRD], 1)
    t_imu, imu = sorted_unique(t, imu)

    pwm = np.stack([col[f"u{i}"] for i in range(4)], -1)
    try:
        lo, hi, said_pwm = pwm_limits({}, pwm)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    u = np.clip((pwm - lo) / (hi - lo), 0.0, 1.0)
    rotor = throttle_to_rotor_speed(u, 0.0)[:, [list(PX4_QUADX_ORDER).index(j) for j in range(4)]]
    t_m, rotor = sorted_unique(t, rotor)
    conv += [said_pwm.replace("(PWM_MAIN_MIN absent, default, PWM_MAIN_MAX absent, default)",
                              "(PX4's defaults of PWM_MAIN_MIN/MAX: the table carries no parameters)"),
             f"motor commands: throttle u = (pwm − {lo:g}) / ({hi:g} − {lo:g}); PX4's thrust model with THR_MDL_FAC 0 "
             "(the table carries no parameters), thrust ∝ u and thrust ∝ Ω²: Ω_cmd/Ω_max = √u",
             "rotor order: PX4's quad-X outputs u0..u3 are front-right, back-left, front-left, back-right; "
             "reordered to mjxsysid's"]

    within, within_why = None, ""
    if "landed" in col and np.all(np.isfinite(col["landed"])):
        run = _longest(col["landed"] < 0.5)
        if run is None:
            raise ValueError(f"{path}: the landed column is 1 on every row: no flight to identify")
        within = (float(t[run[0]]), float(t[run[1]]))
        within_why = f"off the ground {within[0]:.2f}–{within[1]:.2f} s (the landed column)"
    t0, t1, why = pick_segment(path, segment, t_m, rotor, (float(t_imu[0]), float(t_imu[-1])), within, within_why)

    channels = {"imu": (t_imu, imu, LINEAR), "motor": (t_m, rotor, HELD),
                "omega_cmd": (t_imu, imu[:, :3], LINEAR), "a_cmd": (t_imu, imu[:, 5], LINEAR)}
    absent = ["a_cmd", "omega_cmd"]
    conv += ["omega_cmd: the table has no rate setpoint: filled with the measured gyro (not a setpoint)",
             "a_cmd: the table has no thrust setpoint: filled with the measured specific force along body z "
             "(not a setpoint)"]
    if all(c in col for c in VELOCITY):
        q = np.stack([col[f"q{i}"] for i in range(4)], -1)
        v = np.stack([col[c] for c in ("vx", "vy", "vz")], -1)
        ok = np.all(np.isfinite(q), 1) & np.all(np.isfinite(v), 1) & (np.linalg.norm(q, axis=1) > 0.5)
        if ok.sum() > 1:
            t_v, v_body = sorted_unique(t[ok], world_to_body(q[ok], v[ok]) * FLU_FROM_FRD)
            channels["velocity_body"] = (t_v, v_body, LINEAR)
            conv.append("velocity: vx, vy, vz (NED) rotated into the body by q0..q3 (FRD to NED), then FLU")
        else:
            absent.append("velocity_body")
    else:
        absent.append("velocity_body")
    rates, gaps = native_rates(channels)
    rec = assemble(channels, t0, t1)
    rec["source"] = {"format": FORMAT, "path": str(path), "columns": cols, "rates_hz": rates, "max_gap_s": gaps,
                     "segment": {"t0": float(t0), "t1": float(t1), "why": why,
                                 "clock": "seconds of the table's timestamp column"},
                     "conversions": conv, "missing": absent}
    return rec
