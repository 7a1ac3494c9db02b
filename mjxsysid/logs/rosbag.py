"""ROS 1 bags and ROS 2 bags (mavros / PX4 vehicles) -> the log contract of :mod:`mjxsysid.logs.formats`.

A ROS 1 bag is one file starting ``#ROSBAG V2.0`` (message definitions embedded); a ROS 2 bag is a
folder (``metadata.yaml`` and ``.db3`` SQLite or ``.mcap`` files) or a bare ``.mcap`` file (magic
``\\x89MCAP0\\r\\n``) or ``.db3`` file. Read with rosbags' ``AnyReader`` (optional extra ``rosbag``).

Topics are found by message type, never by name; where several carry a type, the one with the most
messages is used (said in ``rec["source"]["topics"]``):

- ``sensor_msgs/msg/Imu``: angular_velocity rad/s and linear_acceleration m/s², FLU (REP-103; mavros
  converts PX4's FRD), and orientation (world ENU <- body FLU) for a world-frame velocity;
- ``mavros_msgs/msg/RCOut``: the PWM µs sent to the ESCs, channel n = PX4 main output n, PX4's quad-X
  order (M1 front-right, M2 back-left, M3 front-left, M4 back-right);
- ``mavros_msgs/msg/AttitudeTarget``: body_rate rad/s FLU (omega_cmd) where logged;
- ``geometry_msgs/msg/TwistStamped``: velocity, in the body (frame ``base_link``) or in the world
  (ENU, or NED for a ``*_ned`` frame) rotated into the body with the IMU's orientation.

Every time is the message's ``header.stamp`` (the sender's clock, not the bag's receive time), in
seconds since the bag's start; ``segment`` 't0:t1' is read on that clock.

A ROS 1 bag's and an MCAP file's chunks and message indexes are read with numpy, and a topic's messages
of one length and layout at once (:mod:`mjxsysid.logs.rosbag_fast`); rosbags opens the other bags (SQLite,
unindexed) and deserialises the other messages.
"""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from operator import attrgetter
from pathlib import Path

import numpy as np

from mjxsysid.logs import rosbag_fast
from mjxsysid.logs.rosbag_fast import MCAP_MAGIC, ROS1_MAGIC
from mjxsysid.logs.record import (HELD, LINEAR, assemble, body_velocity_from_world, native_rates, pick_segment,
                                    sorted_unique)
from mjxsysid.logs.ulog import PX4_QUADX_ORDER, throttle_to_rotor_speed

SQLITE_MAGIC = b"SQLite format 3\x00"

PWM_MIN, PWM_MAX = 1000.0, 2000.0
"""µs: PX4's default PWM_MAIN_MIN/MAX, the throttle range assumed (a bag carries no parameters)."""

IMU, RCOUT, ATT_TARGET, TWIST = ("sensor_msgs/msg/Imu", "mavros_msgs/msg/RCOut", "mavros_msgs/msg/AttitudeTarget",
                                 "geometry_msgs/msg/TwistStamped")


def _import_rosbags():
    """rosbags' ``AnyReader``; ImportError saying how to install rosbags where it is missing."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError:
        raise ImportError('reading ROS bags needs rosbags: pip install -e ".[rosbag]" '
                          "(or pip install rosbags)") from None
    return AnyReader


def _kind(head: bytes) -> str | None:
    """'.bag', '.mcap' or '.db3' for a ROS 1 bag, an MCAP file or a rosbag2 SQLite file's first bytes, else None."""
    if head.startswith(ROS1_MAGIC):
        return ".bag"
    if head.startswith(MCAP_MAGIC):
        return ".mcap"
    if head.startswith(SQLITE_MAGIC) and b"CREATE TABLE topics" in head and b"CREATE TABLE messages" in head:
        return ".db3"
    return None


def sniff(head: bytes) -> bool:
    """Is ``head`` (a file's first bytes) a ROS 1 bag, an MCAP file or a rosbag2 SQLite file?"""
    return _kind(head) is not None


