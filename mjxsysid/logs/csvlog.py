"""Flight-log CSV files: read (every problem named by line and column), write, and any log by its
suffix (a PX4 ULog: :mod:`mjxsysid.logs.ulog`).

One row per control step at 500 Hz, header required::

    t, gyro_x, gyro_y, gyro_z, acc_x, acc_y, acc_z, a_cmd, omega_cmd_x, omega_cmd_y, omega_cmd_z,
    motor_1, motor_2, motor_3, motor_4

SI units, body frame x forward / y left / z up: gyro (rad/s), specific force acc (m/s², ≈ +9.81
on z at hover), commanded mass-normalised collective thrust a_cmd (m/s²) and body rates (rad/s),
motor commands Ω_cmd/Ω_max ∈ [0, 1] in mjxsysid's rotor order (1 front-right, 2 front-left,
3 back-left, 4 back-right). Optional, all three or none: ``vel_body_x, vel_body_y, vel_body_z`` the
velocity in the body frame (m/s, same frame; a state estimate's), read as ``velocity_body``. The policy's history is rebuilt from the logged IMU, commands and
motor commands (the logged motor commands stand in for the policy's actions).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


LOG_COLUMNS = ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z", "a_cmd", "omega_cmd_x",
               "omega_cmd_y", "omega_cmd_z", "motor_1", "motor_2", "motor_3", "motor_4")
"""The columns every log has (in this order when written)."""

VELOCITY_COLUMNS = ("vel_body_x", "vel_body_y", "vel_body_z")
"""Optional, all three or none: the velocity in the body frame (m/s, FLU), read as ``velocity_body`` (T, 3)."""

LOG_DT = 0.002  # s: the policies run at 500 Hz; a log's rows must be 500 Hz steps

MIN_ROWS = 100
"""Rows a log needs at least: the policy's 0.2 s history at 500 Hz (the policy's ``HISTORY``; the
logs room imports nothing from the policy, a test checks the two agree)."""


def read_log(path) -> dict:
    """Read a flight-log CSV -> dict of arrays (imu (T, 6), a_cmd (T,), omega_cmd (T, 3),
    motor (T, 4), t (T,); velocity_body (T, 3) when the log has :data:`VELOCITY_COLUMNS`).

    The whole file is checked before anything is returned; ``ValueError`` names the file and
    the line/column of the first problem: not UTF-8 text, empty, a delimiter other than ``,``,
    missing or repeated columns (other extra columns are ignored), a row with the wrong number
    of values, a non-numeric or non-finite cell, some of :data:`VELOCITY_COLUMNS` without the others, fewer than 100 rows (0.2 s), time not strictly
    increasing or not sampled at 500 Hz (median step within 5 % of 2 ms), motor commands
    outside [0, 1]. Line numbers count the header as line 1; blank lines are skipped."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"flight log not found: {path}")
    check_log_fits(path)
    fast = _read_log_fast(path)
    if fast is not None:
        return fast
    # The careful parser: slower, and it names the line and column of the first problem.
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a text (UTF-8) CSV file") from None
    lines = [(i + 1, ln) for i, ln in enumerate(text.splitlines()) if ln.strip()]
    if not lines:
        raise ValueError(f"{path}: empty file; expected a header line {','.join(LOG_COLUMNS)} and rows")
    hline, head = lines[0]
    for other, name in ((";", "semicolons"), ("\t", "tabs"), ("|", "'|'")):
        if other in head and head.count(other) >= head.count(","):
            raise ValueError(f"{path}: line {hline}: columns are separated by {name}; expected commas")
    header = [h.strip() for h in head.split(",")]
    if _is_number(header[0]):
        raise ValueError(f"{path}: line {hline}: no header line; expected {','.join(LOG_COLUMNS)}")
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise ValueError(f"{path}: line {hline}: column(s) {dup} appear more than once")
    missing = [c for c in LOG_COLUMNS if c not in header]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; expected {list(LOG_COLUMNS)}")
    names = LOG_COLUMNS + _velocity_columns(path, header, f"line {hline}: ")
    rows = lines[1:]
    if len(rows) < MIN_ROWS:
        raise ValueError(f"{path}: {len(rows)} rows; need at least {MIN_ROWS} (0.2 s at 500 Hz)")
    idx = [header.index(c) for c in names]
    data = np.empty((len(rows), len(names)), np.float64)
    for r, (ln, row) in enumerate(rows):
        cells = row.split(",")
        if len(cells) != len(header):
            hint = " (separated by semicolons?)" if ";" in row else " (separated by tabs?)" if "\t" in row else ""
            raise ValueError(f"{path}: line {ln}: {len(cells)} values, header has {len(header)}{hint}")
        for c, k in enumerate(idx):
            cell = cells[k].strip()
            try:
                v = float(cell)
            except ValueError:
                raise ValueError(f"{path}: line {ln}, column {names[c]}: {cell[:40]!r} is not a number") from None
            if not np.isfinite(v):
                raise ValueError(f"{path}: line {ln}, column {names[c]}: {cell!r} is not finite")
            data[r, c] = v
    col = {c: data[:, i] for i, c in enumerate(names)}
    dt = np.diff(col["t"])
    if np.any(dt <= 0):
        r = int(np.argmax(dt <= 0)) + 1
        raise ValueError(f"{path}: line {rows[r][0]}, column t: time {col['t'][r]:.6g} s does not increase "
                         f"(previous row {col['t'][r - 1]:.6g} s)")
    med = float(np.median(dt))
    if abs(med - LOG_DT) > 0.05 * LOG_DT:
        raise ValueError(f"{path}: column t: {time_step_problem(med)}")
    motor = np.stack([col[f"motor_{i}"] for i in range(1, 5)], -1)
    bad = np.argwhere((motor < -1e-6) | (motor > 1 + 1e-6))
    if bad.size:
        r, m = bad[0]
        raise ValueError(f"{path}: line {rows[r][0]}, column motor_{m + 1}: {motor[r, m]:.6g} is outside [0, 1]; "
                         f"{motor_range_problem(motor)}")
    f32 = {k: v.astype(np.float32) for k, v in col.items()}
    if not all(np.all(np.isfinite(v)) for v in f32.values()):
        c = next(k for k, v in f32.items() if not np.all(np.isfinite(v)))
        raise ValueError(f"{path}: column {c}: values too large (beyond float32)")
    return _record(col, motor)


