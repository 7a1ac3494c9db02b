"""Betaflight blackbox flight logs (``.BBL``/``.BFL``; the forks Indiflight and INAV) -> the log contract of
:mod:`mjxsysid.logs.formats`.

The format: ASCII header lines ``H name:value`` (firmware, ``acc_1G``, ``motorOutput``, the field
definitions with their predictors and encodings), then binary frames: intra (``I``) and inter (``P``)
frames of the main fields on one clock (``time``, µs), slow (``S``), GPS and event (``E``) frames.
One file may hold several logs, each starting with the header line ``H Product:Blackbox flight data
recorder by Nicholas Sherlock``. The frames are decoded by :mod:`mjxsysid.logs.blackbox_frames`; a log
whose header it does not plan is decoded by orangebox (``pip install -e ".[blackbox]"``, orangebox 0.4.0:
0.5.0's wheel does not install). This module converts them.

Fields used: ``time``, ``gyroADC[0..2]`` (deg/s × ``gyro_scale``, × 10 with ``blackbox_high_resolution``),
``accSmooth[0..2]`` (``acc_1G`` per g), ``motor[0..3]`` (the ESC command between ``motorOutput[0]``
and ``motorOutput[1]``), rate setpoints ``setpoint[0..2]`` (Betaflight 4) or ``gyroSp[0..2]``
(Indiflight), Indiflight's ``spfSp[2]`` (specific force setpoint, cm/s², FRD), ``omegaUnfiltered[0..3]`` (else ``omega``: rotor
speed, rad/s), ``vel[0..2]`` (cm/s, NED) and ``quat[0..3]`` (body FRD to NED, × 8127).

Frames as logged (measured on the samples against the quaternion's rates and the motors' regression,
shared/data/logs/formats/README.md): gyro and accelerometer are FLU (+roll right side down, +pitch nose
down, +yaw nose left, +1 g on z at hover); Indiflight's ``gyroSp``, ``spfSp`` and ``quat`` are FRD.
Motors M1 rear-right, M2 front-right, M3 rear-left, M4 front-left.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from mjxsysid import theta as P
from mjxsysid.logs import blackbox_frames
from mjxsysid.logs.record import rate_hz
from mjxsysid.logs.segment import airborne_segment
from mjxsysid.logs.grid import DT, MIN_ROWS, hold, interp_linear, user_segment, world_to_body

MAGIC = b"H Product:Blackbox flight data recorder by Nicholas Sherlock"
"""The first header line of every log in a blackbox file."""

BF_TO_MJX = (1, 3, 2, 0)
"""Betaflight motor index (0-based) driving each mjxsysid rotor (front-right M2, front-left M4,
back-left M3, back-right M1)."""

FLU_FROM_FRD = np.array([1.0, -1.0, -1.0])
"""FRD (x forward, y right, z down) to FLU: y and z negated."""

QUAT_SCALE = (127 << 6) - 1
"""Indiflight's unit float to signed VB scale (8127) of ``quat``."""

MAX_GAP_S = 1.0
"""s: a step of ``time`` backwards, or forward by more than this, breaks the log (garbage frames)."""


def sniff(head: bytes) -> bool:
    """Is ``head`` (a file's first bytes) the header of a blackbox log? (:mod:`mjxsysid.logs.formats`)"""
    return MAGIC in head


def log_starts(data: bytes) -> list[int]:
    """Byte offsets of the logs in a blackbox file's ``data`` (each starts with :data:`MAGIC`)."""
    out, i = [], data.find(MAGIC)
    while i >= 0:
        out.append(i)
        i = data.find(MAGIC, i + 1)
    return out


def pick_log(sizes, log_index=None):
    """The log to read of a file holding logs of ``sizes`` bytes -> (1-based index, sentence):
    ``log_index`` (1-based) or, when None, the largest. ValueError on an index out of range."""
    n = len(sizes)
    if log_index is not None:
        if not 1 <= int(log_index) <= n:
            raise ValueError(f"log_index {log_index}: the file holds {n} log(s), numbered 1..{n}")
        k = int(log_index)
        why = f"log {k} of {n} (log_index)"
    else:
        k = int(np.argmax(sizes)) + 1
        why = f"log {k} of {n}" + (" (the largest; log_index picks another)" if n > 1 else "")
    if n > 1:
        why += "; the file's logs: " + ", ".join(f"{i + 1}: {s / 1e6:.2f} MB" for i, s in enumerate(sizes))
    return k, why


def hex_float(v) -> float:
    """A header float written as its IEEE-754 bits (``0x3f800000`` -> 1.0); orangebox gives the integer."""
    if isinstance(v, str):
        v = int(v, 16) if v.lower().startswith("0x") else float(v)
    if isinstance(v, float):
        return v
    return struct.unpack("<f", struct.pack("<I", int(v) & 0xFFFFFFFF))[0]


