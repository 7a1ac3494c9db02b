"""A flight written in every format the readers read: Crazyflie uSD, Betaflight (Indiflight) blackbox,
ArduPilot DataFlash and ROS 1 / 2 bags (the PX4 ULog and the CSV have :mod:`~mjxsysid.logs.ulog_write`
and :func:`~mjxsysid.logs.csvlog.write_log`). The tests read logs the project writes itself; the
benchmarks time every reader on the same flight (``benchmarks/long_logs.py``).

Every writer takes the flight of :func:`~mjxsysid.logs.csvlog.read_log`: ``t`` (T,) s, ``imu`` (T, 6)
gyro rad/s and specific force m/s² (FLU), ``a_cmd`` (T,) m/s², ``omega_cmd`` (T, 3) rad/s, ``motor``
(T, 4) Ω_cmd/Ω_max in mjxsysid's rotor order; optionally ``quat`` (T, 4) the attitude (w x y z, body
FLU to the world, z up) and ``vel`` (T, 3) m/s in that world, both or neither, written as the format's
state estimate. Each writes what its reader undoes (units, frames, rotor orders, the motor command's
encoding) at every row, so a flight reads back within the format's resolution. The records are packed
with numpy (structured dtypes, one block per record type, merged in time order by :func:`interleave`):
a 10-minute flight writes in seconds.
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.blackbox import BF_TO_MJX, MAGIC as BLACKBOX_MAGIC, QUAT_SCALE
from mjxsysid.logs.blackbox_frames import END_OF_LOG
from mjxsysid.logs.crazyflie import CF_ORDER, MAGIC as USD_MAGIC, PWM_FULL, STAMP, TYPE_CODES
from mjxsysid.logs.dataflash import AP_QUADX_ORDER, EV_ARMED, EV_DISARMED, FORMAT_DTYPES
from mjxsysid.logs.record import interleave
from mjxsysid.logs.rosbag import typestore_with_mavros
from mjxsysid.logs.ulog import PX4_QUADX_ORDER
from mjxsysid.logs.ulog_write import FRD, FRD_QUAT, state_estimate  # FLU <-> FRD, world <-> NED: (x, −y, −z)


def _flight(t, imu, a_cmd, omega_cmd, motor, quat, vel):
    """The flight's arrays as float64, then its attitude and velocity where given (:func:`~.ulog_write.state_estimate`)."""
    est = state_estimate(quat, vel)
    f = [np.asarray(x, np.float64) for x in (t, imu, a_cmd, omega_cmd, motor)]
    return f + list(est) if est[0] is not None else f


def _frd_to_ned(quat):
    """Attitudes (N, 4) w x y z, body FLU to the world (z up) -> body FRD to NED: y and z negated."""
    return np.asarray(quat, np.float64) * FRD_QUAT


def _packed(dtype, columns: dict, n: int) -> np.ndarray:
    """Records of ``dtype`` from ``columns`` {field: (n,) values or a scalar} -> (n, itemsize) uint8."""
    a = np.zeros(n, dtype)
    for k, v in columns.items():
        a[k] = v
    return a.view(np.uint8).reshape(n, dtype.itemsize)


# ---- Crazyflie uSD (mjxsysid.logs.crazyflie)

def usd_log(version: int, events, records) -> bytes:
    """A Crazyflie uSD log: ``events`` [(id, name, [(variable, struct code)])], ``records`` [(id, ticks
    (N,), {variable: (N,) values})] merged in time order; the CRC32 at the end."""
    out = bytearray([USD_MAGIC]) + struct.pack("<HH", version, len(events))
    dtypes = {}
    for eid, name, variables in events:
        out += struct.pack("<H", eid) + name.encode() + b"\0" + struct.pack("<H", len(variables))
        for var, code in variables:
            out += f"{var}({code})".encode() + b"\0"
        dtypes[eid] = np.dtype([("id", "<u2"), ("t", STAMP[version][0])] + [(v, TYPE_CODES[c]) for v, c in variables])
    blocks = [(ticks, _packed(dtypes[eid], {"id": eid, "t": ticks, **cols}, len(ticks)))
              for eid, ticks, cols in records]
    out += interleave(blocks)
    return bytes(out) + struct.pack("<I", zlib.crc32(bytes(out)))


