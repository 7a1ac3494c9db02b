"""The checks of a log in order (:func:`check_log`): units and frame of the IMU and commands,
the rotors carrying the vehicle, then the dynamics checks of the other modules."""
from __future__ import annotations

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.checks.findings import Finding
from mjxsysid.logs.checks.noise import check_imu_noise
from mjxsysid.logs.checks.rates import check_resampled
from mjxsysid.logs.checks.policy_replay import check_replay
from mjxsysid.logs.checks.rotors import check_motors, check_rotor_speed, check_thrust_model
from mjxsysid.logs.checks.signals import DT, fit_line, smooth

GYRO_FULL_SCALE = np.deg2rad(2000.0)
"""rad/s: the largest full-scale range of common MEMS gyros (±2000 °/s). A body rate beyond it
cannot have been measured: the column is not in rad/s."""


def check_log(rec: dict, *, policy=None, zhat=None, imu_limit: dict | None = None,
              speed_fit: dict | None = None) -> list[Finding]:
    """Physical plausibility of a flight log read by
    [read_log][mjxsysid.logs.csvlog.read_log] (``rec``: t, imu (T, 6), a_cmd, omega_cmd (T, 3),
    motor (T, 4)). ``policy``: the loaded latent policy being decoded, and ``zhat`` (T, 8) its
    replay of the log (both optional): then the policy's own actions on the logged inputs are
    compared with the logged motor commands (without them there is no replay check here: the
    policy's replay is :func:`check_replay`, run by ``decode`` and ``mjxsysid.check_log``).
    ``imu_limit``: the IMU noise the decoders are calibrated under (:func:`imu_noise_limit`;
    default :data:`IMU_NOISE_LIMIT`). Columns resampled from a lower rate (declared by the reader
    in ``rec["native"]`` / ``rec["resampled"]``, or detected in a CSV) are named, and each check
    reads the native samples or says that it cannot tell at that rate. ``speed_fit``: the log's
    :func:`~mjxsysid.logs.speedmap.check_fit` where the caller has it (``check-log`` prints it): not fitted
    again. -> findings, errors first."""
    out = []
    out += check_specific_force(rec)
    out += check_gyro(rec)
    if not any(f.level == "error" for f in out):   # the thrust checks need a sane accelerometer
        out += check_thrust(rec)
    if not any(f.level == "error" for f in out):   # a_cmd against the thrust that carried the vehicle
        out += check_a_cmd(rec)
    if not any(f.level == "error" for f in out):   # the dynamics checks need sane units and thrust
        out += check_resampled(rec)
        out += check_motors(rec)
        out += check_thrust_model(rec)
        out += check_rotor_speed(rec, speed_fit)
        out += check_imu_noise(rec, imu_limit)
        if policy is not None and zhat is not None and hasattr(policy, "replay_actions"):
            out += check_replay(rec, policy, zhat)
    return sorted(out, key=lambda f: f.level != "error")


def check_specific_force(rec) -> list[Finding]:
    acc = np.asarray(rec["imu"], np.float64)[:, 3:6]
    g = P.GRAVITY
    norm = np.linalg.norm(acc, axis=1)
    med = float(np.median(norm))
    mean = np.mean(acc, 0)
    seconds = len(acc) * DT
    cols = "acc_x, acc_y, acc_z"
    if 0.5 < med < 2.0:
        return [Finding("error", cols, f"the specific force has median norm {med:.3g} in flight: looks like g, "
                        f"not m/s² (an accelerometer reads about 9.81 m/s² at hover): multiply acc_x/y/z by {g}")]
    if 0.5 * g * 1000 < med < 2.0 * g * 1000:
        return [Finding("error", cols, f"the specific force has median norm {med:.4g}: looks like milli-g "
                        f"(mg), not m/s²: multiply acc_x/y/z by {g / 1000:g}")]
    if med < 0.5 * g or med > 5 * g:
        lvl = "error" if seconds >= 1.0 else "warning"
        return [Finding(lvl, cols, f"the specific force has median norm {med:.3g} m/s²; a flying (or resting) "
                        f"vehicle's accelerometer averages about g = {g} m/s² over a flight: check the unit "
                        f"(m/s² expected) and that the columns are the accelerometer (specific force)")]
    axis = int(np.argmax(np.abs(mean)))
    if axis != 2 or mean[2] < 0:
        name = "xyz"[axis]
        sign = "+" if mean[axis] > 0 else "−"
        fix = ("the body z axis points down (FRD, as PX4 logs): convert to FLU by negating the y and z columns "
               "of gyro and acc" if axis == 2 else
               f"the thrust axis is {sign}{name}: map the columns to FLU (x forward, y left, z up, thrust on +z)")
        return [Finding("error", cols, f"the mean specific force is {mean.round(2).tolist()} m/s², largest on "
                        f"{sign}{name}; a multirotor's thrust is along +z in mjxsysid's body frame (FLU): {fix}")]
    return []