def clean_run(time_us):
    """The longest run of frames whose ``time_us`` (N,) steps forward by at most :data:`MAX_GAP_S`
    -> (i0, i1) the frames [i0, i1) to keep (garbage frames at a log's start jump back or far ahead)."""
    d = np.diff(np.asarray(time_us, np.float64))
    breaks = np.flatnonzero((d <= 0) | (d > MAX_GAP_S * 1e6)) + 1
    edges = np.concatenate([[0], breaks, [len(time_us)]])
    k = int(np.argmax(np.diff(edges)))
    return int(edges[k]), int(edges[k + 1])


def gyro_deg_per_lsb(headers) -> tuple[float, str]:
    """deg/s per logged gyro unit: ``gyro_scale`` (a Cleanflight-family firmware writes deg/s per
    unit), / 10 with ``blackbox_high_resolution`` -> (scale, sentence)."""
    fw = str(headers.get("Firmware type", "Cleanflight"))
    if fw != "Cleanflight":
        raise ValueError(f"firmware type {fw!r}: only the Cleanflight family (Betaflight, INAV, Indiflight) "
                         f"logs gyro in deg/s; this log's gyro units are not supported")
    scale = hex_float(headers.get("gyro_scale", 0x3F800000))
    hi_res = int(headers.get("blackbox_high_resolution", 0) or 0)
    said = f"gyro_scale {scale:g} deg/s per unit"
    if hi_res:
        scale /= 10.0
        said += ", / 10 (blackbox_high_resolution)"
    return scale, said


def motor_limits(headers) -> tuple[float, float, str]:
    """The ESC command at zero and full throttle: ``motorOutput`` (DShot: idle with the digital idle
    offset, and 2047), else minthrottle/maxthrottle -> (lo, hi, sentence)."""
    mo = headers.get("motorOutput")
    if isinstance(mo, list) and len(mo) == 2:
        lo, hi, src = float(mo[0]), float(mo[1]), "motorOutput"
    elif "minthrottle" in headers and "maxthrottle" in headers:
        lo, hi, src = float(headers["minthrottle"]), float(headers["maxthrottle"]), "minthrottle/maxthrottle"
    else:
        raise ValueError("no motorOutput (nor minthrottle/maxthrottle) header: the motor command's range is unknown")
    if not hi > lo:
        raise ValueError(f"{src} {lo:g}–{hi:g}: the maximum is not above the minimum")
    return lo, hi, src


def rotor_command(motor, lo: float, hi: float):
    """Ω_cmd/Ω_max (N, 4) in mjxsysid's order from Betaflight's motor commands ``motor`` (N, 4)
    (M1..M4): throttle = (motor − lo) / (hi − lo) clipped to [0, 1], thrust ∝ throttle and ∝ Ω², so
    Ω_cmd/Ω_max = √throttle."""
    u = np.clip((np.asarray(motor, np.float64) - lo) / (hi - lo), 0.0, 1.0)
    return np.sqrt(u)[:, list(BF_TO_MJX)]


def _import_orangebox():
    try:
        from orangebox import Parser
        from orangebox.types import FrameType
    except ImportError:
        raise ImportError('reading blackbox logs needs orangebox: pip install -e ".[blackbox]" '
                          "(or pip install orangebox==0.4.0)") from None
    return Parser, FrameType.INTRA


def _decode(path: Path, index: int, data: bytes, starts: list[int]):
    """The headers, main field names and main frames (N, F) int64 of log ``index`` (1-based) of the
    file's bytes ``data`` whose logs start at ``starts``."""
    end = starts[index] if index < len(starts) else len(data)
    try:
        headers, main, frames = blackbox_frames.decode_frames(data, starts[index - 1], end)
    except blackbox_frames.Unsupported:
        headers, main, frames = _decode_orangebox(path, index)
    if not len(frames):
        raise ValueError(f"{path}: log {index} has no frames (armed and disarmed without logging?); "
                         f"try another log_index")
    return headers, main, np.asarray(frames, np.int64)


def _decode_orangebox(path: Path, index: int):
    """:func:`_decode` by orangebox."""
    Parser, intra = _import_orangebox()
    try:
        parser = Parser.load(str(path), log_index=index)
        main = [f.name for f in parser.reader.field_defs[intra]]
        rows = [fr.data[:len(main)] for fr in parser.frames()]
    except Exception as e:  # orangebox raises assorted errors on a damaged file
        raise ValueError(f"{path}: log {index} is not a readable blackbox log ({type(e).__name__}: {e}); "
                         f"check the file is complete (not truncated by a power cut) or try another log_index") from None
    return dict(parser.headers), main, rows