def write_crazyflie(path, t, imu, a_cmd, omega_cmd, motor, *, quat=None, vel=None) -> Path:
    """A flight as a Crazyflie uSD log (version 2, µs since boot = ``t``): event ``imuMotors`` (acc.x/y/z in
    g, gyro.x/y/z in deg/s, motor.m1..m4 the PWM duty Ω_cmd² · 65535 in the Crazyflie's M1..M4 order) and,
    given ``quat`` and ``vel``, event ``stateEstimate`` (vx/vy/vz, qx/qy/qz/qw). The Crazyflie logs no
    setpoints: ``a_cmd`` and ``omega_cmd`` are not written (its reader fills them from the IMU). -> ``path``."""
    t, imu, _, _, motor, *est = _flight(t, imu, a_cmd, omega_cmd, motor, quat, vel)
    ticks = np.round(t * 1e6).astype(np.uint64)
    duty = np.round(np.clip(motor, 0, 1) ** 2 * PWM_FULL)[:, np.argsort(CF_ORDER)]
    cols = {**{f"acc.{a}": imu[:, 3 + i] / P.GRAVITY for i, a in enumerate("xyz")},
            **{f"gyro.{a}": np.rad2deg(imu[:, i]) for i, a in enumerate("xyz")},
            **{f"motor.m{k + 1}": duty[:, k] for k in range(4)}}
    events = [(1, "imuMotors", [(k, "H" if k.startswith("motor") else "f") for k in cols])]
    records = [(1, ticks, cols)]
    if est:
        q, v = est
        s = {**{f"stateEstimate.v{a}": v[:, i] for i, a in enumerate("xyz")},
             **{f"stateEstimate.q{a}": q[:, (i + 1) % 4] for i, a in enumerate("xyzw")}}
        events.append((2, "stateEstimate", [(k, "f") for k in s]))
        records.append((2, ticks, s))
    Path(path).write_bytes(usd_log(2, events, records))
    return Path(path)


# ---- Betaflight / Indiflight blackbox (mjxsysid.logs.blackbox)

def _vb_bytes(v) -> tuple[np.ndarray, np.ndarray]:
    """Blackbox's variable-byte encoding of unsigned ints ``v`` (N,) -> (bytes (N, 5) uint8, used (N, 5) bool)."""
    v = np.asarray(v, np.int64) & 0xFFFFFFFF
    k = np.arange(5)
    n = 1 + (v[:, None] >= (1 << (7 * k[1:]))).sum(1)
    b = ((v[:, None] >> (7 * k)) & 0x7F) | np.where(k < n[:, None] - 1, 0x80, 0)
    return b.astype(np.uint8), k < n[:, None]


def blackbox_log(fields: dict, headers: dict) -> bytes:
    """One blackbox log: ``fields`` {name: (N,) ints} as intra (I) frames only (predictor none; unsigned
    variable bytes for loopIteration and time, signed (zig-zag) for the others), ``headers`` {name: text},
    then the end-of-log event."""
    names = ["loopIteration", "time"] + [k for k in fields if k not in ("loopIteration", "time")]
    n = len(fields["time"])
    fields = {"loopIteration": np.arange(n), **fields}
    unsigned = ("loopIteration", "time")
    head = [BLACKBOX_MAGIC.decode(), "H Data version:2", "H I interval:1", "H P interval:1/1",
            "H Firmware type:Cleanflight", f"H Field I name:{','.join(names)}",
            f"H Field I signed:{','.join('0' if k in unsigned else '1' for k in names)}",
            f"H Field I predictor:{','.join('0' for _ in names)}",
            f"H Field I encoding:{','.join('1' if k in unsigned else '0' for k in names)}",
            f"H Field P predictor:{','.join('0' for _ in names)}",
            f"H Field P encoding:{','.join('1' if k in unsigned else '0' for k in names)}"]
    head += [f"H {k}:{v}" for k, v in headers.items()]
    parts = [(np.full((n, 1), ord("I"), np.uint8), np.ones((n, 1), bool))]
    for k in names:
        v = np.asarray(fields[k], np.int64)
        parts.append(_vb_bytes(v if k in unsigned else (v << 1) ^ (v >> 63)))
    body = np.concatenate([b for b, _ in parts], 1)[np.concatenate([m for _, m in parts], 1)]
    return "\n".join(head).encode() + b"\n" + body.tobytes() + b"E\xff" + END_OF_LOG