def check_gyro(rec) -> list[Finding]:
    gyro = np.asarray(rec["imu"], np.float64)[:, :3]
    w_cmd = np.asarray(rec["omega_cmd"], np.float64)
    out = []
    peak = float(np.percentile(np.abs(gyro), 99.9))
    if peak > GYRO_FULL_SCALE:
        out.append(Finding("error", "gyro_x, gyro_y, gyro_z",
                           f"body rates reach {peak:.4g} (99.9th percentile of |gyro|), beyond any gyro's full "
                           f"scale ({GYRO_FULL_SCALE:.1f} rad/s = 2000 °/s): looks like deg/s, not rad/s: "
                           f"multiply gyro_x/y/z by π/180"))
    cpeak = float(np.percentile(np.abs(w_cmd), 99.9))
    if cpeak > GYRO_FULL_SCALE:
        out.append(Finding("error", "omega_cmd_x, omega_cmd_y, omega_cmd_z",
                           f"commanded body rates reach {cpeak:.4g}, beyond what any gyro measures "
                           f"({GYRO_FULL_SCALE:.1f} rad/s): looks like deg/s: multiply omega_cmd_x/y/z by π/180"))
    if out:
        return out
    # A rate-tracking controller follows its command: the gain from omega_cmd to gyro is about 1.
    gs, ws = smooth(gyro).ravel(), smooth(w_cmd).ravel()
    if np.std(ws) > 0.05:   # rad/s of commanded rate: enough to measure a gain
        k, r2 = fit_line(ws, gs)
        ratio = 180.0 / np.pi
        if r2 > 0.3 and ratio / 3 < k < ratio * 3:
            out.append(Finding("warning", "gyro_x, gyro_y, gyro_z",
                               f"the body rates follow omega_cmd with gain {k:.3g} (R² {r2:.2f}); a rate "
                               f"controller tracks its command with gain about 1: the gyro looks like deg/s "
                               f"(multiply gyro_x/y/z by π/180)"))
        elif r2 > 0.3 and 1 / (ratio * 3) < k < 3 / ratio:
            out.append(Finding("warning", "omega_cmd_x, omega_cmd_y, omega_cmd_z",
                               f"the body rates follow omega_cmd with gain {k:.3g} (R² {r2:.2f}), not about 1: "
                               f"omega_cmd looks like deg/s (multiply omega_cmd_x/y/z by π/180)"))
    return out


IDLE_COMMAND = 0.05
"""Normalised rotor-speed command below which a rotor is taken as stopped or idling (a
multirotor hovers at 0.4–0.9; PX4's idle spin is about 0.2 of Ω_max)."""

TWR_IMPOSSIBLE = 25.0
"""Thrust-to-weight past which the motor commands cannot be what holds the vehicle up (the most
powerful racing quadrotors reach about 15): the specific force is not supported by them."""