def read_any_log(path, segment=None) -> dict:
    """A flight log of any known format, detected by its content (:mod:`mjxsysid.logs.formats`): a PX4
    ULog, a Crazyflie uSD log, a Betaflight blackbox, an ArduPilot DataFlash log, a ROS bag or a PX4 CSV table of
    data-driven-dynamics is
    read by its reader (cut at its airborne segment, or ``segment`` 't0:t1'), anything else as the
    CSV of :func:`read_log`, cut at its airborne segment (:func:`~mjxsysid.logs.segment.airborne_segment`
    on the motor commands: ground time, spin-up and landing) or at ``segment`` (rows with
    t0 ≤ t ≤ t1, t in the log's own clock), with ``native``, ``resampled`` and ``source`` as a
    reader's (every column group's rate measured from its samples: :func:`~mjxsysid.logs.checks.rates.measure_columns`)."""
    from mjxsysid.logs.formats import FORMATS, HEAD_BYTES, detect, reader
    fmt = detect(path)
    if fmt != "CSV":
        return reader(fmt)(path, segment)
    with open(path, "rb") as f:
        head = f.read(HEAD_BYTES)
    if not head:
        raise ValueError(f"{path}: empty file (0 bytes): no flight log in it")
    try:
        head.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        if e.start < len(head) - 4:                     # not a multi-byte character cut at the head's end
            raise ValueError(f"{path}: not a flight log mjxsysid reads: a binary file whose content matches none of "
                             f"{', '.join(n for n, *_ in FORMATS)}, and not a text CSV (docs/logs.md lists the "
                             f"formats; a damaged or truncated log of one of them may not be recognised)") from None
    return cut_csv(read_log(path), path, segment)


