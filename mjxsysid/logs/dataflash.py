"""ArduPilot (ArduCopter) DataFlash ``.bin`` logs -> the log contract of :mod:`mjxsysid.logs.formats`.

A DataFlash log is a stream of binary records, each ``0xA3 0x95 <type>`` and a packed payload whose
layout an ``FMT`` record declared earlier. A clean log is read with numpy (:func:`parse_records`: the FMT
records found first, the record boundaries walked once, each type's records decoded at once); a log whose
records do not chain (damaged, resynchronised) is read with pymavlink's ``DFReader_binary`` (optional
extra ``ardupilot``). Used: ``IMU`` (GyrX/Y/Z rad/s, AccX/Y/Z m/s², FRD; instance ``I`` 0 where logged),
``RCOU`` (servo outputs Cn, PWM µs), ``EV`` / ``ARM`` (armed and disarmed), ``RATE`` (RDes/PDes/YDes
deg/s: omega_cmd), ``CTUN`` (ThO and ThH: a_cmd), ``NKF1`` (EKF2) or ``XKF1`` (EKF3) VN/VE/VD (NED)
with ``ATT`` Roll/Pitch/Yaw for velocity_body, ``PARM`` (SERVOn_FUNCTION, MOT_PWM_MIN/MAX, RC3_MIN/MAX,
MOT_THST_EXPO, MOT_THST_HOVER, FRAME/FRAME_CLASS/FRAME_TYPE) and ``MSG`` (the firmware version).

Time is the autopilot's boot clock (TimeUS, or TimeMS in old logs) in seconds; ``segment`` 't0:t1'
is read on that clock (what Mission Planner and MAVExplorer plot). With the default LOG_BITMASK
ArduCopter logs IMU at about 25 Hz and RCOU at about 10 Hz: ``rec["source"]["rates_hz"]`` says so
and nothing is made to look faster than it was logged.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs.record import (HELD, LINEAR, assemble, body_velocity_from_world, gather, native_rates,
                                    pick_segment, sorted_unique)
from mjxsysid.logs.ulog import throttle_to_rotor_speed

MAGIC = b"\xa3\x95\x80"
"""A DataFlash log's first bytes: the record header 0xA3 0x95 and type 128 (its first FMT record)."""

AP_QUADX_ORDER = (0, 2, 1, 3)
"""ArduCopter quad-X motors 1..4 (front-right, back-left, front-left, back-right): the mjxsysid
rotor (0 front-right, 1 front-left, 2 back-left, 3 back-right) each drives."""

EV_ARMED, EV_DISARMED = 10, 11
"""ArduCopter's EV ids (LogEvent DATA_ARMED, DATA_DISARMED)."""

GAP_S = 1.0
"""s: an IMU gap longer than this is time the logger stopped (disarmed with LOG_DISARMED 0)."""

FRD = np.array([1.0, -1.0, -1.0])
TYPES = ("IMU", "RCOU", "EV", "ARM", "RATE", "CTUN", "NKF1", "XKF1", "ATT", "MSG", "VER", "PARM")


def _import_dfreader():
    try:
        from pymavlink import DFReader
    except ImportError:
        raise ImportError('reading ArduPilot DataFlash logs needs pymavlink: pip install -e ".[ardupilot]" '
                          "(or pip install pymavlink)") from None
    return DFReader


def sniff(head: bytes) -> bool:
    """Is ``head`` (a file's first bytes) a DataFlash binary log? (:mod:`mjxsysid.logs.formats`)"""
    return head[:3] == MAGIC


FORMAT_DTYPES = {"a": ("<i2", (32,)), "b": "i1", "B": "u1", "g": "<f2", "h": "<i2", "H": "<u2", "i": "<i4",
                 "I": "<u4", "f": "<f4", "d": "<f8", "n": "S4", "N": "S16", "Z": "S64", "c": "<i2", "C": "<u2",
                 "e": "<i4", "E": "<u4", "L": "<i4", "M": "i1", "q": "<i8", "Q": "<u8"}
