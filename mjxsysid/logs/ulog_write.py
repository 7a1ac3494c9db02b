"""A flight written as a PX4 ULog, the topics :func:`~mjxsysid.logs.ulog.read_ulog` reads: the
project's own flights open in PX4 Flight Review and PlotJuggler, and the tests read logs the
project writes itself.

The ULog format (PX4's docs, "ULog File Format"): a 16-byte header (magic ``ULog\\x01\\x12\\x35``,
version 1, start time µs), then the definitions (a flag-bits message ``B``, formats ``F`` "topic:
type field;…", info ``I``, initial parameters ``P``) and the data (a subscription ``A`` per topic,
then data messages ``D``, packed little-endian, in time order). Every message is a uint16 size, a
uint8 type and its body.

Written, in PX4's frame and units (FRD body frame, normalised commands): ``sensor_combined``
(gyro rad/s, accelerometer m/s²), ``actuator_motors`` (each rotor's normalised thrust Ω² in PX4's
quad-X order, with the CA_ROTORi geometry as parameters), ``vehicle_rates_setpoint`` (rad/s),
``vehicle_thrust_setpoint`` (−a_cmd · hover / g on z), ``hover_thrust_estimate``,
``actuator_armed`` and ``vehicle_land_detected``; given the flight's attitude and velocity,
``vehicle_attitude`` (q, FRD body to NED) and ``vehicle_local_position`` (vx, vy, vz NED, both valid
flags set), the simulator's world (x, y, z up) taken as north, west, up: NED = (x, −y, −z).
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.record import interleave
from mjxsysid.logs.ulog import PX4_QUADX_ORDER, ULOG_MAGIC

START_US = 1_000_000
"""µs: the log's start time in its header (the samples' timestamps count from it)."""

TOPICS = {
    # topic: ((ULog type, field, count), ...) after ``uint64_t timestamp``
    "sensor_combined": (("float", "gyro_rad", 3), ("int32_t", "accelerometer_timestamp_relative", 1),
                        ("float", "accelerometer_m_s2", 3)),
    "actuator_motors": (("float", "control", 4),),
    "vehicle_rates_setpoint": (("float", "roll", 1), ("float", "pitch", 1), ("float", "yaw", 1),
                               ("float", "thrust_body", 3)),
    "vehicle_thrust_setpoint": (("float", "xyz", 3),),
    "hover_thrust_estimate": (("float", "hover_thrust", 1), ("bool", "valid", 1)),
    "actuator_armed": (("bool", "armed", 1),),
    "vehicle_land_detected": (("bool", "landed", 1),),
    "vehicle_attitude": (("float", "q", 4),),
    "vehicle_local_position": (("float", "vx", 1), ("float", "vy", 1), ("float", "vz", 1),
                               ("bool", "v_xy_valid", 1), ("bool", "v_z_valid", 1)),
}
_NP = {"float": "<f4", "int32_t": "<i4", "bool": "u1", "uint64_t": "<u8"}
FRD = np.array([1.0, -1.0, -1.0])
FRD_QUAT = np.array([1.0, 1.0, -1.0, -1.0])
"""A body-FLU-to-world (z up) quaternion (w x y z) times this: the body-FRD-to-NED one."""
QUADX_POSITIONS = {0: (1.0, 1.0), 1: (-1.0, -1.0), 2: (1.0, -1.0), 3: (-1.0, 1.0)}
"""PX4 motor -> (x forward, y right) signs of its rotor in PX4's default quad-X (FRD)."""


def state_estimate(quat, vel):
    """A flight's attitude (T, 4) and world velocity (T, 3), both or neither -> both as float64, or
    (None, None)."""
    if (quat is None) != (vel is None):
        raise ValueError("give both quat and vel (the attitude and the world velocity), or neither")
    if quat is None:
        return None, None
    return np.asarray(quat, np.float64), np.asarray(vel, np.float64)


def _msg(kind: bytes, body: bytes) -> bytes:
    return struct.pack("<HB", len(body), kind[0]) + body


def _param(name: str, value) -> bytes:
    key = (f"int32_t {name}" if isinstance(value, int) else f"float {name}").encode()
    val = struct.pack("<i", value) if isinstance(value, int) else struct.pack("<f", float(value))
    return _msg(b"P", bytes([len(key)]) + key + val)