def cut_csv(rec: dict, path, segment=None) -> dict:
    """The arrays of :func:`read_log` cut at ``segment`` ('t0:t1' in the t column) or, when None, at
    the airborne segment, measured (native rates of every column group) and said (``source``)."""
    from mjxsysid.logs.checks.rates import measure_columns
    from mjxsysid.logs.segment import airborne_segment
    from mjxsysid.logs.grid import parse_segment
    t = rec["t"]
    seg = parse_segment(segment)
    if seg is None:
        try:
            t0, t1, why = airborne_segment(t, rec["motor"])
        except ValueError as e:
            raise ValueError(f"{path}: {e}") from None
    else:
        t0 = float(t[0]) if seg[0] is None else seg[0]
        t1 = float(t[-1]) if seg[1] is None else seg[1]
        why = "--segment (seconds in the log's t column)"
    keep = (t >= t0 - 1e-9) & (t <= t1 + 1e-9)
    if keep.sum() < MIN_ROWS:
        raise ValueError(f"{path}: segment {t0:.6g}–{t1:.6g} s: {int(keep.sum())} rows in it (the log runs "
                         f"{t[0]:.6g}–{t[-1]:.6g} s); need at least {MIN_ROWS}: give a longer --segment T0:T1")
    rec = {k: v[keep] for k, v in rec.items()}
    native, resampled, rates = measure_columns(rec)
    rec["native"], rec["resampled"] = native, resampled
    rec["source"] = {"format": "CSV", "path": str(path), "rates_hz": rates,
                     "segment": {"t0": float(rec["t"][0]), "t1": float(rec["t"][-1]), "why": why,
                                 "clock": "the log's t column (s)"},
                     "missing": [] if "velocity_body" in rec else ["velocity_body"],
                     "conversions": ["none: the CSV is the log contract (SI units, body frame FLU, Ω_cmd/Ω_max in "
                                     "mjxsysid's rotor order; docs/decoding.md)"]}
    return rec


def time_step_problem(median_dt: float) -> str:
    """What a log's median time step ``median_dt`` (in the log's unit) says, when it is not
    2 ms in seconds: the unit (ms, µs, ns) or another rate, and the fix."""
    for scale, unit in ((1e3, "milliseconds"), (1e6, "microseconds"), (1e9, "nanoseconds")):
        if abs(median_dt - LOG_DT * scale) <= 0.05 * LOG_DT * scale:
            return (f"rows are {median_dt:.4g} apart (median): time looks like {unit}, not seconds "
                    f"(divide t by {scale:g}); the rows themselves are 500 Hz steps")
    return (f"rows are {median_dt * 1e3:.4g} ms apart (median), {1 / median_dt:.4g} Hz; the policy acts at 500 Hz "
            f"and its 0.2 s history is 100 steps of 2 ms: log every step the policy acted on, one row each "
            f"(resampling a log of another rate does not give the inputs the policy saw)")


def motor_range_problem(motor) -> str:
    """Why motor columns (T, 4) outside [0, 1] are not normalised rotor-speed commands, and the
    fix (docs/decoding.md, 'Converting autopilot outputs')."""
    lo, hi = float(np.min(motor)), float(np.max(motor))
    if 800 <= lo and hi <= 2200:
        why = (f"values {lo:.4g}–{hi:.4g} look like PWM pulse widths in µs: throttle = (pwm − 1000) / 1000, "
               f"then Ω_cmd/Ω_max = √throttle for an ESC whose thrust is linear in throttle")
    elif lo >= 0 and hi <= 100:
        why = f"values {lo:.4g}–{hi:.4g} look like percent: divide by 100 (and see the throttle conversion)"
    elif lo >= 0 and hi > 100:
        why = (f"values {lo:.4g}–{hi:.4g} look like rotor speeds (RPM or rad/s): divide by the maximum rotor "
               f"speed in the same unit")
    else:
        why = (f"values {lo:.4g}–{hi:.4g} are signed: these look like body rates, torques or another signed "
               f"quantity, not rotor-speed commands")
    return f"{why}. Motor commands are normalised Ω_cmd/Ω_max in [0, 1] (docs/decoding.md, 'Converting autopilot outputs')"


def _record(col: dict, motor) -> dict:
    """Columns by name (T,) and the motor commands (T, 4) -> the arrays of :func:`read_log`."""
    rec = {"t": col["t"], "imu": np.stack([col[c] for c in LOG_COLUMNS[1:7]], -1),
           "a_cmd": col["a_cmd"], "omega_cmd": np.stack([col[c] for c in LOG_COLUMNS[8:11]], -1),
           "motor": motor}
    if all(c in col for c in VELOCITY_COLUMNS):
        rec["velocity_body"] = np.stack([col[c] for c in VELOCITY_COLUMNS], -1)
    return rec