BLACKBOX_IDLE = 158
"""The DShot command at zero throttle of the written blackbox logs (Betaflight's idle with the digital idle offset)."""


def write_blackbox(path, t, imu, a_cmd, omega_cmd, motor, *, quat=None, vel=None) -> Path:
    """A flight as an Indiflight blackbox log (time µs = ``t``): gyroADC (deg/s × 10, high resolution),
    accSmooth (acc_1G 2048), motor (DShot, motorOutput 158–2047, throttle = Ω_cmd², Betaflight's M1..M4
    order), the rate setpoint gyroSp (FRD, deg/s × 10), the specific force setpoint spfSp (cm/s², FRD)
    and, given ``quat`` and ``vel``, vel (cm/s, NED) and quat (body FRD to NED, × 8127). -> ``path``."""
    t, imu, a_cmd, omega_cmd, motor, *est = _flight(t, imu, a_cmd, omega_cmd, motor, quat, vel)
    hi = 2047
    bf = np.round(BLACKBOX_IDLE + np.clip(motor, 0, 1) ** 2 * (hi - BLACKBOX_IDLE))[:, np.argsort(BF_TO_MJX)]
    deg10 = lambda w: np.round(np.rad2deg(w) * 10)                           # noqa: E731
    f = {"time": np.round(t * 1e6)}
    f.update({f"gyroADC[{i}]": deg10(imu[:, i]) for i in range(3)})
    f.update({f"accSmooth[{i}]": np.round(imu[:, 3 + i] / P.GRAVITY * 2048) for i in range(3)})
    f.update({f"motor[{i}]": bf[:, i] for i in range(4)})
    f.update({f"gyroSp[{i}]": deg10(omega_cmd[:, i] * FRD[i]) for i in range(3)})
    spf = np.stack([0 * a_cmd, 0 * a_cmd, -a_cmd * 100], -1)
    f.update({f"spfSp[{i}]": np.round(spf[:, i]) for i in range(3)})
    if est:
        q, v = est
        f.update({f"vel[{i}]": np.round(v[:, i] * FRD[i] * 100) for i in range(3)})
        f.update({f"quat[{i}]": np.round(_frd_to_ned(q)[:, i] * QUAT_SCALE) for i in range(4)})
    headers = {"Firmware revision": "Indiflight 5.0.0 (mjxsysid)", "gyro_scale": "0x3f800000",
               "motorOutput": f"{BLACKBOX_IDLE},{hi}", "acc_1G": "2048", "blackbox_high_resolution": "1"}
    Path(path).write_bytes(blackbox_log(f, headers))
    return Path(path)


# ---- ArduPilot DataFlash (mjxsysid.logs.dataflash)

ARDUCOPTER_MESSAGES = (("PARM", "QNf", "TimeUS,Name,Value"), ("MSG", "QZ", "TimeUS,Message"), ("EV", "QB", "TimeUS,Id"),
                       ("IMU", "QffffffB", "TimeUS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ,I"),
                       ("RCOU", "QHHHHHH", "TimeUS,C1,C2,C3,C4,C5,C6"), ("RATE", "Qfff", "TimeUS,RDes,PDes,YDes"),
                       ("CTUN", "Qff", "TimeUS,ThO,ThH"), ("XKF1", "QBfff", "TimeUS,C,VN,VE,VD"),
                       ("ATT", "Qfff", "TimeUS,Roll,Pitch,Yaw"))
"""(name, format, columns) of the ArduCopter messages the DataFlash reader uses, as written here."""