def check_thrust(rec) -> list[Finding]:
    """An error for a log whose rotors do not carry the vehicle: motor commands at idle or zero
    on most rows (disarmed, on the ground, a bench log), or a specific force far beyond what the
    commands could produce."""
    u = np.asarray(rec["motor"], np.float64)
    acc_z = np.asarray(rec["imu"], np.float64)[:, 5]
    cols = "motor_1, motor_2, motor_3, motor_4"
    idle = float(np.mean(u.max(1) < IDLE_COMMAND))
    if idle > 0.5:
        return [Finding("error", cols, f"every motor command is below {IDLE_COMMAND:g} of full rotor speed on "
                        f"{idle:.0%} of the rows: the rotors were stopped or idling (disarmed, on the ground, a "
                        f"bench log), nothing carried the vehicle, there is no flight to decode. Cut the airborne "
                        f"part (--segment T0:T1; a ULog is cut at its armed, airborne segment)")]
    s2 = float((u ** 2).sum(1).mean())
    twr = 4.0 * float(acc_z.mean()) / (P.GRAVITY * max(s2, 1e-12))
    if acc_z.mean() > 0.5 * P.GRAVITY and twr > TWR_IMPOSSIBLE:
        return [Finding("error", cols, f"the specific force (mean {acc_z.mean():.3g} m/s² on z) is not supported by "
                        f"the motor commands (mean Σu² {s2:.3g}): it would need a thrust-to-weight of {twr:.3g}. "
                        f"The rotors did not carry the vehicle (on the ground, a bench log), or the motor columns "
                        f"are not Ω_cmd/Ω_max (throttles: Ω_cmd/Ω_max = √throttle; docs/decoding.md, 'Converting autopilot "
                        f"outputs')")]
    return []


A_CMD_RATIO = (0.67, 1.5)
"""How far the mean a_cmd may lie from the mean specific force along z (a ratio) before it is
flagged: a_cmd is the mass-normalised collective thrust the vehicle was commanded, which the
accelerometer measures along body z (drag and the rotors' lag average out over a flight)."""


def check_a_cmd(rec) -> list[Finding]:
    a = np.asarray(rec["a_cmd"], np.float64)
    acc_z = float(np.asarray(rec["imu"], np.float64)[:, 5].mean())
    if acc_z < 0.5 * P.GRAVITY:
        return []
    lo, hi = float(a.min()), float(a.max())
    fmt = (rec.get("source") or {}).get("format", "CSV")
    if fmt != "CSV":     # the reader built a_cmd: the advice is about its conversion, not the file's column
        built = next((c for c in rec["source"].get("conversions", []) if c.startswith("a_cmd")), "")
        ratio = float(a.mean()) / acc_z
        if A_CMD_RATIO[0] < ratio < A_CMD_RATIO[1]:
            return []
        return [Finding("warning", "a_cmd", f"a_cmd averages {a.mean():.3g} m/s², the specific force along z "
                        f"{acc_z:.3g} m/s² (ratio {ratio:.2g}); the {fmt} reader built a_cmd ({built or 'no setpoint'}): "
                        f"the hover thrust or setpoint it used does not match this part of the log. Check the "
                        f"segment (--segment T0:T1 on the flight) and the conversion (docs/decoding.md; a PX4 ULog: docs/px4.md)")]
    if lo >= -1e-6 and hi <= 1.0 + 1e-6:
        return [Finding("error", "a_cmd", f"a_cmd lies in [0, 1] (mean {a.mean():.3g}) while the specific force along "
                        f"z averages {acc_z:.3g} m/s²: it looks like a normalised thrust setpoint (PX4's "
                        f"vehicle_thrust_setpoint), not m/s². a_cmd is the commanded mass-normalised collective "
                        f"thrust in m/s²: multiply by g / hover thrust (PX4: hover_thrust_estimate or "
                        f"MPC_THR_HOVER; docs/px4.md)")]
    ratio = float(a.mean()) / acc_z
    if not A_CMD_RATIO[0] < ratio < A_CMD_RATIO[1]:
        return [Finding("warning", "a_cmd", f"a_cmd averages {a.mean():.3g} m/s², the specific force along z it "
                        f"commands {acc_z:.3g} m/s² (ratio {ratio:.2g}): a_cmd is the mass-normalised collective "
                        f"thrust commanded (m/s², about g at hover); check its unit and scale (docs/decoding.md)")]
    return []