"""DataFlash format characters -> numpy dtypes (pymavlink's ``FORMAT_TO_STRUCT``)."""

FORMAT_SCALES = {"c": 0.01, "C": 0.01, "e": 0.01, "E": 0.01, "L": 1e-7}
"""Format characters stored scaled: the value is the integer times this (as pymavlink reads them)."""

FMT_TYPE, FMT_SIZE = 128, 89
"""The FMT record's type and size (header, Type, Length, Name[4], Format[16], Columns[64])."""


def _fmt_dtype(fmt: str, columns: list[str]):
    """The packed record dtype (after the 3-byte header) of a FMT's format and columns, or None when unknown."""
    if any(c not in FORMAT_DTYPES for c in fmt) or len(columns) != len(fmt) or len(set(columns)) != len(columns):
        return None
    return np.dtype([(n, FORMAT_DTYPES[c]) for n, c in zip(columns, fmt)])


def _formats(buf, cand, kind):
    """{type: (name, format, dtype)} of the FMT records among the record starts ``cand`` (their types
    ``kind``); None when a type is declared twice with different layouts (left to pymavlink)."""
    out = {}
    for p in cand[(kind == FMT_TYPE) & (cand + FMT_SIZE <= len(buf))]:
        rec = bytes(buf[p + 3:p + FMT_SIZE])
        typ, length = rec[0], rec[1]
        try:
            name, fmt, cols = (rec[a:b].split(b"\0")[0].decode("ascii") for a, b in ((2, 6), (6, 22), (22, 86)))
        except UnicodeDecodeError:
            continue
        dt = _fmt_dtype(fmt, cols.split(",")) if cols else np.dtype([])
        if dt is None or dt.itemsize + 3 != length:
            continue
        if typ in out and out[typ][1:] != (fmt, dt):
            return None
        out[typ] = (name, fmt, dt)
    return out


def _chain(cand, nxt):
    """Indices into ``cand`` of the records chained from the first (each record's end is the next one's start)
    -> (indices, where the chain stopped)."""
    j = np.searchsorted(cand, nxt)
    ok = j < len(cand)
    ok[ok] = cand[j[ok]] == nxt[ok]
    step = np.where(ok, j, -1).tolist()
    out, i = [], 0
    while i >= 0:
        out.append(i)
        i = step[i]
    return np.asarray(out, np.int64), int(nxt[out[-1]])


def parse_records(data: bytes, types=None) -> dict | None:
    """The records of a DataFlash log ``data`` with numpy -> {type name: {column: (N,) array}} for the
    names in ``types`` (all when None; strings as str object arrays, scaled format characters as floats),
    or None when its records do not chain from the first byte to the end (a damaged log: pymavlink reads
    it). A last record cut short is dropped."""
    buf = np.frombuffer(data, np.uint8)
    if len(buf) < FMT_SIZE:
        return None
    cand = np.flatnonzero((buf[:-2] == 0xA3) & (buf[1:-1] == 0x95))
    kind = buf[np.minimum(cand + 2, len(buf) - 1)]
    fmts = _formats(buf, cand, kind)
    if not fmts or cand[0] != 0:
        return None
    size = np.zeros(256, np.int64)
    for typ, (_, _, dt) in fmts.items():
        size[typ] = dt.itemsize + 3
    known = size[kind] > 0
    cand, kind = cand[known], kind[known]
    chain, stop = _chain(cand, cand + size[kind])
    if stop > len(buf):                                   # the last record cut short
        chain = chain[:-1]
        stop = int(cand[chain[-1]] + size[kind[chain[-1]]]) if len(chain) else 0
    if len(buf) - stop >= 3:                             # bytes left the chain does not reach
        return None
    offs, kind = cand[chain], kind[chain]
    out = {}
    for typ, (name, fmt, dt) in fmts.items():
        if types is not None and name not in types:
            continue
        o = offs[kind == typ] + 3
        if not len(o):
            continue
        rows = gather(buf, o, dt)
        cols = {}
        for c, n in zip(fmt, dt.names):
            v = rows[n]
            if v.dtype.kind == "S":
                v = np.asarray([x.split(b"\0")[0].decode("utf-8", "replace") for x in v.tolist()], object)
            elif c in FORMAT_SCALES:
                v = v.astype(np.float64) * FORMAT_SCALES[c]
            cols[n] = np.asarray(v)
        out[name] = cols
    return out


