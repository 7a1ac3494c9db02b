"""`mjxsysid decode`: fly (or replay) a vehicle with the frozen policy, read its latent ẑ at a
given rate and decode each into a distribution of physical models.

Flight-log CSV format (``--log``), one row per control step at 500 Hz, header required::

    t, gyro_x, gyro_y, gyro_z, acc_x, acc_y, acc_z, a_cmd, omega_cmd_x, omega_cmd_y, omega_cmd_z,
    motor_1, motor_2, motor_3, motor_4

SI units, body frame x forward / y left / z up: gyro (rad/s), specific force acc (m/s², ≈ +9.81
on z at hover), commanded mass-normalised collective thrust a_cmd (m/s²) and body rates (rad/s),
motor commands Ω_cmd/Ω_max ∈ [0, 1] in mjxsysid's rotor order (1 front-right, 2 front-left,
3 back-left, 4 back-right). The policy's history is rebuilt from the logged IMU, commands and
motor commands (the logged motor commands stand in for the policy's actions).

Windows (``--window``): at each decode time t the flight-level posterior p(θ | ẑ over a window)
comes from the sequence decoder (``cfm_seq.npz``) given the latents it was trained on (10 Hz,
from 0.2 s on) with times in the window: ``flight`` (default) everything flown so far
(0.2 s … t), ``SECONDS`` a sliding window (t − SECONDS, t]; ``instant`` is the single-latent
CFM p(θ | ẑ(t)) alone. The instant posterior is always computed too (``decoded.npz`` key
``samples``; the window's are ``samples_window``).
"""
from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
from mjxsysid.cfm.posterior import summarize_posterior
from mjxsysid.dataset.collect import decode_indices
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.progress import stages
from mjxsysid.render.posterior import plot_decoded_over_time, plot_information_gap, plot_marginals
from mjxsysid.render.video import render_rollout
from mjxsysid.rollout.flight import fly_vehicles, make_reference, one_flight, seen_imu
from mjxsysid.studies.logcheck import (LogError, check_log, check_replay, estimate_vehicle, imu_noise_limit,
                                       prior_check, warn)

LOG_COLUMNS = ("t", "gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z", "a_cmd", "omega_cmd_x",
               "omega_cmd_y", "omega_cmd_z", "motor_1", "motor_2", "motor_3", "motor_4")


LOG_DT = 0.002  # s: the policies run at 500 Hz; a log's rows must be 500 Hz steps


def read_log(path) -> dict:
    """Read a flight-log CSV -> dict of arrays (imu (T, 6), a_cmd (T,), omega_cmd (T, 3),
    motor (T, 4), t (T,)).

    The whole file is checked before anything is returned; ``ValueError`` names the file and
    the line/column of the first problem: not UTF-8 text, empty, a delimiter other than ``,``,
    missing or repeated columns (other extra columns are ignored), a row with the wrong number
    of values, a non-numeric or non-finite cell, fewer than 100 rows (0.2 s), time not strictly
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
    rows = lines[1:]
    if len(rows) < N.HISTORY:
        raise ValueError(f"{path}: {len(rows)} rows; need at least {N.HISTORY} (0.2 s at 500 Hz)")
    idx = [header.index(c) for c in LOG_COLUMNS]
    data = np.empty((len(rows), len(LOG_COLUMNS)), np.float64)
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
                raise ValueError(f"{path}: line {ln}, column {LOG_COLUMNS[c]}: {cell[:40]!r} is not a number") from None
            if not np.isfinite(v):
                raise ValueError(f"{path}: line {ln}, column {LOG_COLUMNS[c]}: {cell!r} is not finite")
            data[r, c] = v
    col = {c: data[:, i] for i, c in enumerate(LOG_COLUMNS)}
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
    """A flight log by its suffix: ``.ulg`` a PX4 ULog (:func:`~mjxsysid.logs.ulog.read_ulog`, cut
    at its armed, airborne segment or ``segment`` 't0:t1'), anything else the CSV of
    :func:`read_log` (``segment``: rows with t0 ≤ t ≤ t1, t in the log's own clock)."""
    if Path(path).suffix.lower() == ".ulg":
        from mjxsysid.logs.ulog import read_ulog
        return read_ulog(path, segment)
    rec = read_log(path)
    if segment is None:
        return rec
    from mjxsysid.logs.ulog import parse_segment
    t0, t1 = parse_segment(segment)
    keep = np.ones(len(rec["t"]), bool)
    if t0 is not None:
        keep &= rec["t"] >= t0
    if t1 is not None:
        keep &= rec["t"] <= t1
    if keep.sum() < N.HISTORY:
        raise ValueError(f"{path}: --segment {segment}: {int(keep.sum())} rows in it (the log runs "
                         f"{rec['t'][0]:.6g}–{rec['t'][-1]:.6g} s); need at least {N.HISTORY}")
    return {k: v[keep] for k, v in rec.items()}


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
    return {"t": col["t"], "imu": np.stack([col[c] for c in LOG_COLUMNS[1:7]], -1),
            "a_cmd": col["a_cmd"], "omega_cmd": np.stack([col[c] for c in LOG_COLUMNS[8:11]], -1),
            "motor": motor}


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
                    or any(c not in header for c in LOG_COLUMNS)):
                return None
            data = np.loadtxt(f, delimiter=",", dtype=np.float64, ndmin=2)
    except (ValueError, UnicodeDecodeError, OSError):
        return None
    if data.shape[1] != len(header) or data.shape[0] < N.HISTORY or not np.isfinite(data).all():
        return None
    col = {c: data[:, header.index(c)] for c in LOG_COLUMNS}
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