class DataFlashLog:
    """A DataFlash log being written: :meth:`define` a message type (its FMT record; ``messages``
    [(name, format, columns)] at once), :meth:`add` records of it (columns of arrays, TimeUS first),
    then :meth:`bytes`: the FMT records, then every record merged in TimeUS order (equal times in the
    order added)."""

    def __init__(self, messages=()):
        self.types: dict = {}
        self.blocks: list = []
        self.define("FMT", "BBnNZ", "Type,Length,Name,Format,Columns")
        for name, fmt, columns in messages:
            self.define(name, fmt, columns)

    def define(self, name: str, fmt: str, columns: str) -> None:
        cols = columns.split(",")
        dt = np.dtype([("head", "S2"), ("type", "u1")] + [(c, FORMAT_DTYPES[f]) for c, f in zip(cols, fmt)])
        self.types[name] = (128 + len(self.types), fmt, columns, dt)

    def add(self, name: str, **columns) -> None:
        """Records of ``name``: ``columns`` {column: (N,) values or a scalar}, TimeUS (N,) among them."""
        typ, _, _, dt = self.types[name]
        n = len(np.atleast_1d(columns["TimeUS"]))
        self.blocks.append((np.atleast_1d(columns["TimeUS"]),
                            _packed(dt, {"head": b"\xa3\x95", "type": typ, **columns}, n)))

    def bytes(self) -> bytes:
        typ, _, _, dt = self.types["FMT"]
        fmt = _packed(dt, {"head": b"\xa3\x95", "type": typ,
                           "Type": [v[0] for v in self.types.values()],
                           "Length": [v[3].itemsize for v in self.types.values()],
                           "Name": [k.encode() for k in self.types],
                           "Format": [v[1].encode() for v in self.types.values()],
                           "Columns": [v[2].encode() for v in self.types.values()]}, len(self.types))
        return fmt.tobytes() + interleave(self.blocks)


def throttle_for_rotor_speed(s, e: float):
    """The throttle u ∈ [0, 1] giving Ω_cmd/Ω_max ``s`` under thrust ∝ (1 − e) u + e u² (the inverse of
    :func:`~mjxsysid.logs.ulog.throttle_to_rotor_speed`)."""
    s2 = np.clip(np.asarray(s, np.float64), 0, 1) ** 2
    if e == 0:
        return s2
    return (-(1 - e) + np.sqrt((1 - e) ** 2 + 4 * e * s2)) / (2 * e)


def _euler_zyx(q):
    """ArduPilot's roll, pitch, yaw (N,) rad (Z-Y-X) of rotations ``q`` (N, 4) w x y z."""
    w, x, y, z = np.asarray(q, np.float64).T
    return (np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)), np.arcsin(np.clip(2 * (w * y - z * x), -1, 1)),
            np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def write_dataflash(path, t, imu, a_cmd, omega_cmd, motor, *, quat=None, vel=None, expo: float = 0.65,
                    hover: float | None = None) -> Path:
    """A flight as an ArduCopter DataFlash log (TimeUS = ``t``, armed throughout): IMU (FRD), RCOU (PWM
    1000–2000 µs through MOT_THST_EXPO ``expo``, ArduCopter's quad-X motors 1..4 on C1..C4), RATE
    (deg/s FRD), CTUN (ThO = a_cmd · ``hover`` / g, ThH = ``hover``; default the median Ω_cmd²), and given
    ``quat`` and ``vel`` XKF1 (VN/VE/VD) with ATT (deg); the parameters the reader needs. -> ``path``."""
    t, imu, a_cmd, omega_cmd, motor, *est = _flight(t, imu, a_cmd, omega_cmd, motor, quat, vel)
    us = np.round(t * 1e6).astype(np.uint64)
    hover = float(np.median((motor ** 2).mean(1))) if hover is None else hover
    w = DataFlashLog(ARDUCOPTER_MESSAGES)
    params = {"FRAME_CLASS": 1, "FRAME_TYPE": 1, "MOT_PWM_MIN": 1000, "MOT_PWM_MAX": 2000, "MOT_THST_EXPO": expo,
              "MOT_THST_HOVER": hover, "AHRS_EKF_TYPE": 3, **{f"SERVO{n}_FUNCTION": 32 + n for n in range(1, 5)}}
    w.add("PARM", TimeUS=np.zeros(len(params), np.uint64), Name=[k.encode() for k in params],
          Value=list(params.values()))
    w.add("MSG", TimeUS=us[:1], Message=b"ArduCopter V4.5.7 (mjxsysid)")
    w.add("EV", TimeUS=us[[0, -1]], Id=[EV_ARMED, EV_DISARMED])
    g = imu * np.tile(FRD, 2)
    w.add("IMU", TimeUS=us, **{c: g[:, i] for i, c in enumerate(("GyrX", "GyrY", "GyrZ", "AccX", "AccY", "AccZ"))}, I=0)
    pwm = np.round(1000 + 1000 * throttle_for_rotor_speed(motor, expo))[:, list(AP_QUADX_ORDER)]
    w.add("RCOU", TimeUS=us, **{f"C{k + 1}": pwm[:, k] for k in range(4)}, C5=0, C6=0)
    rate = np.rad2deg(omega_cmd * FRD)
    w.add("RATE", TimeUS=us, RDes=rate[:, 0], PDes=rate[:, 1], YDes=rate[:, 2])
    w.add("CTUN", TimeUS=us, ThO=a_cmd * hover / P.GRAVITY, ThH=hover)
    if est:
        q, v = est
        v_ned = v * FRD
        w.add("XKF1", TimeUS=us, C=0, VN=v_ned[:, 0], VE=v_ned[:, 1], VD=v_ned[:, 2])
        r, p, y = (np.rad2deg(a) for a in _euler_zyx(_frd_to_ned(q)))
        w.add("ATT", TimeUS=us, Roll=r, Pitch=p, Yaw=y)
    Path(path).write_bytes(w.bytes())
    return Path(path)