def _params(msgs: dict) -> dict:
    """{name: value} of the PARM records (the last value of a parameter set twice)."""
    parm = msgs.get("PARM", {})
    return {str(k): float(v) for k, v in zip(parm.get("Name", []), parm.get("Value", []))}


def _messages(df) -> dict:
    """{type: {column: (N,) array}} of the :data:`TYPES` in the log (strings kept as object arrays)."""
    rows: dict = {}
    while True:
        m = df.recv_match(type=list(TYPES))
        if m is None:
            break
        rows.setdefault(m.get_type(), []).append(m.to_dict())
    out = {}
    for typ, recs in rows.items():
        cols = [c for c in recs[0] if c != "mavpackettype"]
        out[typ] = {c: np.asarray([r.get(c) for r in recs]) for c in cols}
    return out


def _seconds(msg: dict):
    """Boot time (N,) s of a message's records: TimeUS (µs) or TimeMS (ms, old logs)."""
    if "TimeUS" in msg:
        return np.asarray(msg["TimeUS"], np.float64) * 1e-6
    return np.asarray(msg["TimeMS"], np.float64) * 1e-3


def _instance(msg: dict, field: str) -> dict:
    """The records of instance 0 (``field`` 'I' for sensors, 'C' for EKF cores) where the log has one."""
    if msg is None or field not in msg:
        return msg
    keep = np.asarray(msg[field]) == 0
    return {k: v[keep] for k, v in msg.items()}


def firmware(msgs: dict) -> tuple[str, tuple[int, int] | None]:
    """The firmware line of the log's MSG records (e.g. 'APM:Copter V3.4-rc2 (f46a31d0)') and its
    (major, minor) version, or ('', None). ValueError for a vehicle other than a copter."""
    for text in msgs.get("MSG", {}).get("Message", []):
        text = str(text)
        for other in ("Plane", "Rover", "Sub", "Tracker", "Blimp", "Heli"):
            if re.search(rf"\b(Ardu)?{other}\b|APM:{other}", text):
                raise ValueError(f"the log is of Ardu{other} ({text!r}): mjxsysid models a quad-X multicopter only")
        m = re.search(r"Copter V(\d+)\.(\d+)", text)
        if m:
            return text, (int(m.group(1)), int(m.group(2)))
    ver = msgs.get("VER")
    if ver is not None and "Major" in ver:
        return "", (int(ver["Major"][0]), int(ver["Minor"][0]))
    return "", None


def check_frame(params: dict) -> str:
    """ValueError for a frame other than a quad-X (FRAME_CLASS/FRAME_TYPE from ArduCopter 3.5, FRAME
    before) -> the sentence saying what was checked."""
    if "FRAME_CLASS" in params:
        cls, typ = int(params["FRAME_CLASS"]), int(params.get("FRAME_TYPE", 1))
        if cls != 1:
            raise ValueError(f"FRAME_CLASS = {cls}: not a quad (1); mjxsysid models a quad-X only")
        if typ != 1:
            raise ValueError(f"FRAME_TYPE = {typ}: not the X frame (1; H, V, plus and the BetaFlight orders differ "
                             f"in motor positions or spin); mjxsysid models ArduPilot's quad-X only")
        return "airframe: FRAME_CLASS 1 (quad), FRAME_TYPE 1 (X)"
    if "FRAME" in params:
        if int(params["FRAME"]) != 1:
            raise ValueError(f"FRAME = {int(params['FRAME'])}: not the X frame (1); mjxsysid models a quad-X only")
        return "airframe: FRAME 1 (X; ArduCopter before 3.5)"
    return "airframe: the log has no FRAME_CLASS/FRAME_TYPE or FRAME parameter; a quad-X assumed"