def write_log(path, t, imu, a_cmd, omega_cmd, motor) -> Path:
    """Write a flight log in the documented CSV format (time with 15 significant digits: boot-time
    stamps keep their 2 ms steps; the other columns 7, float32's precision)."""
    arr = np.column_stack([t, imu, a_cmd, omega_cmd, motor])
    np.savetxt(path, arr, delimiter=",", header=",".join(LOG_COLUMNS), comments="",
               fmt=["%.15g"] + ["%.7g"] * (arr.shape[1] - 1))
    return Path(path)


def parse_window(text):
    """``--window``: 'flight' (everything flown so far), 'instant' (one latent) or a number of
    seconds (> 0) of a sliding window. Returns 'flight', 'instant' or a float."""
    if isinstance(text, str) and text.strip().lower() in ("flight", "instant"):
        return text.strip().lower()
    try:
        w = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"--window must be 'flight', 'instant' or a number of seconds > 0, got {text!r}") from None
    if not (np.isfinite(w) and w > 0):
        raise ValueError(f"--window must be > 0 s (or 'flight' / 'instant'), got {text}")
    return w


def check_window(window, flight_s: float):
    """A window (see :func:`parse_window`) must fit in a flight of ``flight_s`` s."""
    window = parse_window(window)
    if isinstance(window, float) and window > flight_s + 1e-6:
        raise ValueError(f"--window {window:g} s is longer than the flight ({flight_s:.2f} s)")
    return window


def window_masks(latent_times, report_times, window):
    """Which latents (recorded at ``latent_times`` (L,)) each decode time (``report_times``
    (K,)) conditions on: 'flight' all up to t, seconds W those in (t − W, t]. -> (K, L) bool."""
    lt = np.asarray(latent_times)[None, :]
    rt = np.asarray(report_times)[:, None]
    mask = lt <= rt + 1e-6
    if isinstance(window, float):
        mask &= lt > rt - window + 1e-6
    # The first decode time may precede the first recorded latent by less than a step: use it.
    empty = ~mask.any(1)
    if empty.any():
        mask[empty, np.argmin(np.abs(lt - rt[empty]), 1)] = True
    return mask


MAX_DECODES = 30
"""Decode times at most per flight: a longer flight is decoded at a lower rate (evenly spaced,
the end always included), so a log of any length costs one replay and one pass of the sequence
decoder's encoder (both linear in the flight) plus at most this many posterior samplings. Each
sampling is the decoders' ODE (50 steps × 100 samples × a 5 M-parameter network, twice: instant
and flight-level): on 2 CPU cores 120 of them took 26 s of a 10 s log's 42 s decode; 30 still draw
the over-time figure, and every 10 Hz latent still enters the flight-level posterior."""