def _info(name: str, text: str) -> bytes:
    v = text.encode()
    key = f"char[{len(v)}] {name}".encode()
    return _msg(b"I", bytes([len(key)]) + key + v)


def _rows(msg_id: int, topic: str, ts, columns: dict) -> np.ndarray:
    """Data messages ``D`` of ``topic`` at timestamps ``ts`` (N,) µs -> (N, size) uint8, one row each."""
    fields = [("size", "<u2"), ("type", "u1"), ("msg_id", "<u2"), ("timestamp", "<u8")]
    fields += [(name, _NP[typ], (n,)) if n > 1 else (name, _NP[typ]) for typ, name, n in TOPICS[topic]]
    dt = np.dtype(fields)          # numpy's structured dtypes are packed: ULog's layout
    a = np.zeros(len(ts), dt)
    a["size"], a["type"], a["msg_id"], a["timestamp"] = dt.itemsize - 3, ord("D"), msg_id, ts
    for k, v in columns.items():
        a[k] = v
    return a.view(np.uint8).reshape(len(ts), dt.itemsize)


def _every(t, rate_hz):
    """Indices of the rows of ``t`` (N,) s kept for a topic logged at ``rate_hz`` (None: every row)."""
    if rate_hz is None:
        return np.arange(len(t))
    step = max(int(round(1.0 / (rate_hz * float(np.median(np.diff(t)))))), 1)
    return np.arange(0, len(t), step)