@contextmanager
def _bag_path(path: Path):
    """The path rosbags opens for ``path``: a rosbag2 folder as is; a file under a name whose suffix
    says its content (rosbags picks the reader by suffix), through a temporary link when it does not."""
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise ValueError(f"{path}: a folder without metadata.yaml is not a ROS 2 bag; give the bag's folder "
                             f"(metadata.yaml with its .db3 or .mcap files) or a .bag / .mcap file")
        yield path
        return
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    with open(path, "rb") as f:
        kind = _kind(f.read(4096))
    if kind is None:
        raise ValueError(f"{path}: not a ROS bag (no '#ROSBAG V2.0', MCAP or rosbag2 SQLite header); "
                         f"give a ROS 1 .bag, a ROS 2 bag folder or an .mcap file")
    if path.suffix == kind:
        yield path
        return
    with tempfile.TemporaryDirectory() as tmp:
        link = Path(tmp) / ("bag" + kind)
        os.symlink(path.resolve(), link)
        yield link


STAMP = ("header.stamp.sec", "header.stamp.nanosec")
FIELDS = {IMU: ("angular_velocity.x", "angular_velocity.y", "angular_velocity.z", "linear_acceleration.x",
                "linear_acceleration.y", "linear_acceleration.z", "orientation.x", "orientation.y", "orientation.z",
                "orientation.w"),
          RCOUT: ("channels",), ATT_TARGET: ("body_rate.x", "body_rate.y", "body_rate.z"),
          TWIST: ("twist.linear.x", "twist.linear.y", "twist.linear.z")}
"""The fields read of each message type (after its header's stamp; TwistStamped's frame id too)."""

MAVROS_TYPES = {
    RCOUT: "std_msgs/Header header\nuint16[] channels\n",
    ATT_TARGET: "std_msgs/Header header\nuint8 type_mask\ngeometry_msgs/Quaternion orientation\n"
                "geometry_msgs/Vector3 body_rate\nfloat32 thrust\n"}
"""mavros' message definitions (not in rosbags' stores) the ROS 1 fast path reads."""


def typestore_with_mavros(ros1: bool):
    """rosbags' typestore of ROS 1 Noetic or ROS 2 Humble with :data:`MAVROS_TYPES` registered."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    for name, text in MAVROS_TYPES.items():
        ts.register(get_types_from_msg(text, name))
    return ts


def _topic_fields(typestore, msgtype, raws, cdr, deserialize) -> dict:
    """{path: (N,) or (N, k) array} of :data:`STAMP` and :data:`FIELDS` of a topic's raw messages ``raws``
    (and header.frame_id, a str): at once where they share a layout, else message by message."""
    paths = STAMP + FIELDS[msgtype]
    got = rosbag_fast.fields(typestore, msgtype, raws, cdr, paths)
    if got is not None:
        return got
    if isinstance(raws, np.ndarray):
        raws = [r.tobytes() for r in raws]
    msgs = [deserialize(r, msgtype) for r in raws]
    got = {p: np.asarray([attrgetter(p)(m) for m in msgs], np.float64) for p in paths if p != "channels"}
    if "channels" in paths:
        got["channels"] = np.array([np.asarray(m.channels[:4], np.float64) for m in msgs])
    got["header.frame_id"] = msgs[0].header.frame_id if msgs else ""
    return got


def _topics(raw: dict, typestore, cdr: bool, deserialize) -> dict:
    """{topic: (header times (N,) s, bag times (N,) s, fields)} of ``raw`` {topic: (msgtype, bag times (N,) ns,
    raw messages)} (fields: :func:`_topic_fields`)."""
    out = {}
    for topic, (msgtype, t_bag, raws) in raw.items():
        f = _topic_fields(typestore, msgtype, raws, cdr, deserialize)
        t = f["header.stamp.sec"].astype(np.float64) + 1e-9 * f["header.stamp.nanosec"].astype(np.float64)
        out[topic] = (t, np.asarray(t_bag, np.float64) * 1e-9, f)
    return out


def _read_topics(reader, cons) -> dict:
    """:func:`_topics` of the connections ``cons`` of an open rosbags reader."""
    raw = {c.topic: (c.msgtype, [], []) for c in cons}
    for con, t_bag, data in reader.messages(connections=cons):
        raw[con.topic][1].append(t_bag)
        raw[con.topic][2].append(bytes(data))
    return _topics(raw, reader.typestore, reader.is2, reader.deserialize)


def _bag_topics(bag, typestore, cons, cdr: bool) -> dict:
    """:func:`_topics` of the connections ``cons`` of a bag read by :mod:`~mjxsysid.logs.rosbag_fast`
    (ROS 1, or MCAP when ``cdr``)."""
    raw = {t: _merged(bag, [c for c in cons if c.topic == t]) for t in {c.topic for c in cons}}
    return _topics(raw, typestore, cdr, typestore.deserialize_cdr if cdr else typestore.deserialize_ros1)


def _merged(bag, cons) -> tuple:
    """(msgtype, bag times (N,) ns, raw messages) of a topic's connections ``cons`` in ``bag``, in time order."""
    if len(cons) == 1:                                           # one connection: in time order already
        return (cons[0].msgtype, *bag.messages[cons[0].id])
    t = np.concatenate([bag.messages[c.id][0] for c in cons])
    order = np.argsort(t, kind="stable")
    parts = [bag.messages[c.id][1] for c in cons]
    if all(isinstance(p, np.ndarray) for p in parts) and len({p.shape[1] for p in parts}) == 1:
        return cons[0].msgtype, t[order], np.concatenate(parts)[order]      # one length: still one matrix
    flat = [r.tobytes() if isinstance(p, np.ndarray) else r for p in parts for r in p]
    return cons[0].msgtype, t[order], [flat[i] for i in order.tolist()]