def window_bounds(latent_times, report_times, window):
    """The latents (recorded at ``latent_times`` (L,), increasing) each decode time
    (``report_times`` (K,)) conditions on, as index ranges: starts (K,), ends (K,) inclusive —
    the rows of :func:`window_masks` without building the (K, L) matrix."""
    lt, rt = np.asarray(latent_times), np.asarray(report_times)
    ends = np.searchsorted(lt, rt + 1e-6, side="right") - 1
    starts = np.zeros_like(ends) if not isinstance(window, float) else np.searchsorted(lt, rt - window + 1e-6, side="right")
    empty = (ends < 0) | (starts > ends)
    if empty.any():   # the first decode time may precede the first latent by less than a step: use it
        near = np.argmin(np.abs(lt[None, :] - rt[empty][:, None]), 1)
        starts[empty], ends[empty] = near, near
    return starts, ends


def every_times(times, every: float) -> np.ndarray:
    """Of the increasing decode ``times`` (K,), those nearest each multiple of ``every`` s within
    them, the first and last included (unique, increasing)."""
    times = np.asarray(times)
    grid = np.arange(np.ceil(times[0] / every - 1e-6), np.floor(times[-1] / every + 1e-6) + 1) * every
    near = np.abs(times[None, :] - grid[:, None]).argmin(1) if grid.size else np.zeros(0, int)
    return times[np.unique(np.concatenate([[0, len(times) - 1], near]))]


def decode_latents(zhat_t, times, *, rate: float, samples: int, seed: int = 0, decoder=None,
                   regression=None, start: float = N.HISTORY * 0.002, window="instant", seq_decoder=None,
                   max_decodes: int | None = MAX_DECODES, window_every: float | None = None):
    """Decode ẑ (T, 8) sampled at ``rate`` Hz after ``start`` s — at most ``max_decodes`` times
    (evenly spaced, the last included; None: no limit). Returns dict with times (K,), zhat (K, 8),
    samples (K, S, 19) physical (single latent), regression (K, 19) physical, decode_rate_hz ().
    Decoders default to the shipped ones of mjxsysid's policy. With a ``window`` other than
    'instant' and a ``seq_decoder``: also samples_window (K, S, 19), the flight-level posterior
    given the latents at the sequence decoder's rate (10 Hz) in the window, and n_window (K,),
    the number of latents in it, at the decode times times_window (K,) — all of them, or with
    ``window_every`` (s) only those nearest each multiple of it, the first and last included
    (the window's posterior sampled in one batch at fewer times: what the demo does). The
    windows are encoded incrementally
    (:meth:`~mjxsysid.cfm.sequence.SequenceDecoder.encode_flight`): time and memory grow
    linearly with the flight."""
    if not rate > 0:
        raise ValueError(f"--rate must be > 0 Hz, got {rate}")
    if samples < 2:
        raise ValueError(f"--samples must be >= 2, got {samples}")
    if max_decodes is not None and max_decodes < 1:
        raise ValueError(f"max_decodes must be >= 1, got {max_decodes}")
    if window_every is not None and not window_every > 0:
        raise ValueError(f"window_every must be > 0 s, got {window_every}")
    window = parse_window(window)
    times = np.asarray(times)
    idx = decode_indices(times, rate, start)
    rate_used = float(rate)
    if max_decodes is not None and len(idx) > max_decodes:
        idx = idx[np.unique(np.round(np.linspace(0, len(idx) - 1, max_decodes)).astype(int))]
        rate_used = (len(idx) - 1) / max(float(times[idx[-1]] - times[idx[0]]), 1e-9)
    if decoder is None or regression is None:
        cfm0, reg0 = load_decoders()
        decoder, regression = decoder or cfm0, regression or reg0
    z = np.asarray(zhat_t)[idx]
    s = np.asarray(decoder.sample_theta(z, jax.random.PRNGKey(seed), samples))
    out = {"times": times[idx], "zhat": z, "samples": s, "regression": np.asarray(regression.point(z)),
           "decode_rate_hz": np.float64(rate_used)}
    if window != "instant" and seq_decoder is not None:
        lidx = decode_indices(times, float(seq_decoder.meta.get("traj_rate_hz", 10.0)), start)
        wt = out["times"] if window_every is None else every_times(out["times"], window_every)
        out["times_window"] = wt
        starts, ends = window_bounds(times[lidx], wt, window)
        # Past the longest window the decoder was trained on (max_len latents) every latent still
        # enters the pooled features and the count feature saturates: calibrated on 60 s flights
        # (docs/runs/measurements/long-flight-calibration/long_flight_calibration.json; a sliding window of trained length was the
        # other candidate, measured too).
        out["beyond_trained_length"] = ends - starts + 1 > seq_decoder.max_len
        c = seq_decoder.encode_flight(np.asarray(zhat_t, np.float32)[lidx], ends,
                                      starts=None if window == "flight" else starts)
        out["samples_window"] = np.asarray(seq_decoder.sample_cond_theta(c, jax.random.PRNGKey(seed + 1), samples))
        out["n_window"] = ends - starts + 1
    return out