def motor_channels(params: dict, version) -> tuple[list[int], str]:
    """RCOU channels (1-based) of ArduCopter motors 1..4 -> (channels, sentence): SERVOn_FUNCTION
    33..36 (ArduCopter ≥ 3.5), else output n drives motor n (the fixed mapping before 3.5).
    ValueError when SERVOn_FUNCTION is logged but does not assign motors 1..4."""
    funcs = {int(k[5:-9]): int(v) for k, v in params.items()
             if re.fullmatch(r"SERVO\d+_FUNCTION", k)}
    if funcs:
        chans = {f - 32: n for n, f in funcs.items() if 33 <= f <= 36}
        if sorted(chans) != [1, 2, 3, 4]:
            raise ValueError(f"SERVOn_FUNCTION assigns motors {sorted(chans)} (functions 33..36), not motors 1..4; "
                             f"check the log's SERVOn_FUNCTION parameters")
        extra = sorted(f - 32 for f in funcs.values() if 37 <= f <= 40)
        if extra:
            raise ValueError(f"SERVOn_FUNCTION drives motors {extra} beyond 4: mjxsysid models a quad-X only")
        ch = [chans[k] for k in (1, 2, 3, 4)]
        return ch, (f"motor outputs: RCOU C{ch[0]}, C{ch[1]}, C{ch[2]}, C{ch[3]} drive motors 1..4 "
                    f"(SERVOn_FUNCTION 33..36)")
    v = "" if version is None else f" (the log is of {version[0]}.{version[1]})"
    return [1, 2, 3, 4], (f"motor outputs: no SERVOn_FUNCTION parameters{v}: ArduCopter's fixed mapping before 3.5, "
                          f"RCOU C1..C4 drive motors 1..4")


def pwm_range(params: dict) -> tuple[float, float, str]:
    """Zero and full throttle in µs: MOT_PWM_MIN/MAX, else (both 0, or absent) RC3_MIN/MAX as ArduCopter
    does, else 1000/2000 -> (lo, hi, sentence)."""
    lo, hi = float(params.get("MOT_PWM_MIN", 0.0)), float(params.get("MOT_PWM_MAX", 0.0))
    if lo > 0 and hi > lo:
        return lo, hi, f"PWM range {lo:g}–{hi:g} µs (MOT_PWM_MIN/MAX)"
    if "RC3_MIN" in params and "RC3_MAX" in params and float(params["RC3_MAX"]) > float(params["RC3_MIN"]) > 0:
        lo, hi = float(params["RC3_MIN"]), float(params["RC3_MAX"])
        return lo, hi, (f"PWM range {lo:g}–{hi:g} µs (RC3_MIN/MAX: MOT_PWM_MIN/MAX are 0 or absent, as "
                        f"ArduCopter does)")
    return 1000.0, 2000.0, "PWM range 1000–2000 µs (no MOT_PWM_MIN/MAX or RC3_MIN/MAX in the log: assumed)"