def _columns(frames, names, stem, n, path, scale=1.0):
    """Fields ``stem[0..n-1]`` of ``frames`` (N, F) as float (N, n) × ``scale``; ValueError when absent."""
    want = [f"{stem}[{i}]" for i in range(n)]
    missing = [w for w in want if w not in names]
    if missing:
        raise ValueError(f"{path}: no {', '.join(missing)} field in the log (fields: {', '.join(names[:40])}"
                         f"{', …' if len(names) > 40 else ''}); enable it in the blackbox settings")
    return frames[:, [names.index(w) for w in want]].astype(np.float64) * scale


def _segment(t, rotor, segment, path):
    """(t0, t1, why) in seconds since the log's first kept frame."""
    given = user_segment(path, segment, float(t[0]), float(t[-1]))
    if given is not None:
        return given
    try:
        return airborne_segment(t, rotor)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None


def read_blackbox(path, segment=None, log_index=None) -> dict:
    """Read a Betaflight / Indiflight / INAV blackbox log -> the log contract of
    :mod:`mjxsysid.logs.formats` (t (T,) s since the log's first valid frame, imu (T, 6), a_cmd (T,),
    omega_cmd (T, 3), motor (T, 4), and with Indiflight's fields rotor_speed (T, 4) rad/s and
    velocity_body (T, 3) m/s) on a 2 ms grid over the airborne segment (or ``segment`` 't0:t1').

    ``log_index`` (1-based) picks one of several logs in the file; the largest (in bytes, the longest
    at one logging rate) by default. Frames
    before the longest run of monotonic time (garbage at a log's start) are dropped. ValueError: not
    a readable blackbox log, a field missing, not four motors, a segment too short; ImportError
    without orangebox (``pip install -e ".[blackbox]"``) for a header the project's own decoder
    does not plan (:mod:`.blackbox_frames`)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    data = path.read_bytes()
    starts = log_starts(data)
    if not starts:
        raise ValueError(f"{path}: not a blackbox log (no '{MAGIC.decode()}' header line); "
                         f"give a .BBL/.BFL file as written by the flight controller")
    sizes = np.diff(starts + [len(data)])
    index, said_log = pick_log(sizes, log_index)
    headers, names, frames = _decode(path, index, data, starts)
    conv = [f"blackbox {said_log}; firmware {headers.get('Firmware revision', 'unknown')}"]
    if "motor[4]" in names:
        raise ValueError(f"{path}: the log has motor[4]: more than four motors; mjxsysid models a quad-X only")
    if "time" not in names:
        raise ValueError(f"{path}: no time field in the log's main frames")

    i0, i1 = clean_run(frames[:, names.index("time")])
    if i1 - i0 < len(frames):
        conv.append(f"frames: {len(frames) - (i1 - i0)} of {len(frames)} dropped outside the longest run of "
                    f"monotonic time (steps ≤ {MAX_GAP_S:g} s; garbage frames at a log's start)")
    frames = frames[i0:i1]
    t = (frames[:, names.index("time")] - frames[0, names.index("time")]) * 1e-6
    rate = rate_hz(t)
    g = P.GRAVITY

    deg, said_g = gyro_deg_per_lsb(headers)
    gyro = _columns(frames, names, "gyroADC", 3, path, deg * np.pi / 180.0)
    if "acc_1G" not in headers:
        raise ValueError(f"{path}: no acc_1G header: the accelerometer's scale is unknown")
    acc_1g = float(headers["acc_1G"])
    acc = _columns(frames, names, "accSmooth", 3, path, g / acc_1g)
    conv.append(f"IMU: gyroADC ({said_g}) to rad/s, accSmooth / acc_1G ({acc_1g:g}) × {g} m/s²; both logged in "
                f"FLU already (+roll right side down, +pitch nose down, +yaw nose left, +1 g on z at hover): "
                f"no axis changed")

    lo, hi, src = motor_limits(headers)
    rotor = rotor_command(_columns(frames, names, "motor", 4, path), lo, hi)
    conv.append(f"motor commands: throttle = (motor − {lo:g}) / ({hi:g} − {lo:g}) ({src}: DShot idle with the "
                f"digital idle offset, and full), clipped to [0, 1]; thrust ∝ throttle and ∝ Ω², so "
                f"Ω_cmd/Ω_max = √throttle")
    if int(headers.get("yaw_motors_reversed", 0) or 0):
        raise ValueError(f"{path}: yaw_motors_reversed = 1 (props out): the rotors spin opposite to mjxsysid's "
                         f"quad-X (Betaflight's default props in); this layout is not supported")
    conv.append("rotor order: Betaflight M1 rear-right, M2 front-right, M3 rear-left, M4 front-left to mjxsysid's "
                "front-right (M2), front-left (M4), back-left (M3), back-right (M1); props in (Betaflight's default, "
                "no yaw_motors_reversed) spin as mjxsysid's rotors")

    native_all = {"imu": np.concatenate([gyro, acc], -1), "motor": rotor}
    missing = []
    hr = 10.0 if int(headers.get("blackbox_high_resolution", 0) or 0) else 1.0
    if "gyroSp[0]" in names:
        native_all["omega_cmd"] = _columns(frames, names, "gyroSp", 3, path, np.pi / 180.0 / hr) * FLU_FROM_FRD
        conv.append(f"omega_cmd: Indiflight's rate setpoint gyroSp (deg/s{' × 10' if hr > 1 else ''}, FRD: its pitch "
                    f"and yaw run against the gyro's) to rad/s FLU, y and z negated")
    elif "setpoint[0]" in names:
        native_all["omega_cmd"] = _columns(frames, names, "setpoint", 3, path, np.pi / 180.0 / hr)
        conv.append(f"omega_cmd: Betaflight's rate setpoint setpoint[0..2] (deg/s{' × 10' if hr > 1 else ''}, "
                    f"the gyro's axes) to rad/s")
    else:
        native_all["omega_cmd"] = gyro
        missing.append("omega_cmd")
        conv.append("omega_cmd: the log has no rate setpoint (setpoint or gyroSp; rcCommand is stick deflection, "
                    "not a rate): filled with the measured gyro")
    if "spfSp[2]" in names:
        native_all["a_cmd"] = -_columns(frames, names, "spfSp", 3, path, 0.01)[:, 2]
        conv.append("a_cmd: Indiflight's specific force setpoint −spfSp[2] (cm/s², FRD z down) to m/s² up")
    else:
        native_all["a_cmd"] = acc[:, 2]
        missing.append("a_cmd")
        conv.append("a_cmd: the log has no thrust setpoint: filled with the measured specific force along z")
    speed_field = next((f for f in ("omegaUnfiltered", "omega") if f"{f}[0]" in names), None)
    if speed_field is not None:     # omega is low-pass filtered on board: its lag reads as ~16 ms more τ_m
        native_all["rotor_speed"] = _columns(frames, names, speed_field, 4, path)[:, list(BF_TO_MJX)]
        conv.append(f"rotor_speed: Indiflight's {speed_field}[0..3] (rad/s from the ESCs' eRPM"
                    f"{'' if speed_field == 'omega' else '; not omega, which is filtered on board'}), reordered as the motors")
    if "vel[0]" in names and "quat[0]" in names:
        v_ned = _columns(frames, names, "vel", 3, path, 0.01)
        q = _columns(frames, names, "quat", 4, path, 1.0 / QUAT_SCALE)
        native_all["velocity_body"] = world_to_body(q, v_ned) * FLU_FROM_FRD
        conv.append("velocity_body: Indiflight's vel (cm/s, NED) to m/s, rotated into the body by quat "
                    "(/ 8127, body FRD to NED), FRD to FLU (y and z negated)")

    t0, t1, why = _segment(t, rotor, segment, path)
    n = int(np.floor((t1 - t0) / DT + 1e-9)) + 1
    if n < MIN_ROWS:
        raise ValueError(f"{path}: the segment {t0:.3f}–{t1:.3f} s is shorter than {MIN_ROWS * DT:g} s")
    grid = t0 + DT * np.arange(n)
    j0 = max(int(np.searchsorted(t, t0, side="right")) - 1, 0)
    j1 = min(int(np.searchsorted(t, t1, side="left")) + 1, len(t))
    native = {k: (t[j0:j1], v[j0:j1]) for k, v in native_all.items()}
    on_grid = abs(rate * DT - 1) <= 0.05                  # within 5 % of 500 Hz: read as the grid's own samples
    rate_txt = f"{rate:.0f} Hz"
    rec = {"t": grid}
    resampled = {}
    for k, (tn, xn) in native.items():
        linear = k in ("imu", "rotor_speed", "velocity_body") or k in missing   # filled from the IMU: as the IMU
        rec[k] = (interp_linear if linear else hold)(tn, xn, grid)
        resampled[k] = (f"native ({rate_txt})" if on_grid else
                        f"{'interpolated (linear)' if linear else 'held (zero-order)'} from {rate_txt}")
    rec["native"] = native
    rec["resampled"] = resampled
    rec["source"] = {"format": "Betaflight blackbox", "path": str(path), "log_index": index,
                     "rates_hz": {k: round(rate, 2) for k in native},
                     "segment": {"t0": float(t0), "t1": float(t1), "why": why,
                                 "clock": "seconds since the log's first valid frame"},
                     "conversions": conv, "missing": missing,
                     "headers": {k: headers[k] for k in ("Firmware revision", "Craft name", "motorOutput", "acc_1G",
                                                         "blackbox_high_resolution", "motor_poles", "dshot_bidir")
                                 if k in headers}}
    return rec


read = read_blackbox
