"""Crazyflie uSD-card deck binary logs (format versions 1 and 2) -> the log contract of
:mod:`mjxsysid.logs.formats`.

The format, as the firmware writes it (documented by its ``tools/usdlog/cfusdlog.py``), all
little-endian and packed:

- header: magic byte 0xBC, u16 version, u16 number of event types, then per event type: u16 id,
  its name (NUL-terminated), u16 number of variables and each variable as ``name(c)`` (NUL-terminated),
  ``c`` a Python ``struct`` type code (``f`` float, ``H`` u16, ``I`` u32, ...);
- records: u16 event id, the timestamp (version 1: u32 ms; version 2: u64 µs, both on the
  Crazyflie's clock since boot), then the event's variables packed in the header's order;
- a CRC32 (zlib's) of everything before it, u32, at the end (written when logging stops).

Each event's records have one size, so every event is decoded at once with numpy (a structured
dtype over the record bytes); only the record boundaries of a file mixing several events are
walked one by one.

Used: the event carrying ``gyro.x/y/z`` (deg/s), ``acc.x/y/z`` (g) and the motor commands
``motor.m1..m4`` or ``pwm.m1_pwm..m4_pwm`` (0–65535), found by its variables; where logged,
``rpm.m1..m4`` (an RPM deck: measured rotor speed) and ``stateEstimate.vx/vy/vz`` with
``stateEstimate.qx/qy/qz/qw`` (the on-board estimate: world-frame velocity and attitude). The
Crazyflie's body frame is FLU already; its motors are M1 front-right, M2 back-right, M3 back-left,
M4 front-left. No setpoints are logged by the usual configurations: ``a_cmd`` and ``omega_cmd``
are then filled from the measured specific force and gyro (said in ``source``).
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.segment import _runs, airborne_segment
from mjxsysid.logs.record import gather, rate_hz, rate_text
from mjxsysid.logs.grid import DT, cut, hold, interp_linear, segment_grid, user_segment, world_to_body

MAGIC = 0xBC
STAMP = {1: ("<u4", 1e-3, "u32 ms"), 2: ("<u8", 1e-6, "u64 µs")}
"""Format version -> (timestamp dtype, seconds per tick, what it is)."""

TYPE_CODES = {"b": "i1", "B": "u1", "h": "<i2", "H": "<u2", "i": "<i4", "I": "<u4", "q": "<i8",
              "Q": "<u8", "e": "<f2", "f": "<f4", "d": "<f8"}
"""The variables' struct type codes -> numpy dtypes."""

PWM_FULL = 65535.0
"""The Crazyflie's motor command at full duty (UINT16_MAX)."""

MOTOR_NAMES = (("motor.m{k}", "the mixer's motor commands motor.m1..m4"),
               ("pwm.m{k}_pwm", "the PWM sent to the motors pwm.m1_pwm..m4_pwm"))
"""Motor-command variables, in order of preference (k = 1..4)."""

CF_ORDER = (0, 3, 2, 1)
"""The Crazyflie motor (M1 front-right, M2 back-right, M3 back-left, M4 front-left, 0-based)
driving each mjxsysid rotor (front-right, front-left, back-left, back-right)."""

RPM_STUCK_FRACTION = 0.2
"""Share of samples with the motor commanded above 30 % but the RPM deck reading 0 past which
its rotor speeds are not used (a deck that lost its sensor)."""

MIN_CMD_FOR_RPM = 0.3
"""Ω_cmd/Ω_max above which a rotor must be turning (for :data:`RPM_STUCK_FRACTION`)."""


MOTORS_ON = 0.05
"""Ω_cmd/Ω_max above which a Crazyflie motor is spinning (its motors stop at 0 when not flying)."""

MAX_CUT_S = 0.5
"""s: a stop of all motors this short, with the motors back on after it, is a motor cut in the air."""

IMPACT_G = 1.5
"""g: specific force above which a motor stop met the ground (a touch-down's impact), not the air."""

PAD_S = 1.0
"""s: ground time kept before the first spin-up and after the last stop, for the segment's search."""


class FormatError(ValueError):
    """A file that is not a readable Crazyflie uSD log; the message says where and why."""


class HeaderCut(FormatError):
    """The bytes end inside the header (a file's first bytes only, or a file cut short)."""