# ---- ROS 1 / 2 bags (mjxsysid.logs.rosbag)

def write_bag(path, typestore, messages, storage=None) -> Path:
    """A bag of ``messages`` [(topic, msgtype, receive time ns, message)] (in receive-time order): a ROS 1
    bag when ``storage`` is None, else a ROS 2 bag folder (``storage``: rosbags' StoragePlugin). -> ``path``."""
    if storage is None:
        from rosbags.rosbag1 import Writer
        writer, serialize = Writer(path), typestore.serialize_ros1
    else:
        from rosbags.rosbag2 import Writer
        writer, serialize = Writer(path, version=8, storage_plugin=storage), typestore.serialize_cdr
    with writer as w:
        conns = {}
        for topic, typ, t_ns, msg in messages:
            if topic not in conns:
                conns[topic] = w.add_connection(topic, typ, typestore=typestore)
            w.write(conns[topic], int(t_ns), serialize(msg, typ))
    return Path(path)


def flight_messages(typestore, t, imu, omega_cmd, motor, quat=None, vel=None, start_s: float = 1.6e9):
    """The mavros topics of a flight -> [(topic, msgtype, ns, message)] in time order, stamped and received
    at ``start_s`` + ``t``: /mavros/imu/data (Imu, FLU; orientation ENU <- FLU, the world taken as ENU),
    /mavros/rc/out (RCOut, PWM 1000 + 1000 Ω_cmd² µs in PX4's quad-X order), /mavros/setpoint_raw/target_attitude
    (AttitudeTarget body_rate) and, given ``vel``, /mavros/local_position/velocity_local (TwistStamped, ENU)."""
    T = typestore.types
    Time, Header, Vec, Quat = (T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"],
                               T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"])
    seq = "seq" in Header.__dataclass_fields__
    cov = np.zeros(9)
    q = np.tile([1.0, 0, 0, 0], (len(t), 1)) if quat is None else np.asarray(quat, np.float64)
    pwm = np.ascontiguousarray(np.round(1000 + 1000 * np.clip(motor, 0, 1) ** 2)[:, list(PX4_QUADX_ORDER)], np.uint16)
    out = []
    for i, ti in enumerate(np.asarray(t, np.float64) + start_s):
        sec = int(ti)
        stamp = Time(sec=sec, nanosec=int(round((ti - sec) * 1e9)))
        head = (lambda frame: Header(seq=0, stamp=stamp, frame_id=frame) if seq  # noqa: E731
                else Header(stamp=stamp, frame_id=frame))
        ns = int(round(ti * 1e9))
        g, a = imu[i, :3], imu[i, 3:]
        out.append(("/mavros/imu/data", "sensor_msgs/msg/Imu", ns, T["sensor_msgs/msg/Imu"](
            header=head("base_link"), orientation=Quat(x=q[i, 1], y=q[i, 2], z=q[i, 3], w=q[i, 0]),
            orientation_covariance=cov, angular_velocity=Vec(x=g[0], y=g[1], z=g[2]), angular_velocity_covariance=cov,
            linear_acceleration=Vec(x=a[0], y=a[1], z=a[2]), linear_acceleration_covariance=cov)))
        out.append(("/mavros/rc/out", "mavros_msgs/msg/RCOut", ns, T["mavros_msgs/msg/RCOut"](
            header=head(""), channels=pwm[i])))
        w = omega_cmd[i]
        out.append(("/mavros/setpoint_raw/target_attitude", "mavros_msgs/msg/AttitudeTarget", ns,
                    T["mavros_msgs/msg/AttitudeTarget"](header=head(""), type_mask=0, orientation=Quat(
                        x=q[i, 1], y=q[i, 2], z=q[i, 3], w=q[i, 0]), body_rate=Vec(x=w[0], y=w[1], z=w[2]),
                        thrust=0.5)))
        if vel is not None:
            v = vel[i]
            tw = T["geometry_msgs/msg/Twist"](linear=Vec(x=v[0], y=v[1], z=v[2]), angular=Vec(x=0.0, y=0.0, z=0.0))
            out.append(("/mavros/local_position/velocity_local", "geometry_msgs/msg/TwistStamped", ns,
                        T["geometry_msgs/msg/TwistStamped"](header=head("map"), twist=tw)))
    return out


def write_rosbag(path, t, imu, a_cmd, omega_cmd, motor, *, quat=None, vel=None, storage=None) -> Path:
    """A flight as a mavros bag (:func:`flight_messages`): ROS 1 when ``storage`` is None, else a ROS 2
    bag folder of rosbags' StoragePlugin ``storage`` (SQLITE3 or MCAP). mavros carries no thrust setpoint
    in m/s²: ``a_cmd`` is not written (the reader fills it from the IMU). -> ``path``."""
    t, imu, _, omega_cmd, motor, *est = _flight(t, imu, a_cmd, omega_cmd, motor, quat, vel)
    ts = typestore_with_mavros(storage is None)
    return write_bag(path, ts, flight_messages(ts, t, imu, omega_cmd, motor, *est), storage)


# ---- data-driven-dynamics' PX4 tables (mjxsysid.logs.px4csv)

def write_px4csv(path, t, imu, a_cmd, omega_cmd, motor, *, quat=None, vel=None, landed_s: float = 0.0) -> Path:
    """A flight as a data-driven-dynamics table (an unnamed index column first, as the project writes them):
    timestamp µs, u0..u3 PWM through PX4's thrust model with THR_MDL_FAC 0 (pwm = 1000 + 1000 Ω_cmd²) in PX4's
    quad-X order, ang_vel and acc_b FRD, their angular acceleration (ang_acc_b), given ``quat`` and ``vel`` the
    NED velocity and the FRD→NED attitude, and ``landed`` 1 over the first ``landed_s`` seconds. It carries no
    setpoints: ``a_cmd`` and ``omega_cmd`` are not written. -> ``path``."""
    t, imu, _, _, motor, *est = _flight(t, imu, a_cmd, omega_cmd, motor, quat, vel)
    pwm = (1000.0 + 1000.0 * np.clip(motor, 0, 1) ** 2)[:, list(PX4_QUADX_ORDER)]
    g = imu * np.tile(FRD, 2)
    cols = {"timestamp": np.round(t * 1e6), **{f"u{k}": pwm[:, k] for k in range(4)}}
    if est:
        q, v = est
        v_ned, q_ned = v * FRD, _frd_to_ned(q)
        cols |= {"vx": v_ned[:, 0], "vy": v_ned[:, 1], "vz": v_ned[:, 2], **{f"q{k}": q_ned[:, k] for k in range(4)}}
    dw = np.gradient(g[:, :3], t, axis=0)
    cols |= {**{f"ang_vel_{a}": g[:, i] for i, a in enumerate("xyz")},
             **{f"acc_b_{a}": g[:, 3 + i] for i, a in enumerate("xyz")},
             **{f"ang_acc_b_{a}": dw[:, i] for i, a in enumerate("xyz")}, "landed": (t - t[0] < landed_s).astype(float)}
    table = np.column_stack([np.arange(len(t), dtype=float)] + list(cols.values()))
    np.savetxt(path, table, delimiter=",", header="," + ",".join(cols), comments="", fmt="%.10g")
    return Path(path)