def decode_posterior(zhat_t, times, truth=None, *, decoder, regression, rate: float = 10.0,
                     samples: int = 100, seed: int = 0, window="instant", seq_decoder=None) -> dict:
    """What ``mjxsysid decode`` writes, in memory: ẑ (T, 8) over ``times`` (T,) decoded at
    ``rate`` Hz -> dict with the arrays of ``decoded.npz`` (times (K,), zhat (K, 8), samples
    (K, S, 19) instant, regression (K, 19), theta_true (19,) or NaN; with a window and a
    ``seq_decoder`` also samples_window (K, S, 19) and n_window (K,), see
    :func:`decode_latents`) and ``summary`` (the content of ``summary.json``:
    :func:`summarize_posterior` of the last decode time's samples — the window's if decoded,
    else the instant ones —, plus ``_invalid_fraction``, ``_window`` (window used, requested,
    label, t_end_s, n_latents) and, for a window, ``_instant``). ``window`` other than
    'instant' without a ``seq_decoder`` falls back to 'instant' (``_window`` says so)."""
    window = parse_window(window)
    used = window if seq_decoder is not None else "instant"
    dec = decode_latents(zhat_t, times, rate=rate, samples=samples, seed=seed, decoder=decoder,
                         regression=regression, window=used, seq_decoder=seq_decoder)
    instant = dec["samples"][-1]
    final = dec["samples_window"][-1] if "samples_window" in dec else instant
    summary = summarize_posterior(final, truth)
    summary["_invalid_fraction"] = float(P.project_valid(final)[1].mean())  # e.g. J triangle violated
    label = {"flight": "flight-level", "instant": "instant"}[used] if isinstance(used, str) else f"last {used:g} s"
    summary["_window"] = {"window": used, "requested": window, "label": label, "t_end_s": float(dec["times"][-1]),
                          "n_latents": int(dec["n_window"][-1]) if "n_window" in dec else 1,
                          "decode_rate_hz": float(dec["decode_rate_hz"]), "n_decodes": int(len(dec["times"])),
                          "beyond_trained_length": bool(dec["beyond_trained_length"][-1])
                          if "beyond_trained_length" in dec else False}
    if used != "instant":
        summary["_instant"] = summarize_posterior(instant, truth)
    truth = np.full(P.N_PARAMS, np.nan, np.float32) if truth is None else np.asarray(truth, np.float32)
    return dict(dec, theta_true=truth, summary=summary)