def _cstring(data: bytes, i: int):
    end = data.find(b"\0", i)
    if end < 0:
        raise HeaderCut(f"byte {i}: the header ends inside a name")
    try:
        return data[i:end].decode("ascii"), end + 1
    except UnicodeDecodeError:
        raise FormatError(f"byte {i}: a name in the header is not ASCII text") from None


def parse_header(data: bytes):
    """The header of a uSD log ``data`` -> (version, events {id: (name, [variable names],
    record dtype)}, byte offset of the first record). The record dtype is packed: ``id`` u16,
    ``t`` the timestamp, then the variables. FormatError on anything else."""
    if len(data) < 5 or data[0] != MAGIC:
        raise FormatError("does not start with the uSD log's magic byte 0xBC")
    version, n_events = struct.unpack_from("<HH", data, 1)
    if version not in STAMP:
        raise FormatError(f"format version {version}; versions 1 and 2 are known")
    i, events = 5, {}
    for _ in range(n_events):
        if i + 2 > len(data):
            raise HeaderCut(f"byte {i}: the header ends inside the event table")
        (eid,), i = struct.unpack_from("<H", data, i), i + 2
        name, i = _cstring(data, i)
        if i + 2 > len(data):
            raise HeaderCut(f"byte {i}: the header ends inside the event table")
        (n_vars,), i = struct.unpack_from("<H", data, i), i + 2
        names, fields = [], [("id", "<u2"), ("t", STAMP[version][0])]
        for _ in range(n_vars):
            var, i = _cstring(data, i)
            if len(var) < 4 or var[-3] != "(" or var[-1] != ")" or var[-2] not in TYPE_CODES:
                raise FormatError(f"event {name!r}: variable {var!r} is not 'name(c)' with a known type code "
                                  f"({''.join(TYPE_CODES)})")
            names.append(var[:-3])
            fields.append((var[:-3], TYPE_CODES[var[-2]]))
        if eid in events or len(set(names)) != len(names):
            raise FormatError(f"event {name!r} (id {eid}): an id or variable name appears twice in the header")
        events[eid] = (name, names, np.dtype(fields))
    return version, events, i


def record_offsets(data: bytes, start: int, end: int, sizes: dict):
    """Byte offsets of the records between ``start`` and ``end`` -> ({event id: offsets (N,)},
    problem or None, where the complete records end). ``sizes`` {id: record bytes}. A file of one
    event type is sliced at once; one that mixes several is walked record by record. The problem
    (a sentence) is an unknown event id or a record cut short at ``end``."""
    if len(sizes) == 1:
        (eid, size), = sizes.items()
        n = (end - start) // size
        ids = np.ndarray((n,), "<u2", data, start, (size,))
        if (end - start) % size == 0 and np.all(ids == eid):
            return {eid: start + size * np.arange(n)}, None, end
    offsets = {e: [] for e in sizes}
    i = start
    while i < end:
        if i + 2 > end:
            return _arrays(offsets), f"a record is cut short at byte {i}", i
        eid = data[i] | (data[i + 1] << 8)
        size = sizes.get(eid)
        if size is None:
            return _arrays(offsets), f"byte {i}: event id {eid} is not in the header's table {sorted(sizes)}", i
        if i + size > end:
            return _arrays(offsets), f"a record is cut short at byte {i}", i
        offsets[eid].append(i)
        i += size
    return _arrays(offsets), None, i


def _arrays(offsets):
    return {e: np.asarray(v, np.int64) for e, v in offsets.items()}