def _fast_bag(path: Path):
    """(bag, typestore, CDR or not) of a ROS 1 bag or an MCAP file (or a ROS 2 bag folder of one) read by
    :mod:`~mjxsysid.logs.rosbag_fast`, or None (rosbags reads it)."""
    if path.is_dir():
        files = sorted(path.glob("*.mcap"))
        if len(files) != 1 or any(path.glob("*.db3")):
            return None
        path = files[0]
    if not path.is_file():
        return None
    with open(path, "rb") as f:
        head = f.read(16)
    kind = _kind(head)
    if kind == ".bag":
        store = typestore_with_mavros(True)
        bag = rosbag_fast.read_ros1(path.read_bytes(), store, FIELDS)
        return None if bag is None else (bag, store, False)
    if kind == ".mcap":
        got = rosbag_fast.read_mcap(path.read_bytes(), typestore_with_mavros(False))
        return None if got is None else (*got, True)
    return None


def _richest(connections, msgtype, keep=lambda c: True):
    """The topic of ``msgtype`` among ``connections`` with the most messages -> (topic or None, sentence)."""
    counts: dict = {}
    for c in connections:
        if c.msgtype == msgtype and keep(c):
            counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
    if not counts:
        return None, ""
    best = max(counts, key=counts.get)
    others = [f"{t} ({n})" for t, n in counts.items() if t != best]
    return best, (f"{best} ({counts[best]} messages" + (f"; not used: {', '.join(others)})" if others else ")"))