def euler_to_matrix(roll, pitch, yaw):
    """Rotations (N, 3, 3) taking FRD body vectors to NED from ArduPilot's Euler angles (N,) rad
    (yaw-pitch-roll, Z-Y-X)."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.stack([np.stack([cp * cy, sr * sp * cy - cr * sy, cr * sp * cy + sr * sy], -1),
                     np.stack([cp * sy, sr * sp * sy + cr * cy, cr * sp * sy - sr * cy], -1),
                     np.stack([-sp, sr * cp, cr * cp], -1)], -2)


def armed_stretches(msgs: dict, t_imu) -> list[tuple[float, float]]:
    """[(t0, t1)] s the vehicle was armed: EV ARMED/DISARMED (or ARM ArmState) between the log's
    ends, split where the IMU stops for more than :data:`GAP_S` (the logger paused while disarmed)."""
    lo, hi = float(t_imu[0]), float(t_imu[-1])
    events = []
    if "ARM" in msgs and "ArmState" in msgs["ARM"]:
        events = [(t, bool(s)) for t, s in zip(_seconds(msgs["ARM"]), msgs["ARM"]["ArmState"])]
    elif "EV" in msgs:
        events = [(t, i == EV_ARMED) for t, i in zip(_seconds(msgs["EV"]), msgs["EV"]["Id"])
                  if i in (EV_ARMED, EV_DISARMED)]
    stretches, start = [], (lo if not events or not events[0][1] else None)
    for t, armed in sorted(events):
        if armed and start is None:
            start = t
        elif not armed and start is not None:
            stretches.append((start, t))
            start = None
    if start is not None:
        stretches.append((start, hi))
    out = []
    gaps = np.flatnonzero(np.diff(t_imu) > GAP_S)
    cuts = [lo] + [c for g in gaps for c in (float(t_imu[g]), float(t_imu[g + 1]))] + [hi]
    for a, b in stretches:
        for c0, c1 in zip(cuts[::2], cuts[1::2]):
            s0, s1 = max(a, c0), min(b, c1)
            if s1 > s0:
                out.append((s0, s1))
    return out


def read_dataflash(path, segment=None) -> dict:
    """Read an ArduCopter DataFlash log -> the log contract (:mod:`mjxsysid.logs.formats`) over the
    airborne part of its longest armed stretch (or ``segment`` 't0:t1', seconds of boot time).
    ValueError: not a DataFlash log, not a quad-X copter, IMU or RCOU missing, too short; ImportError
    without pymavlink for a damaged log (its records then read one by one)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    data = path.read_bytes()
    if not sniff(data[:3]):
        raise ValueError(f"{path}: not an ArduPilot DataFlash .bin log (no 0xA3 0x95 FMT header); "
                         f"a .log text dump must be converted back with mavlogdump or read as .bin")
    msgs = parse_records(data, TYPES)
    if msgs is not None:
        params = _params(msgs)
    else:
        DFReader = _import_dfreader()
        try:
            df = DFReader.DFReader_binary(str(path), zero_time_base=False)
            msgs = _messages(df)
        except Exception as e:  # pymavlink raises assorted errors on a damaged log
            raise ValueError(f"{path}: not a readable DataFlash log ({type(e).__name__}: {e}); "
                             f"check it opens in MAVExplorer or Mission Planner") from None
        params = dict(df.params)
    try:
        text, version = firmware(msgs)
        conv = [check_frame(params)]
        chans, said_chans = motor_channels(params, version)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    for need in ("IMU", "RCOU"):
        if need not in msgs:
            raise ValueError(f"{path}: no {need} messages; log them (LOG_BITMASK: IMU and RCOUT) to read this log")
    g = P.GRAVITY
    missing, types = [], {}

    # ---- IMU, FRD -> FLU
    imu = _instance(msgs["IMU"], "I")
    t_imu, x_imu = sorted_unique(_seconds(imu), np.stack([imu[k] for k in ("GyrX", "GyrY", "GyrZ", "AccX", "AccY",
                                                                          "AccZ")], -1))
    x_imu = x_imu * np.tile(FRD, 2)
    types["imu"] = "IMU (GyrX/Y/Z, AccX/Y/Z" + (", instance I 0)" if "I" in msgs["IMU"] else ")")
    conv.append("body frame: ArduPilot's FRD (x forward, y right, z down) to FLU (x forward, y left, z up): gyro, "
                "accelerometer and rate setpoint y and z negated; velocity rotated from NED into FRD then FLU")

    # ---- motors: PWM -> throttle -> Ω_cmd/Ω_max, ArduCopter order -> mjxsysid's
    rc = msgs["RCOU"]
    cols = [f"C{c}" if f"C{c}" in rc else f"Chan{c}" for c in chans]
    if any(c not in rc for c in cols):
        raise ValueError(f"{path}: RCOU has no {', '.join(c for c in cols if c not in rc)} (the motor outputs)")
    t_m, pwm = sorted_unique(_seconds(rc), np.stack([rc[c] for c in cols], -1))
    lo, hi, said_pwm = pwm_range(params)
    e = float(params.get("MOT_THST_EXPO", 0.65))
    u = np.clip((pwm - lo) / (hi - lo), 0.0, 1.0)
    rotor = throttle_to_rotor_speed(u, e)[:, [list(AP_QUADX_ORDER).index(j) for j in range(4)]]
    types["motor"] = f"RCOU ({', '.join(cols)})"
    conv += [said_chans, said_pwm,
             f"motor commands: throttle u = (pwm − {lo:g}) / ({hi:g} − {lo:g}) clipped to [0, 1]; ArduPilot's "
             f"thrust curve thrust ∝ (1 − e) u + e u² with MOT_THST_EXPO e = {e:g}"
             + ("" if "MOT_THST_EXPO" in params else " (absent: ArduCopter's default)")
             + " and thrust ∝ Ω²: Ω_cmd/Ω_max = √((1 − e) u + e u²) (MOT_SPIN_MIN/MAX not applied: the "
               "curve taken over the whole PWM range)",
             "rotor order: ArduCopter quad-X motors 1..4 are front-right, back-left, front-left, back-right; "
             "reordered to mjxsysid's"]

    # ---- segment: the airborne part of the longest armed stretch
    stretches = armed_stretches(msgs, t_imu)
    if stretches:
        a0, a1 = max(stretches, key=lambda s: s[1] - s[0])
        how = f"{'ARM' if 'ARM' in msgs else 'EV'} messages and logging gaps"
        within_why = (f"armed {a0:.2f}–{a1:.2f} s ({how}" + (f"; the longest of {len(stretches)} armed stretches)"
                                                               if len(stretches) > 1 else ")"))
    else:
        a0, a1, within_why = float(t_imu[0]), float(t_imu[-1]), "no armed stretch found: the whole log"
    t0, t1, why = pick_segment(path, segment, t_m, rotor, (float(t_imu[0]), float(t_imu[-1])), (a0, a1), within_why)

    # ---- commands
    channels = {"imu": (t_imu, x_imu, LINEAR), "motor": (t_m, rotor, HELD)}
    if "RATE" in msgs:
        rt = msgs["RATE"]
        t_w, w = sorted_unique(_seconds(rt), np.deg2rad(np.stack([rt["RDes"], rt["PDes"], rt["YDes"]], -1)) * FRD)
        channels["omega_cmd"] = (t_w, w, HELD)
        types["omega_cmd"] = "RATE (RDes, PDes, YDes)"
        conv.append("omega_cmd: RATE RDes/PDes/YDes, deg/s to rad/s, FRD to FLU")
    else:
        channels["omega_cmd"] = (t_imu, x_imu[:, :3], LINEAR)
        missing.append("omega_cmd")
        conv.append("omega_cmd: the log has no RATE messages: filled with the measured gyro (not a setpoint)")
    hover, said_h = _hover(msgs, params, t0, t1)
    if "CTUN" in msgs and "ThO" in msgs["CTUN"] and hover is not None:
        ct = msgs["CTUN"]
        t_T, thr = sorted_unique(_seconds(ct), np.asarray(ct["ThO"], np.float64))
        channels["a_cmd"] = (t_T, thr * g / hover, HELD)
        types["a_cmd"] = "CTUN (ThO)"
        conv.append(f"a_cmd: CTUN ThO (the collective throttle, ArduCopter's normalised thrust) × g / hover throttle "
                    f"({said_h}): m/s², g at hover")
    else:
        channels["a_cmd"] = (t_imu, x_imu[:, 5], LINEAR)
        missing.append("a_cmd")
        conv.append("a_cmd: the log has no CTUN ThO with a hover throttle: filled with the measured specific force "
                    "along body z (not a setpoint)")

    vel = _velocity(msgs, params)
    if vel is not None:
        t_v, v_body, said_v, typ_v = vel
        channels["velocity_body"] = (t_v, v_body, LINEAR)
        types["velocity_body"] = typ_v
        conv.append(said_v)
    else:
        missing.append("velocity_body")
    rates, gaps = native_rates(channels)

    rec = assemble(channels, t0, t1)
    rec["source"] = {
        "format": "ArduPilot DataFlash", "path": str(path), "firmware": text, "messages": types,
        "rates_hz": rates, "max_gap_s": gaps,
        "segment": {"t0": float(t0), "t1": float(t1), "why": why,
                    "clock": "seconds since the autopilot's boot (TimeUS)"},
        "conversions": conv, "missing": missing,
        "parameters": {k: float(params[k]) for k in ("MOT_THST_EXPO", "MOT_THST_HOVER", "MOT_PWM_MIN", "MOT_PWM_MAX",
                                                     "MOT_SPIN_MIN", "MOT_SPIN_MAX", "RC3_MIN", "RC3_MAX", "FRAME",
                                                     "FRAME_CLASS", "FRAME_TYPE") if k in params}}
    return rec