def write_ulog(path, t, imu, a_cmd, omega_cmd, motor, *, rates: dict | None = None, armed=None, landed=None,
               hover_thrust: float | None = None, params: dict | None = None, quat=None, vel=None) -> Path:
    """Write a flight as a PX4 ULog: ``t`` (T,) s, ``imu`` (T, 6) gyro rad/s and specific force m/s²
    (FLU), ``a_cmd`` (T,) m/s², ``omega_cmd`` (T, 3) rad/s, ``motor`` (T, 4) Ω_cmd/Ω_max in mjxsysid's
    rotor order (the arrays of :func:`~mjxsysid.logs.csvlog.read_log`); ``quat`` (T, 4) the attitude
    (w x y z, body FLU to the world, z up) and ``vel`` (T, 3) m/s the world-frame velocity, both or
    neither: the state estimate's topics (the reader's ``velocity_body``). ``rates`` {imu, motor,
    setpoint, estimate: Hz}: log a topic group at that rate (every k-th row; default every row); ``armed``,
    ``landed`` (T,) bool (default armed and airborne throughout); ``hover_thrust`` the normalised
    collective thrust at hover (default the median mean Ω_cmd² while armed: a_cmd = g there);
    ``params`` extra parameters. -> ``path``."""
    t = np.asarray(t, np.float64)
    imu, motor = np.asarray(imu, np.float64), np.asarray(motor, np.float64)
    a_cmd, omega_cmd = np.asarray(a_cmd, np.float64), np.asarray(omega_cmd, np.float64)
    rates = rates or {}
    armed = np.ones(len(t), bool) if armed is None else np.asarray(armed, bool)
    landed = np.zeros(len(t), bool) if landed is None else np.asarray(landed, bool)
    thrust = motor ** 2                                          # actuator_motors: normalised thrust ∝ Ω²
    if hover_thrust is None:
        hover_thrust = float(np.median(thrust[armed].mean(1))) if armed.any() else 0.5
    ts = (START_US + np.round(t * 1e6)).astype(np.uint64)
    i_imu, i_m, i_sp, i_est = (_every(t, rates.get(k)) for k in ("imu", "motor", "setpoint", "estimate"))
    change = lambda x: np.concatenate([[0], np.flatnonzero(np.diff(x.astype(int))) + 1])  # noqa: E731
    i_arm, i_land = change(armed), change(landed)
    data = {
        "sensor_combined": (i_imu, {"gyro_rad": imu[i_imu, :3] * FRD, "accelerometer_m_s2": imu[i_imu, 3:] * FRD}),
        "actuator_motors": (i_m, {"control": thrust[i_m][:, list(PX4_QUADX_ORDER)]}),
        "vehicle_rates_setpoint": (i_sp, {"roll": omega_cmd[i_sp, 0], "pitch": -omega_cmd[i_sp, 1],
                                          "yaw": -omega_cmd[i_sp, 2]}),
        "vehicle_thrust_setpoint": (i_sp, {"xyz": np.stack([0 * i_sp, 0 * i_sp,
                                                            -a_cmd[i_sp] * hover_thrust / P.GRAVITY], -1)}),
        "hover_thrust_estimate": (i_sp[:1], {"hover_thrust": hover_thrust, "valid": 1}),
        "actuator_armed": (i_arm, {"armed": armed[i_arm]}),
        "vehicle_land_detected": (i_land, {"landed": landed[i_land]}),
    }
    quat, vel = state_estimate(quat, vel)
    if quat is not None:
        q, v = quat[i_est], vel[i_est]
        # NED = (x, −y, −z) of the world and FRD = (x, −y, −z) of FLU: a half turn about x on both sides
        # of the rotation, i.e. its quaternion's y and z negated
        data["vehicle_attitude"] = (i_est, {"q": q * FRD_QUAT})
        data["vehicle_local_position"] = (i_est, {"vx": v[:, 0], "vy": -v[:, 1], "vz": -v[:, 2],
                                                  "v_xy_valid": 1, "v_z_valid": 1})
    head = ULOG_MAGIC + bytes([1]) + struct.pack("<Q", START_US)
    defs = [_msg(b"B", bytes(40))]
    for topic in data:
        fields = TOPICS[topic]
        spec = "".join(f"{typ}[{n}] {name};" if n > 1 else f"{typ} {name};" for typ, name, n in fields)
        defs.append(_msg(b"F", f"{topic}:uint64_t timestamp;{spec}".encode()))
    defs += [_info("sys_name", "mjxsysid"), _info("ver_hw", "mjxsysid simulator")]
    geo = {}
    for m, (x, y) in QUADX_POSITIONS.items():     # KM > 0 turns the body about FRD z: mjxsysid's yaw sign −1
        km = -0.05 * float(P.YAW_SIGNS[PX4_QUADX_ORDER[m]])
        geo.update({f"CA_ROTOR{m}_PX": 0.15 * x, f"CA_ROTOR{m}_PY": 0.15 * y, f"CA_ROTOR{m}_KM": km})
    for k, v in {"MAV_TYPE": 2, "CA_AIRFRAME": 0, "CA_ROTOR_COUNT": 4, "THR_MDL_FAC": 0.0,
                 "MPC_THR_HOVER": hover_thrust, **geo, **(params or {})}.items():
        defs.append(_param(k, v))
    subs = [_msg(b"A", struct.pack("<BH", 0, msg_id) + topic.encode()) for msg_id, topic in enumerate(data)]
    body = interleave([(ts[idx], _rows(msg_id, topic, ts[idx], cols))
                       for msg_id, (topic, (idx, cols)) in enumerate(data.items())])
    Path(path).write_bytes(head + b"".join(defs) + b"".join(subs) + body)
    return Path(path)


def write_flight_logs(one, out) -> tuple[Path, Path]:
    """A flown flight (one vehicle's :class:`~mjxsysid.rollout.harness.Flight`, host arrays) written
    as logs: ``out/flight.ulg`` (this PX4 ULog: Flight Review and PlotJuggler open it) and
    ``out/flight.csv`` (the CSV contract), each row the IMU the controller acted on, its commands,
    motor commands and the true velocity in the body frame (:func:`~mjxsysid.rollout.flight.flight_log`;
    the ULog carries it as the attitude and NED velocity), t from 0 in 2 ms steps. -> the two paths."""
    from mjxsysid.logs.csvlog import LOG_DT, write_log
    from mjxsysid.rollout.flight import flight_log
    out = Path(out)
    t = np.asarray(one.time, np.float64) - LOG_DT
    rec = flight_log(one.frame)
    arrays = (t, np.asarray(rec["imu"]), np.asarray(one.a_cmd), np.asarray(one.omega_cmd), np.asarray(rec["motor"]))
    return (write_ulog(out / "flight.ulg", *arrays, quat=np.asarray(one.frame.quat), vel=np.asarray(one.frame.vel)),
            write_log(out / "flight.csv", *arrays, velocity_body=rec["velocity_body"]))