def _velocity_columns(path, header, where: str = "") -> tuple:
    """:data:`VELOCITY_COLUMNS` when the header has all three, () when none; ValueError naming the
    missing ones when it has some."""
    have = [c for c in VELOCITY_COLUMNS if c in header]
    if not have:
        return ()
    if len(have) < len(VELOCITY_COLUMNS):
        lack = [c for c in VELOCITY_COLUMNS if c not in header]
        raise ValueError(f"{path}: {where}velocity column(s) {lack} missing: the body-frame velocity needs all of "
                         f"{list(VELOCITY_COLUMNS)} (or none), has only {have}")
    return VELOCITY_COLUMNS


LOG_MEMORY_FACTOR = 6.0
"""Memory budgeted for decoding a log, bytes per byte of CSV. Measured (benchmarks/decode_long_log.py):
1.5 GB peak for a 283 MB one-hour log, of which about 0.9 GB is the fixed cost of JAX and the
decoders (≈ 2 bytes per byte on top): 6 leaves a wide margin."""


def available_memory() -> int | None:
    """Bytes of memory available to this process now (Linux: MemAvailable), or None if unknown."""
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def check_log_fits(path) -> None:
    """A log too large to decode on this machine is a one-line error naming the limit, before
    anything is read."""
    size = Path(path).stat().st_size
    avail = available_memory()
    need = LOG_MEMORY_FACTOR * size
    if avail is not None and need > avail:
        raise ValueError(f"{path}: a {size / 1e9:.2f} GB log needs about {need / 1e9:.1f} GB of memory to decode, "
                         f"{avail / 1e9:.1f} GB are available: split the log (rows are independent 2 ms steps) "
                         f"or decode it on a larger machine")


def _read_log_fast(path: Path) -> dict | None:
    """The common case in one vectorised pass (numpy's C parser): a clean log -> the arrays of
    :func:`read_log`; anything unusual -> None (the careful parser then finds and names it)."""
    try:
        with open(path, encoding="utf-8-sig") as f:
            head = f.readline()
            header = [h.strip() for h in head.split(",")]
            if (len(header) < len(LOG_COLUMNS) or sorted(set(header)) != sorted(header)
                    or any(c not in header for c in LOG_COLUMNS)
                    or 0 < sum(c in header for c in VELOCITY_COLUMNS) < len(VELOCITY_COLUMNS)):
                return None
            data = np.loadtxt(f, delimiter=",", dtype=np.float64, ndmin=2)
    except (ValueError, UnicodeDecodeError, OSError):
        return None
    if data.shape[1] != len(header) or data.shape[0] < MIN_ROWS or not np.isfinite(data).all():
        return None
    col = {c: data[:, header.index(c)] for c in LOG_COLUMNS + VELOCITY_COLUMNS if c in header}
    dt = np.diff(col["t"])
    motor = np.stack([col[f"motor_{i}"] for i in range(1, 5)], -1)
    if (np.any(dt <= 0) or abs(float(np.median(dt)) - LOG_DT) > 0.05 * LOG_DT
            or np.any((motor < -1e-6) | (motor > 1 + 1e-6)) or np.abs(data).max() > np.finfo(np.float32).max):
        return None
    return _record(col, motor)


def _is_number(text: str) -> bool:
    try:
        float(text)
        return True
    except ValueError:
        return False


def write_log(path, t, imu, a_cmd, omega_cmd, motor, velocity_body=None) -> Path:
    """Write a flight log in the documented CSV format (time with 15 significant digits: boot-time
    stamps keep their 2 ms steps; the other columns 7, float32's precision); ``velocity_body``
    (T, 3) m/s FLU, when given, as :data:`VELOCITY_COLUMNS` after the others."""
    parts, names = [t, imu, a_cmd, omega_cmd, motor], LOG_COLUMNS
    if velocity_body is not None:
        parts, names = parts + [np.asarray(velocity_body, np.float64).reshape(len(t), 3)], names + VELOCITY_COLUMNS
    arr = np.column_stack(parts)
    np.savetxt(path, arr, delimiter=",", header=",".join(names), comments="",
               fmt=["%.15g"] + ["%.7g"] * (arr.shape[1] - 1))
    return Path(path)