def quat_to_matrix(q):
    """Rotation matrices (N, 3, 3) of unit quaternions ``q`` (N, 4) in ROS order (x, y, z, w)."""
    q = np.asarray(q, np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = q.T
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                     np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                     np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def _is_body_frame(frame_id: str) -> bool:
    return "base_link" in frame_id or frame_id in ("body", "fcu")


def read_rosbag(path, segment=None) -> dict:
    """Read a ROS 1 bag, a ROS 2 bag folder or an MCAP file -> the log contract
    (:mod:`mjxsysid.logs.formats`) over its airborne segment (or ``segment`` 't0:t1', seconds since
    the bag's start). ValueError: not a bag, no IMU or motor topic, too short; ImportError without rosbags."""
    AnyReader = _import_rosbags()
    path = Path(path)
    fast = _fast_bag(path)
    if fast is not None:
        bag, store, cdr = fast
        return _read(bag.connections, bag.start_time, lambda cons: _bag_topics(bag, store, cons, cdr), path, segment)
    from rosbags.typesys import Stores, get_typestore
    with _bag_path(path) as bag:
        typestore = get_typestore(Stores.ROS2_HUMBLE)        # the types of a bag without embedded definitions
        try:
            with AnyReader([bag], default_typestore=typestore) as reader:
                return _read(reader.connections, reader.start_time, lambda cons: _read_topics(reader, cons),
                             path, segment)
        except (ValueError, ImportError, FileNotFoundError):
            raise
        except Exception as e:  # rosbags raises its own errors on a damaged or unindexed bag
            raise ValueError(f"{path}: not a readable ROS bag ({type(e).__name__}: {e}); "
                             f"check it with `rosbag info` or `ros2 bag info` (reindex it if it was cut short)"
                             ) from None


def _read(connections, start_time, fetch, path, segment) -> dict:
    """The log contract of a bag's ``connections`` (topic, msgtype, msgcount), ``start_time`` (ns) and
    ``fetch(connections) -> {topic: (header times, bag times, fields)}`` (:func:`_read_topics`)."""
    topics, conv, missing = {}, [], []
    imu_topic, said = _richest(connections, IMU)
    if imu_topic is None:
        raise ValueError(f"{path}: no sensor_msgs/Imu topic; mjxsysid needs the IMU (mavros: /mavros/imu/data)")
    topics["imu"] = said
    rc_topic, said = _richest(connections, RCOUT)
    if rc_topic is None:
        raise ValueError(f"{path}: no mavros_msgs/RCOut topic (the motor PWM, mavros: /mavros/rc/out); "
                         f"record it to read this bag")
    topics["motor"] = said
    at_topic, said_at = _richest(connections, ATT_TARGET)
    tw_body, said_b = _richest(connections, TWIST, lambda c: "velocity_body" in c.topic)
    tw_any, said_w = _richest(connections, TWIST)
    tw_topic, said_tw = (tw_body, said_b) if tw_body else (tw_any, said_w)
    wanted = {imu_topic, rc_topic} | {t for t in (at_topic, tw_topic) if t}
    data = fetch([c for c in connections if c.topic in wanted])
    t_ref = start_time * 1e-9
    clock = []

    def times(topic):
        ts, tb, _ = data[topic]
        if np.all(ts == 0):
            clock.append(topic)
            return tb - t_ref
        return ts - t_ref

    # ---- IMU: FLU already
    f = data[imu_topic][2]
    t_imu = times(imu_topic)
    x_imu = np.stack([f[k] for k in FIELDS[IMU][:6]], -1).astype(np.float64)
    quat = np.stack([f[k] for k in FIELDS[IMU][6:]], -1).astype(np.float64)
    t_imu, both = sorted_unique(t_imu, np.concatenate([x_imu, quat], 1))
    x_imu, quat = both[:, :6], both[:, 6:]
    conv.append("body frame: sensor_msgs/Imu is FLU already (REP-103; mavros converts PX4's FRD): angular_velocity "
                "rad/s and linear_acceleration m/s² taken as they are")

    # ---- motors: PWM -> throttle -> Ω_cmd/Ω_max, PX4 quad-X order -> mjxsysid's
    pwm = np.asarray(data[rc_topic][2]["channels"], np.float64)
    if pwm.ndim != 2 or pwm.shape[1] < 4:
        raise ValueError(f"{path}: {rc_topic} carries fewer than 4 channels; mjxsysid needs the four motors' PWM")
    t_m, pwm = sorted_unique(times(rc_topic), pwm[:, :4])
    u = np.clip((pwm - PWM_MIN) / (PWM_MAX - PWM_MIN), 0.0, 1.0)
    rotor = throttle_to_rotor_speed(u, 0.0)[:, [list(PX4_QUADX_ORDER).index(j) for j in range(4)]]
    conv += [f"motor commands: RCOut channels 1..4 PWM µs, throttle u = (pwm − {PWM_MIN:g}) / ({PWM_MAX:g} − "
             f"{PWM_MIN:g}) clipped to [0, 1] (PX4's default PWM_MAIN_MIN/MAX: the bag carries no parameters); "
             f"thrust ∝ u assumed (THR_MDL_FAC 0, unknown) and thrust ∝ Ω²: Ω_cmd/Ω_max = √u",
             "rotor order: PX4 quad-X outputs 1..4 are front-right, back-left, front-left, back-right (PX4's default, "
             "not checked on the airframe); reordered to mjxsysid's"]

    span = (float(t_imu[0]), float(t_imu[-1]))
    t0, t1, why = pick_segment(path, segment, t_m, rotor, span)

    channels = {"imu": (t_imu, x_imu, LINEAR), "motor": (t_m, rotor, HELD)}
    if at_topic:
        w = np.stack([data[at_topic][2][k] for k in FIELDS[ATT_TARGET]], -1).astype(np.float64)
        channels["omega_cmd"] = (*sorted_unique(times(at_topic), w), HELD)
        topics["omega_cmd"] = said_at
        conv.append("omega_cmd: AttitudeTarget body_rate, rad/s FLU (mavros converts PX4's FRD)")
    else:
        channels["omega_cmd"] = (t_imu, x_imu[:, :3], LINEAR)
        missing.append("omega_cmd")
        conv.append("omega_cmd: the bag has no rate setpoint (mavros_msgs/AttitudeTarget): filled with the measured "
                    "gyro (not a setpoint)")
    channels["a_cmd"] = (t_imu, x_imu[:, 5], LINEAR)
    missing.append("a_cmd")
    conv.append("a_cmd: the bag has no collective thrust setpoint in m/s² (a normalised thrust cannot be scaled "
                "without the hover thrust): filled with the measured specific force along body z (not a setpoint)")

    if tw_topic:
        vel = _velocity(data[tw_topic][2], times(tw_topic), t_imu, quat, tw_topic)
        if vel is not None:
            channels["velocity_body"] = (vel[0], vel[1], LINEAR)
            topics["velocity_body"] = said_tw
            conv.append(vel[2])
    if "velocity_body" not in channels:
        missing.append("velocity_body")
        conv.append("velocity_body: no geometry_msgs/TwistStamped velocity (mavros local_position/velocity_body or "
                    "velocity_local) with an orientation to rotate it: not given")
    if clock:
        conv.append(f"time: {', '.join(clock)} has no header stamps: the bag's receive time used for it")
    rates, gaps = native_rates(channels)

    rec = assemble(channels, t0, t1)
    rec["source"] = {
        "format": "ROS bag", "path": str(path), "topics": topics,
        "rates_hz": rates, "max_gap_s": gaps,
        "segment": {"t0": float(t0), "t1": float(t1), "why": why,
                    "clock": "seconds since the bag's start (header.stamp − the bag's first receive time)"},
        "bag_start_s": t_ref, "conversions": conv, "missing": missing}
    return rec


def _velocity(f, t_v, t_imu, quat, topic):
    """(t (N,), v (N, 3) m/s FLU, sentence) from TwistStamped fields ``f`` at ``t_v``: as they are in a body
    frame, else rotated from the world (ENU, or NED for a '*_ned' frame) with the IMU orientation nearest in
    time; None when a world velocity has no orientation to rotate it."""
    frame = f["header.frame_id"]
    v = np.stack([f[k] for k in FIELDS[TWIST]], -1).astype(np.float64)
    t_v, v = sorted_unique(t_v, v)
    if _is_body_frame(frame):
        flip = np.array([1.0, -1.0, -1.0]) if frame.endswith("_frd") else np.ones(3)
        how = "FRD to FLU" if frame.endswith("_frd") else "FLU"
        return t_v, v * flip, f"velocity_body: {topic} twist.linear in the body frame ({frame!r}), {how}"
    if not np.all(np.isfinite(quat)) or np.any(np.linalg.norm(quat, axis=-1) < 0.5):
        return None
    if frame.endswith("_ned"):
        v = v[:, [1, 0, 2]] * np.array([1.0, 1.0, -1.0])
    i = np.clip(np.searchsorted(t_imu, t_v), 0, len(t_imu) - 1)
    v_body = body_velocity_from_world(v, quat_to_matrix(quat[i]))
    world = "NED, taken to ENU" if frame.endswith("_ned") else "ENU"
    return t_v, v_body, (f"velocity_body: {topic} twist.linear in the world ({frame!r}, {world}) rotated into the "
                         f"body FLU with the IMU orientation (ENU <- FLU) nearest in time")


read = read_rosbag