def log_latents(policy, rec: dict, *, source="flight log", checks: dict | None = None,
                imu_limit: dict | None = None):
    """ẑ (T, 8) and times (T,) (s from the log's start, first step at 2 ms) of a flight log read
    by :func:`read_log`, rebuilt by the frozen ``policy`` (a name, path or PolicyRef).

    The log's physics is checked first (:func:`~mjxsysid.studies.logcheck.check_log`): a log
    that cannot be right raises :class:`~mjxsysid.studies.logcheck.LogError` (naming ``source``)
    before any replay; then the policy's own actions on the logged inputs are compared with the
    logged motor commands. The findings (warnings) are appended to ``checks["findings"]``.
    ``imu_limit``: the IMU noise the decoders are calibrated under
    (:func:`~mjxsysid.studies.logcheck.imu_noise_limit`; default its shipped decoders' limit)."""
    found = check_log(rec, imu_limit=imu_limit)
    if any(f.level == "error" for f in found):
        raise LogError(source, found)
    ctrl = resolve_policy(policy).load()
    zhat_t = np.asarray(ctrl.replay(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"]))
    if hasattr(ctrl, "replay_actions"):
        found += check_replay(rec, ctrl, zhat_t)
    if checks is not None:
        checks.setdefault("findings", []).extend(found)
    return zhat_t, rec["t"] - rec["t"][0] + LOG_DT


def decoders_prior(*decoders) -> str | None:
    """The name of the prior the decoders were trained on (from their provenance), if it is a
    size-factor prior of :mod:`mjxsysid.theta` (what :func:`prior_check` compares with)."""
    for d in decoders:
        name = (getattr(d, "meta", None) or {}).get("data", {}).get("pairs_meta", {}).get("prior")
        if name in P.PRIORS and isinstance(P.PRIORS[name], P.SizeFactorPrior):
            return name
    return None


def flight_checks(rec: dict, prior: str | None, checks: dict | None = None) -> dict:
    """Out-of-prior check of a flight (a log's arrays, or a flown flight's): the log-only
    estimates of :func:`~mjxsysid.studies.logcheck.estimate_vehicle` against the decoders'
    ``prior`` -> ``checks`` with ``estimates``, ``prior``, ``findings`` (appended) and the
    summary's form (:func:`checks_summary`)."""
    checks = {} if checks is None else checks
    est = estimate_vehicle(rec)
    checks["estimates"] = est
    checks["prior"] = prior
    if prior is not None:
        checks.setdefault("findings", []).extend(prior_check(rec, prior, est))
    return checks


def checks_summary(checks: dict) -> dict:
    """The ``_checks`` entry of summary.json: warnings and out-of-prior findings as text, the
    log-only estimates, the prior compared with, ``out_of_prior`` (bool), ``notes`` (what the
    log could not tell: e.g. the motor time constant not estimable, its estimate then no
    measurement) and, for a log read from another format (a ULog), ``source`` (topics, rates,
    segment, conversions) and ``resampled`` (how each column group reached 2 ms)."""
    from mjxsysid.studies.logcheck import motor_time_constant
    found = checks.get("findings", [])
    oop = [str(f) for f in found if f.level == "out_of_prior"]
    est = checks.get("estimates", {})
    tau, why = motor_time_constant(est) if est else (None, None)
    out = {"warnings": [str(f) for f in found if f.level == "warning"], "out_of_prior": oop,
           "is_out_of_prior": bool(oop), "prior": checks.get("prior"),
           "estimates": {k: float(v) for k, v in est.items()}, "notes": [why] if est and tau is None else [],
           "motor_time_constant_estimable": tau is not None}
    for k in ("source", "resampled"):
        if checks.get(k) is not None:
            out[k] = checks[k]
    return out


OUT_OF_PRIOR_TITLE = "OUT OF THE DECODERS' PRIOR — bands not calibrated: "


def ground_in_log(dec: dict, summary: dict, rec: dict, truth=None, *, seed: int = 0) -> dict:
    """Make the log-grounded posterior (:mod:`mjxsysid.identify`) of a log's arrays ``rec`` the
    posterior of record, the decoded samples (the window's at the end of the flight, else the
    instant ones) as its proposal. In place: ``dec["samples_log_grounded"]`` (S, 19); ``summary``'s
    top-level entries (19 parameters, identifiable combinations, and the log-identifiable
    quantities of :data:`~mjxsysid.identify.coords.LOG_NAMES`) become the log-grounded posterior's,
    the decoder-only entries move under ``_decoder_only``, and ``_log_grounded`` holds the method,
    its diagnostics (ESS, Pareto k̂, SMC stages), the IMU noise, discrepancy and bias it estimated,
    and the information gap. Returns ``summary``."""
    from mjxsysid.identify.gap import information_gap, log_summary
    from mjxsysid.identify.inference import log_grounded_posterior
    from mjxsysid.identify.likelihood import CHANNELS, LogTooShort
    final = dec["samples_window"][-1] if "samples_window" in dec else dec["samples"][-1]
    try:
        post = log_grounded_posterior(rec, final, seed=seed)
    except LogTooShort as e:       # a log too short for the likelihood's windows: the decoders alone, said so
        summary["_log_grounded"] = {"skipped": str(e)}
        summary["_posterior"] = "decoder-only"
        return summary
    decoder_only = {k: summary.pop(k) for k in list(summary) if not k.startswith("_")}
    decoder_only.update(log_summary(final, truth))
    summary.update(summarize_posterior(post["theta"], truth))
    summary.update(log_summary(post["theta"], truth))
    summary["_decoder_only"] = decoder_only
    diag = {k: post[k] for k in ("method", "proposal", "decoded_is", "laplace_is", "smc_stages", "smc_acceptance",
                                 "smc_tempering") if k in post}
    nz = np.exp(np.median(post["nuisance"][:, :8], 0))
    diag["imu_noise"] = {c: float(x) for c, x in zip(CHANNELS, nz[:4])}
    diag["discrepancy"] = {c: float(x) for c, x in zip(CHANNELS, nz[4:])}
    diag["acc_z_bias"] = float(np.median(post["nuisance"][:, 8]))
    diag["residual_weights"] = {c: float(x) for c, x in zip(CHANNELS, post["weights"])}
    diag["channels_used"] = [c for c, u in zip(CHANNELS, post["channels_used"]) if u > 0]
    diag["gap"] = information_gap(final, post["theta"], truth)
    summary["_log_grounded"] = json.loads(json.dumps(diag, default=float))
    summary["_posterior"] = "log-grounded"
    dec["samples_log_grounded"] = post["theta"]
    return summary


def _posterior_table(summary: dict) -> list[str]:
    """summary.md's table rows of a posterior's summary entries (mean, 5–95 %, truth, inside)."""
    rows = ["| quantity | mean | 5 % | 95 % | true | inside |", "|---|---|---|---|---|---|"]
    for k, v in summary.items():
        if isinstance(v, dict) and "mean" in v and "q05" in v:
            true = f"{v['true']:.4g}" if "true" in v else ""
            inside = ("yes" if v["inside"] else "no") if "inside" in v else ""
            rows.append(f"| {k} | {v['mean']:.4g} | {v['q05']:.4g} | {v['q95']:.4g} | {true} | {inside} |")
    return rows


def write_summary_md(summary: dict, path) -> Path:
    """summary.md: the checks' warnings first (out of prior, suspicious log), then the decoded
    identifiable combinations and parameters (mean, 5–95 %, and the truth if known)."""
    c = summary.get("_checks", {})
    lines = ["# Decoded vehicle", ""]
    if c.get("is_out_of_prior"):
        lines += ["**Out of the decoders' training prior: the bands below are not calibrated.**", ""]
        lines += [f"- {m}" for m in c["out_of_prior"]] + [""]
    if c.get("warnings"):
        lines += ["**Warnings about the log:**", ""] + [f"- {m}" for m in c["warnings"]] + [""]
    w = summary.get("_window", {})
    which = ("log-grounded (the log's IMU given its motor commands under a physical prior; the decoded "
             "samples its proposal)" if summary.get("_posterior") == "log-grounded" else
             f"{w.get('label', '')} at t = {w.get('t_end_s', float('nan')):.2f} s")
    lines += [f"Posterior: {which}.", ""] + _posterior_table(summary)
    if c.get("source") or c.get("resampled") or c.get("notes"):
        lines += ["", "## What was done to the log", ""]
        src = c.get("source") or {}
        lines += [f"- {k}: {v}" for k, v in src.items() if k != "conversions"]
        lines += [f"- conversion: {m}" for m in src.get("conversions", [])]
        lines += [f"- {k}: {v}" for k, v in (c.get("resampled") or {}).items()]
        lines += [f"- note: {m}" for m in c.get("notes", [])]
    g = summary.get("_log_grounded")
    if g and "skipped" in g:
        lines += ["", f"**No log-grounded posterior:** {g['skipped']}. The bands above are the decoders' alone."]
    elif g:
        from mjxsysid.identify.gap import gap_markdown
        d = summary.get("_decoder_only", {})
        lines += ["", "## Decoder-only posterior (what the policy's latent knows)", ""] + _posterior_table(d)
        isd = g.get("decoded_is") or {}
        lines += ["", "## The information gap: decoder-only against log-grounded", "",
                  f"Method: {g['method']}; the decoded ensemble as importance proposal: ESS {isd.get('ess', float('nan')):.3g} "
                  f"of {isd.get('draws', '?')}, Pareto k̂ {isd.get('khat', float('nan')):.3g} (reliable: ESS ≥ 5 %, k̂ ≤ 0.7). Channels "
                  f"used: {', '.join(g.get('channels_used', []))}. A width ratio above 1: the log pins the quantity "
                  f"down more than the policy's latent does; a log-grounded band as wide as the prior: the log cannot "
                  f"see it (docs/identify.md).", ""]
        lines += gap_markdown(g["gap"])
    Path(path).write_text("\n".join(lines) + "\n")
    return Path(path)




def run_decode(out, *, theta=None, log=None, reference="lemniscate", period=10.0, duration=None,
               samples=100, rate=10.0, weights=None, seed=0, video=False, ghosts=4, echo=print,
               policy="mjxsysid", decoders=None, window="flight", truth=None, warn=warn, segment=None,
               decoder_only=False) -> dict:
    """Fly θ (or replay ``log``) with a frozen latent policy (``policy``, ``weights``: see
    :func:`~mjxsysid.policy.interface.resolve_policy`; default the shipped one), decode at
    ``rate`` Hz with that policy's decoders (or those in ``decoders``), write out/decoded.npz,
    out/summary.json and plots (and out/decoded.mp4 with ``video``).

    ``window`` ('flight', 'instant' or seconds, see :func:`parse_window`): the top-level
    entries of summary.json are the posterior at the end of the flight given the latents in
    that window (the sequence decoder; 'instant': the single-latent CFM), ``_instant`` the
    single-latent one, ``_window`` what was used. Without a sequence decoder, falls back to
    'instant' and says so. ``truth`` (θ (19,), with ``log`` only): the logged vehicle's known
    parameters; the summary then reports ``true`` and ``inside`` as for a flown vehicle.
    ``log``: a CSV or a PX4 ULog (``.ulg``, :func:`read_any_log`); ``segment`` 't0:t1': the part
    of it to decode (a ULog's default: its armed, airborne segment).

    A log's posterior of record is grounded in its own physics unless ``decoder_only``
    (:func:`ground_in_log`: summary.json's top-level entries the log-grounded posterior's, the
    decoders' under ``_decoder_only``, the information gap under ``_log_grounded``; also
    marginals_decoder_only.png and information_gap.png).

    A log is checked for physical plausibility before any decoding
    (:mod:`mjxsysid.studies.logcheck`): a log that cannot be right raises ``LogError`` (a
    ``ValueError``); suspicious findings, and a flight outside the decoders' training prior, go
    to ``warn`` (never silenced by ``--quiet``), ``summary["_checks"]``, summary.md and the
    plots' titles."""
    # Every input is checked before any work starts.
    if not rate > 0:
        raise ValueError(f"--rate must be > 0 Hz, got {rate}")
    if samples < 2:
        raise ValueError(f"--samples must be >= 2, got {samples}")
    if (log is None) == (theta is None):
        raise ValueError("give either a vehicle (theta) or a flight log, not both or neither")
    if truth is not None:
        if log is None:
            raise ValueError("truth is for a flight log (a flown vehicle is its own truth)")
        truth = P.validate_theta(truth, what="truth")
        if truth.shape != (P.N_PARAMS,):
            raise ValueError(f"truth: one θ of shape ({P.N_PARAMS},) expected, got {truth.shape}")
    window = parse_window(window)
    rec = read_any_log(log, segment) if log is not None else None
    if theta is not None:
        theta = P.validate_theta(theta, what="vehicle")
        if theta.shape != (P.N_PARAMS,):
            raise ValueError(f"vehicle: one θ of shape ({P.N_PARAMS},) expected, got {theta.shape}")
        # the window must fit in the flight: checked before flying
        d0 = make_reference(reference, period=period, duration=duration, seed=seed)[1]
        check_window(window, d0 if duration is None else duration)
    else:
        check_window(window, float(rec["t"][-1] - rec["t"][0] + LOG_DT))
    ref = resolve_policy(policy, weights)
    cfm, reg = load_decoders(decoders, ref, warn=echo)
    seq = None if window == "instant" else load_sequence_decoder(decoders, ref, echo=echo)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    st = stages(["flying" if log is None else "replaying the log", "decoding"]
                + (["log-grounded posterior"] if log is not None and not decoder_only else []) + ["plots"]
                + (["video"] if video and log is None else []), desc="decode")
    st.start("flying" if log is None else "replaying the log")
    flight = None
    checks = {k: rec[k] for k in ("source", "resampled") if rec is not None and k in rec}   # a ULog's reading
    if log is not None:
        zhat_t, times = log_latents(ref, rec, source=log, checks=checks, imu_limit=imu_noise_limit(cfm, reg, seq))
        truth = None if truth is None else np.asarray(truth, np.float32)
    else:
        flight, _, _ = fly_vehicles(theta, controller="policy", policy=ref, reference=reference,
                                    period=period, duration=duration, seed=seed)
        one = one_flight(flight)
        zhat_t, times, truth = one.latent, one.time, np.asarray(theta, np.float32)
        rec = {"imu": seen_imu(one.frame.imu), "motor": one.frame.motor_cmd}
    flight_checks(rec, decoders_prior(seq, cfm), checks)
    for f in checks["findings"]:
        warn(f)
    st.start("decoding")
    dec = decode_posterior(zhat_t, times, truth, decoder=cfm, regression=reg, rate=rate, samples=samples,
                           seed=seed, window=window, seq_decoder=seq)
    summary = dec.pop("summary")
    summary["_checks"] = checks_summary(checks)
    label = summary["_window"]["label"]
    flag = OUT_OF_PRIOR_TITLE if summary["_checks"]["is_out_of_prior"] else ""
    if summary["_window"]["decode_rate_hz"] < rate - 1e-6:
        echo(f"note: {summary['_window']['n_decodes']} decode times at most (MAX_DECODES): this "
             f"{summary['_window']['t_end_s']:.0f} s flight is decoded at {summary['_window']['decode_rate_hz']:.3g} Hz; "
             f"every latent (10 Hz) still enters the flight-level posterior")
    if summary["_window"]["beyond_trained_length"]:
        echo(f"note: {summary['_window']['n_latents']} latents, more than the sequence decoder's training flights "
             f"({seq.max_len}): the count feature saturates there; calibration checked to 60 s flights "
             f"(docs/decoding.md)")
    final = dec["samples_window"][-1] if "samples_window" in dec else dec["samples"][-1]
    if log is not None and not decoder_only:
        st.start("log-grounded posterior")
        ground_in_log(dec, summary, rec, truth, seed=seed)
    np.savez_compressed(out / "decoded.npz", **dec)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    write_summary_md(summary, out / "summary.md")
    st.start("plots")
    t_true = truth if truth is not None else np.full(19, np.nan)
    if "samples_log_grounded" in dec:
        plot_marginals(dec["samples_log_grounded"], t_true, out / "marginals.png", point=dec["regression"][-1],
                       title=f"{flag}log-grounded posterior p(θ | log) (the decoded samples its proposal)")
        plot_marginals(final, t_true, out / "marginals_decoder_only.png", point=dec["regression"][-1],
                       title=f"{flag}decoder-only p(θ | ẑ, {label}) at t = {dec['times'][-1]:.1f} s")
        plot_information_gap(summary["_log_grounded"]["gap"], out / "information_gap.png")
    else:
        plot_marginals(final, t_true, out / "marginals.png", point=dec["regression"][-1],
                       title=f"{flag}decoded p(θ | ẑ, {label}) at t = {dec['times'][-1]:.1f} s")
    plot_decoded_over_time(dec, truth, out / "decoded_over_time.png", window_label=label, title=flag or None)
    if video and flight is not None:
        st.start("video")
        gth, _ = P.project_valid(final[:ghosts])
        gfl, _, _ = fly_vehicles(gth, controller="policy", policy=ref, reference=reference,
                                 period=period, duration=duration, seed=seed)
        g = [(gth[i], np.asarray(gfl.frame.pos[i]), np.asarray(gfl.frame.quat[i])) for i in range(len(gth))]
        render_rollout(truth, one.frame, out / "decoded.mp4", ghosts=g, reference=one.ref_pos, fps=25,
                       width=480, height=360)
    st.close()
    if truth is not None:
        n_in = sum(v["inside"] for k, v in summary.items() if k in P.PARAM_NAMES)
        echo(f"true θ inside the decoded ({label}) 5–95 % interval for {n_in}/{P.N_PARAMS} parameters")
    return summary