def decode(path):
    """Decode a Crazyflie uSD log -> (version, {event name: {"t": (N,) s on the Crazyflie's clock,
    variable: (N,) as logged}}, CRC sentence). ValueError (one line, naming the file) when the
    file is not a uSD log, or ends mid-record or holds an unknown event id: the log was not closed
    (a power cut or the card pulled while logging) or is damaged; :func:`close_truncated` then
    writes its complete records with a CRC. A CRC that does not match complete records is said in
    the sentence, not raised: the records are read."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    data = path.read_bytes()
    try:
        version, events, start = parse_header(data)
    except FormatError as e:
        raise ValueError(f"{path}: not a readable Crazyflie uSD log: {e}") from None
    if len(data) < start + 4:
        raise ValueError(f"{path}: the uSD log holds its header only ({len(data)} bytes): no records, no CRC; "
                         f"log a flight (the deck records while its logging is on)")
    sizes = {eid: dt.itemsize for eid, (_, _, dt) in events.items()}
    offsets, problem, stop = record_offsets(data, start, len(data) - 4, sizes)
    if problem is not None:
        n = sum(len(v) for v in offsets.values())
        raise ValueError(f"{path}: the uSD log ends mid-record or is damaged ({problem}; {n} complete records "
                         f"before it): it was not closed (power cut or card pulled while logging?); "
                         f"mjxsysid.logs.crazyflie.close_truncated(path, out) writes the complete records "
                         f"with their CRC to a new file to read")
    crc = zlib.crc32(data[:stop])
    logged = struct.unpack_from("<I", data, stop)[0]
    said = (f"CRC32 checked: matches ({len(data)} bytes)" if crc == logged else
            f"warning: the CRC32 at the end ({logged:#010x}) does not match the records ({crc:#010x}): some "
            f"bytes were changed on the card; the records were read as they are")
    out = {}
    scale = STAMP[version][1]
    for eid, (name, names, dtype) in events.items():
        rec = gather(data, offsets[eid], dtype)
        cols = {"t": rec["t"].astype(np.float64) * scale}
        cols.update({v: np.asarray(rec[v]) for v in names})
        out[name] = cols
    return version, out, said


def close_truncated(path, out):
    """Write the complete records of the uSD log at ``path`` (one that ends mid-record or is
    damaged after some records) to ``out``, with their CRC32 -> the number of bytes dropped."""
    data = Path(path).read_bytes()
    try:
        _, events, start = parse_header(data)
    except FormatError as e:
        raise ValueError(f"{path}: not a readable Crazyflie uSD log: {e}") from None
    sizes = {eid: dt.itemsize for eid, (_, _, dt) in events.items()}
    _, _, stop = record_offsets(data, start, len(data), sizes)
    Path(out).write_bytes(data[:stop] + struct.pack("<I", zlib.crc32(data[:stop])))
    return len(data) - stop


def sniff(head: bytes) -> bool:
    """Is ``head`` (a file's first bytes) a Crazyflie uSD log? The magic byte, a known version and
    an event table that parses as far as ``head`` goes (:mod:`mjxsysid.logs.formats`)."""
    if len(head) < 5 or head[0] != MAGIC or struct.unpack_from("<HH", head, 1)[1] == 0:
        return False
    try:
        parse_header(head)
    except HeaderCut:
        return True
    except FormatError:
        return False
    return True


def _find(events, names):
    """The first event (name) logging every variable of ``names``, or None."""
    for ev, cols in events.items():
        if all(n in cols for n in names):
            return ev
    return None


def _describe(events) -> str:
    return "; ".join(f"{ev}: {', '.join(k for k in cols if k != 't')}" for ev, cols in events.items())


def _require(path, events, what, names, step):
    ev = _find(events, names)
    if ev is None:
        raise ValueError(f"{path}: no event logs {what} ({', '.join(names)}); the log's events: "
                         f"{_describe(events)}; {step}")
    return ev


def body_velocity(v_world, q_xyzw):
    """The world-frame velocity ``v_world`` (N, 3) in the body frame, with the attitude quaternions
    ``q_xyzw`` (N, 4) (x, y, z, w; body to world, as the Crazyflie's estimator logs them) -> (N, 3)."""
    q = np.asarray(q_xyzw, np.float64)
    return world_to_body(q[:, [3, 0, 1, 2]], v_world)


def rotor_speed_fit(u, omega) -> dict:
    """Least squares of the measured rotor speed ``omega`` (N, 4) rad/s on the commanded
    Ω_cmd/Ω_max ``u`` (N, 4), all rotors pooled, samples with a rotor at rest left out ->
    {slope, intercept (rad/s), r2, through_origin (rad/s: the slope with no intercept, Ω_max if
    Ω = Ω_max·u), n}."""
    u, w = np.asarray(u, np.float64).ravel(), np.asarray(omega, np.float64).ravel()
    ok = (w > 0) & (u > 0)
    u, w = u[ok], w[ok]
    if len(u) < 10 or np.ptp(u) == 0:
        return {"slope": float("nan"), "intercept": float("nan"), "r2": float("nan"),
                "through_origin": float("nan"), "n": int(len(u))}
    a, b = np.polyfit(u, w, 1)
    r2 = 1.0 - float(np.sum((w - (a * u + b)) ** 2) / np.sum((w - w.mean()) ** 2))
    return {"slope": float(a), "intercept": float(b), "r2": r2,
            "through_origin": float(np.dot(u, w) / np.dot(u, u)), "n": int(len(u))}


def _motor_channels(path, events):
    """(event, variable names M1..M4, what) of the motor commands."""
    for pattern, what in MOTOR_NAMES:
        names = [pattern.format(k=k) for k in range(1, 5)]
        ev = _find(events, names)
        if ev is not None:
            return ev, names, what
    raise ValueError(f"{path}: no event logs the motor commands (motor.m1..m4 or pwm.m1_pwm..m4_pwm); the log's "
                     f"events: {_describe(events)}; add the 'motor' log group to the uSD deck's config.txt "
                     f"(in the event with gyro and acc) and log again, or convert the log to the CSV of "
                     f"docs/decoding.md with the motor commands from elsewhere")


def flight_signal(t, motor, acc_g):
    """The mean motor command for :func:`~mjxsysid.logs.segment.airborne_segment`, from the motor
    commands ``motor`` (N, 4) Ω_cmd/Ω_max and the specific force ``acc_g`` (N, 3) in g at ``t`` (N,) s:
    motor cuts in the air (every motor stopped for under :data:`MAX_CUT_S`, on again after, no
    impact above :data:`IMPACT_G` in the stop) filled with the command before the cut, and the
    samples more than :data:`PAD_S` before the first spin-up or after the last stop dropped (a log
    mostly on the ground still has its flight as the upper half of its commands) -> (t (M,),
    signal (M, 1), sentence)."""
    m = np.asarray(motor, np.float64).mean(-1)
    off = m <= MOTORS_ON
    if off.all():
        return t, m[:, None], ""
    peak = np.linalg.norm(acc_g, axis=-1)
    starts, stops = _runs(off)
    cuts = [(a, b) for a, b in zip(starts, stops)
            if 0 < a and b < len(m) and t[b] - t[a] < MAX_CUT_S and peak[a:b].max() < IMPACT_G]
    for a, b in cuts:
        m[a:b] = m[a - 1]
    on = np.flatnonzero(~off)
    keep = (t >= t[on[0]] - PAD_S) & (t <= t[on[-1]] + PAD_S)
    said = (f"; {len(cuts)} motor cuts in the air (all motors off under {MAX_CUT_S:g} s, back on after, no impact "
            f"above {IMPACT_G:g} g) counted as flight" if cuts else "")
    return t[keep], m[keep, None], said


def _velocity_body(events):
    """The state estimate's velocity in the body frame -> (event, t (N,), v (N, 3) m/s FLU,
    sentence), or (None, None, None, why not or "") when the log lacks it."""
    v_names = [f"stateEstimate.v{a}" for a in "xyz"]
    q_names = [f"stateEstimate.q{a}" for a in "xyzw"]
    ev = _find(events, v_names + q_names)
    if ev is None:
        return None, None, None, ""
    q = np.stack([events[ev][n] for n in q_names], -1).astype(np.float64)
    off = np.abs(np.linalg.norm(q, axis=1) - 1) >= 0.1
    if off.any():
        return None, None, None, (f"velocity_body: not used: the attitude quaternion's norm is off 1 on "
                                  f"{100 * off.mean():.0f} % of the samples (the estimator not running?)")
    vw = np.stack([events[ev][n] for n in v_names], -1)
    return ev, events[ev]["t"], body_velocity(vw, q), (
        "velocity_body: the estimator's world-frame velocity stateEstimate.vx/vy/vz rotated into the body frame "
        "with its attitude quaternion qx/qy/qz/qw (body to world): Rᵀ v, m/s FLU")


def _segment(path, segment, t_imu, t_m, motor, acc_g):
    """(t0, t1, why) on the Crazyflie's clock."""
    given = user_segment(path, segment, float(t_imu[0]), float(t_imu[-1]),
                         "seconds on the Crazyflie's clock since boot, as logged")
    if given is not None:
        return given
    t_s, signal, said = flight_signal(t_m, motor, acc_g)
    t0, t1, why = airborne_segment(t_s, signal)
    return t0, t1, why + said


def read_crazyflie(path, segment=None) -> dict:
    """Read a Crazyflie uSD log -> the log contract of :mod:`mjxsysid.logs.formats` (t (T,) s on the
    Crazyflie's clock since boot, imu (T, 6), a_cmd (T,), omega_cmd (T, 3), motor (T, 4) on a 2 ms
    grid; rotor_speed (T, 4) rad/s with an RPM deck, velocity_body (T, 3) m/s with the state
    estimate's velocity and attitude), ``native``, ``resampled`` and ``source``, over the airborne
    segment (:func:`~mjxsysid.logs.segment.airborne_segment` on the motor commands) or ``segment``
    ('t0:t1' or (t0, t1) on the same clock). ValueError (naming the file, what is missing and the
    next step): not a uSD log, truncated, no gyro, accelerometer or motor commands, a segment too short."""
    path = Path(path)
    version, events, crc_said = decode(path)
    g = P.GRAVITY
    conv, used, rates, missing = [crc_said], {}, {}, ["a_cmd", "omega_cmd"]
    step = "add the group to the uSD deck's config.txt and log again"
    ev_g = _require(path, events, "the gyro", ["gyro.x", "gyro.y", "gyro.z"], step)
    ev_a = _require(path, events, "the accelerometer", ["acc.x", "acc.y", "acc.z"], step)
    ev_m, m_names, m_what = _motor_channels(path, events)

    # ---- IMU (native): deg/s -> rad/s, g -> m/s²; FLU already
    t_g = events[ev_g]["t"]
    if len(t_g) < 2:
        raise ValueError(f"{path}: event {ev_g!r} has {len(t_g)} records: no IMU data to read")
    gyro = np.stack([events[ev_g][f"gyro.{a}"] for a in "xyz"], -1).astype(np.float64) * (np.pi / 180.0)
    acc = np.stack([events[ev_a][f"acc.{a}"] for a in "xyz"], -1).astype(np.float64) * g
    if ev_a != ev_g:
        acc = interp_linear(events[ev_a]["t"], acc, t_g)
        conv.append(f"accelerometer ({ev_a}) interpolated (linear) onto the gyro's samples ({ev_g})")
    imu_native = np.concatenate([gyro, acc], -1)
    used["imu"] = f"{ev_g} (gyro.x/y/z)" + (f" + {ev_a} (acc.x/y/z)" if ev_a != ev_g else " (acc.x/y/z)")
    rates["imu"] = rate_hz(t_g)
    conv.append(f"timestamps: format version {version}, {STAMP[version][2]} on the Crazyflie's clock since boot, "
                f"read as seconds on that clock (t, segment)")
    conv.append("body frame: the Crazyflie's is FLU (x forward, y left, z up) already; gyro deg/s × π/180 -> rad/s, "
                f"accelerometer g × {g:g} -> m/s² (the firmware scales it to 1 g at rest: mjxsysid's g)")

    # ---- motors: Crazyflie M1..M4 -> mjxsysid's order, PWM duty -> Ω_cmd/Ω_max
    t_m = events[ev_m]["t"]
    raw = np.stack([events[ev_m][n] for n in m_names], -1).astype(np.float64)
    motor_native = np.sqrt(np.clip(raw / PWM_FULL, 0.0, 1.0))[:, CF_ORDER]
    used["motor"] = f"{ev_m} ({', '.join(m_names)})"
    rates["motor"] = rate_hz(t_m)
    conv.append(f"motor commands: {m_what} (0–{PWM_FULL:g}) over {PWM_FULL:g} are the motors' duty, the "
                f"throttle; thrust ∝ throttle (roughly, for the Crazyflie's brushed motors) and thrust ∝ Ω², so "
                f"Ω_cmd/Ω_max = √(pwm/{PWM_FULL:g})")
    conv.append("rotor order: Crazyflie M1 front-right (CCW), M2 back-right (CW), M3 back-left (CCW), M4 front-left "
                "(CW) reordered to mjxsysid's front-right, front-left, back-left, back-right (M1, M4, M3, M2); the "
                "spin directions are mjxsysid's")

    acc_m = acc if ev_a == ev_m and ev_a == ev_g else interp_linear(t_g, acc, t_m)
    t0, t1, why = _segment(path, segment, t_g, t_m, motor_native, acc_m / g)
    grid = segment_grid(path, t0, t1)

    native = {"imu": cut(t_g, imu_native, t0, t1), "motor": cut(t_m, motor_native, t0, t1)}
    rec = {"t": grid, "imu": interp_linear(*native["imu"], grid), "motor": hold(*native["motor"], grid)}
    how = {"imu": "interpolated (linear)", "motor": "held (zero-order)"}

    # ---- no setpoints: a_cmd and omega_cmd from the measurements
    rec["a_cmd"] = rec["imu"][:, 5].copy()
    rec["omega_cmd"] = rec["imu"][:, :3].copy()
    conv.append("a_cmd and omega_cmd: the log has no setpoints; filled with the measured specific force along z "
                "and the measured gyro (on the 2 ms grid)")
    extra = {}

    # ---- rotor speed (RPM deck)
    rpm_names = [f"rpm.m{k}" for k in range(1, 5)]
    ev_r = _find(events, rpm_names)
    if ev_r is None:
        missing.append("rotor_speed")
    else:
        t_r = events[ev_r]["t"]
        omega = np.stack([events[ev_r][n] for n in rpm_names], -1).astype(np.float64)[:, CF_ORDER] * (2 * np.pi / 60)
        nat_r = cut(t_r, omega, t0, t1)
        cmd = hold(*native["motor"], nat_r[0])
        stuck = np.mean((nat_r[1] == 0) & (cmd > MIN_CMD_FOR_RPM), axis=0)
        if np.any(stuck > RPM_STUCK_FRACTION):
            missing.append("rotor_speed")
            conv.append(f"rotor speed: not used: the RPM deck reads 0 on {100 * stuck.max():.0f} % of the samples "
                        f"of a spinning rotor (a sensor lost)")
        else:
            native["rotor_speed"] = nat_r
            rec["rotor_speed"] = interp_linear(*nat_r, grid)
            how["rotor_speed"] = "interpolated (linear)"
            used["rotor_speed"] = f"{ev_r} ({', '.join(rpm_names)})"
            rates["rotor_speed"] = rate_hz(t_r)
            conv.append("rotor speed: the RPM deck's rpm.m1..m4 × 2π/60 -> rad/s, in mjxsysid's rotor order")
            fit = rotor_speed_fit(cmd, nat_r[1])
            extra["rotor_speed_fit"] = fit
            conv.append(f"rotor speed against the command √(pwm/{PWM_FULL:g}) in the segment: Ω ≈ "
                        f"{fit['slope']:.0f}·√(pwm/{PWM_FULL:g}) {fit['intercept']:+.0f} rad/s, R² {fit['r2']:.3f} "
                        f"({fit['n']} samples; through the origin {fit['through_origin']:.0f} rad/s)")

    # ---- velocity in the body frame (state estimate)
    ev_v, t_v, v_body, said = _velocity_body(events)
    if ev_v is None:
        missing.append("velocity_body")
    else:
        native["velocity_body"] = cut(t_v, v_body, t0, t1)
        rec["velocity_body"] = interp_linear(*native["velocity_body"], grid)
        how["velocity_body"] = "interpolated (linear)"
        used["velocity_body"] = f"{ev_v} (stateEstimate.vx/vy/vz, qx/qy/qz/qw)"
        rates["velocity_body"] = rate_hz(t_v)
    if said:
        conv.append(said)

    resampled = {k: (f"{how[k]} from {rate_text(rates[k])}" if abs(rates[k] * DT - 1) > 0.05
                     else f"native ({rate_text(rates[k])})") for k in how}
    resampled["a_cmd"] = "not logged: the measured specific force along z"
    resampled["omega_cmd"] = "not logged: the measured gyro"
    rec["native"] = native
    rec["resampled"] = resampled
    rec["source"] = {"format": "Crazyflie uSD", "path": str(path), "version": version, "events": used,
                     "rates_hz": {k: round(v, 2) for k, v in rates.items()},
                     "segment": {"t0": float(t0), "t1": float(t1), "why": why,
                                 "clock": "seconds on the Crazyflie's clock since boot (the log's timestamps)"},
                     "missing": missing, "conversions": conv, **extra}
    return rec


read = read_crazyflie