def _hover(msgs, params, t0, t1):
    """ArduCopter's hover throttle (normalised thrust at hover) -> (value or None, sentence): the median of
    CTUN ThH in the segment (learnt in flight), else MOT_THST_HOVER."""
    ct = msgs.get("CTUN")
    if ct is not None and "ThH" in ct:
        t, v = _seconds(ct), np.asarray(ct["ThH"], np.float64)
        ok = (t >= t0) & (t <= t1) & (v > 0.02) & (v < 1)
        if ok.any():
            val = float(np.median(v[ok]))
            return val, f"CTUN ThH, median of {int(ok.sum())} samples in the segment: {val:.4g}"
    if 0 < float(params.get("MOT_THST_HOVER", 0)) < 1:
        val = float(params["MOT_THST_HOVER"])
        return val, f"MOT_THST_HOVER = {val:.4g}"
    return None, ""


def _velocity(msgs, params):
    """EKF velocity NED (NKF1 or XKF1 VN/VE/VD, core 0) rotated into the body by ATT -> (t (N,), v (N, 3)
    m/s FLU, sentence, source) or None."""
    names = [n for n in ("XKF1", "NKF1") if n in msgs and "VN" in msgs[n]]
    if not names or "ATT" not in msgs:
        return None
    ekf = int(params.get("AHRS_EKF_TYPE", 0))
    name = "XKF1" if ekf == 3 and "XKF1" in names else ("NKF1" if "NKF1" in names else names[0])
    k = _instance(msgs[name], "C")
    t_v, v_ned = sorted_unique(_seconds(k), np.stack([k["VN"], k["VE"], k["VD"]], -1))
    att = msgs["ATT"]
    t_a, ang = sorted_unique(_seconds(att), np.deg2rad(np.stack([att["Roll"], att["Pitch"], att["Yaw"]], -1)))
    ang[:, 2] = np.unwrap(ang[:, 2])
    r, p, y = (np.interp(t_v, t_a, ang[:, i]) for i in range(3))
    v_body = body_velocity_from_world(v_ned, euler_to_matrix(r, p, y)) * FRD
    said = (f"velocity_body: {name} VN/VE/VD (EKF{3 if name == 'XKF1' else 2} NED, core 0) rotated into the body by "
            f"ATT Roll/Pitch/Yaw (interpolated to its times), FRD to FLU")
    return t_v, v_body, said, f"{name} (VN, VE, VD) + ATT (Roll, Pitch, Yaw)"


read = read_dataflash
