"""The rate at which each column group was sampled before it reached the 2 ms grid: declared by
the reader (a ULog) or detected in the values (a CSV held or interpolated from a lower rate),
whatever the number format the values were written in (the quantum is read from the values)."""
from __future__ import annotations

import numpy as np

from mjxsysid.logs.checks.findings import Finding
from mjxsysid.logs.checks.signals import DT

MIN_ORDER_RATE_HZ = 100.0
"""Hz: the motor-command rate below which the rotor order and τ_m cannot be told from the log:
the rotors follow their commands within τ_m (5–100 ms), so commands held for longer than 10 ms
no longer show which rotor moved the vehicle when (PX4 logs its motors at 10 Hz by default)."""

RATE_TOLERANCE = 1e-6
"""Relative: a measured rate this close to a threshold counts as reaching it (an exact 100 Hz log's
median step is 10 ms to float round-off, either side)."""

RESAMPLED_FRACTION = 0.3
"""Share of rows at which a column group is exactly held (no change) or exactly linear (zero
second difference on every channel, to the values' own quantum) past which it is taken as
resampled from a lower rate (a 500 Hz log of a real vehicle: none; from 250 Hz: about half the rows)."""

SAMPLE_VALUES = 4000
"""Values per channel read to find the number format (decimals or significant digits)."""


def reaches(rate: float, threshold: float) -> bool:
    """``rate`` ≥ ``threshold`` up to :data:`RATE_TOLERANCE` (round-off of the sample times)."""
    return rate >= threshold * (1.0 - RATE_TOLERANCE)


def sample_rate(t) -> float:
    """Hz from sample times ``t`` (N,) s: one over the median positive step (500 Hz if none)."""
    d = np.diff(np.asarray(t, np.float64))
    d = d[d > 0]
    return float(1.0 / np.median(d)) if d.size else 1.0 / DT


def knot_rate(t, knots) -> float:
    """The native rate (Hz) of a column resampled from its knot rows ``knots`` (K,) on grid ``t``:
    the knot steps counted in native periods (the median step; a step of several periods is a
    sample that repeated its value), over the time they span. Counts samples, not value changes."""
    tk = np.asarray(t, np.float64)[np.asarray(knots)]
    d = np.diff(tk)
    d = d[d > 0]
    if d.size == 0:
        return 1.0 / max(float(t[-1] - t[0]), DT)
    p = float(np.median(d))
    periods = np.maximum(np.round(d / p), 1.0)
    return float(periods.sum() / d.sum())


def _fits(v, step) -> bool:
    """Is every value of ``v`` a multiple of ``step`` (scalar or per value), to float round-off?"""
    r = v / step
    return bool(np.all(np.abs(r - np.round(r)) <= 1e-4 + 1e-15 * np.abs(r)))


def value_quantum(x):
    """The rounding step of each value of ``x`` (N, k), from the number format the values show: the
    fewest decimals d that every value of a channel fits (step 10⁻ᵈ) and the fewest significant
    digits s (step 10^(⌊log10|x|⌋ − s + 1)), read on :data:`SAMPLE_VALUES` values; each value's step
    is the larger of the two (a format fits both where it can: 9.81 and 10.05 written with 7
    significant digits have 6 decimals and steps 1e-6 and 1e-5), at least float64's precision.
    -> (N, k) steps."""
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    rows = np.unique(np.linspace(0, len(x) - 1, min(SAMPLE_VALUES, len(x))).astype(int))
    mag = np.floor(np.log10(np.maximum(np.abs(x), 1e-300)))
    q = 4.0 * np.finfo(np.float64).eps * np.abs(x)
    for c in range(x.shape[1]):
        v = x[rows, c]
        v = v[v != 0]
        if v.size == 0:
            continue
        vmag = np.floor(np.log10(np.abs(v)))
        d = next((d for d in range(17) if _fits(v, 10.0 ** -d)), None)
        s = next((s for s in range(1, 18) if _fits(v, 10.0 ** (vmag - s + 1))), None)
        if d is not None:
            q[:, c] = np.maximum(q[:, c], 10.0 ** -d)
        if s is not None:
            q[:, c] = np.maximum(q[:, c], 10.0 ** (mag[:, c] - s + 1))
    return q


def detect_resampled(t, x):
    """Whether the columns ``x`` (T, k) sampled at ``t`` (T,) were brought to their grid from a
    lower rate -> None (not resampled), or (how, native rate Hz, knot rows): 'held (zero-order)' if
    every channel repeats its previous row on most rows, 'interpolated (linear)' if every
    channel's second difference is zero to the values' rounding (:func:`value_quantum`: linear
    interpolation rounded to a step q leaves second differences of at most 2 q) on most rows; the
    knot rows are the native samples, the rate their count in native periods (:func:`knot_rate`)."""
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    if len(x) < 10:
        return None
    same = np.all(np.diff(x, axis=0) == 0, axis=1)
    if same.mean() > RESAMPLED_FRACTION:
        knots = np.concatenate([[0], np.flatnonzero(~same) + 1])
        return "held (zero-order)", knot_rate(t, knots), knots
    d2 = np.diff(x, 2, axis=0)
    q = value_quantum(x)
    qmax = np.maximum(np.maximum(q[:-2], q[1:-1]), q[2:])
    lin = np.all(np.abs(d2) <= 2.0 * qmax * (1 + 1e-9) + 1e-300, axis=1)
    if lin.mean() > RESAMPLED_FRACTION:
        knots = np.concatenate([[0], np.flatnonzero(~lin) + 1])
        return "interpolated (linear)", knot_rate(t, knots), np.concatenate([knots, [len(x) - 1]])
    return None


def column_rates(rec: dict) -> dict:
    """For the imu and motor column groups: {group: (rate Hz, how, native (t, values) or None)} —
    the rate at which the group was sampled before it reached the 2 ms grid: what the reader
    declared (``rec["native"]``, ``rec["resampled"]``: :func:`~mjxsysid.logs.ulog.read_ulog`),
    else what :func:`detect_resampled` finds (a CSV resampled from a lower rate: its native
    samples are its knots), else 500 Hz 'native'."""
    out = {}
    native, said = rec.get("native") or {}, rec.get("resampled") or {}
    t = np.asarray(rec["t"], np.float64) if "t" in rec else DT * np.arange(len(rec["imu"]))
    for key in ("imu", "motor"):
        if key not in rec and key not in native:
            continue
        if key in native:
            tn, xn = native[key]
            rate = sample_rate(tn)
            out[key] = (rate, said.get(key, "native"), (np.asarray(tn, np.float64), np.asarray(xn, np.float64)))
            continue
        rate, how, nat = measure_column(t, rec[key])
        out[key] = (rate, how, nat if how != "native" else None)
    return out


def measure_column(t, x):
    """A column group ``x`` (T, ...) on the grid ``t`` (T,) -> (native rate Hz, how it reached the
    grid, native (t, values)): its knots if it was held or interpolated from a lower rate
    (:func:`detect_resampled`), else every row ("native", the rate from the rows' own steps)."""
    x = np.asarray(x, np.float64)
    found = detect_resampled(t, x)
    if found is None or not is_resampled(found[1]):     # (a straight stretch of a native column)
        return sample_rate(t), "native", (np.asarray(t, np.float64), x)
    how, rate, knots = found
    return rate, f"{how} from about {rate:.3g} Hz (detected: the column values)", (np.asarray(t, np.float64)[knots],
                                                                                  x[knots])


COLUMN_GROUPS = ("imu", "motor", "a_cmd", "omega_cmd")


def measure_columns(rec: dict) -> tuple[dict, dict, dict]:
    """Every column group of a log on its grid (``rec``: t and :data:`COLUMN_GROUPS`, and velocity_body
    where it has one) measured from its samples -> (native {group: (t, values)}, resampled {group: how},
    rates_hz {group: Hz})."""
    native, said, rates = {}, {}, {}
    for key in COLUMN_GROUPS + tuple(k for k in ("velocity_body",) if k in rec):
        rate, how, nat = measure_column(rec["t"], rec[key])
        native[key], rates[key] = nat, round(rate, 2)
        said[key] = f"native ({rate:.0f} Hz)" if how == "native" else how
    return native, said, rates


def is_resampled(rate: float) -> bool:
    return abs(rate * DT - 1.0) > 0.05


def check_resampled(rec: dict) -> list[Finding]:
    """A warning naming each column group a CSV carries resampled from a lower rate (held or
    linearly interpolated: detected from its values), what it was, and what the checks do about
    it. A reader that declares its resampling (``rec["resampled"]``, a ULog) is not warned for it
    here (the source says it); the checks that cannot work at its rate say so themselves."""
    out = []
    detected = (rec.get("source") or {}).get("format") == "CSV"     # a CSV's rates are read off its values
    declared = {} if detected else rec.get("resampled") or {}
    for key, (rate, how, _) in column_rates(rec).items():
        if key in declared or not is_resampled(rate):
            continue
        cols = "gyro_x … acc_z" if key == "imu" else "motor_1, motor_2, motor_3, motor_4"
        out.append(Finding("warning", cols, f"the {key} columns look {how}: not sampled every 2 ms step. The "
                           f"decoders read the policy's 500 Hz inputs; a log resampled from another rate does not "
                           f"give the inputs the policy saw (docs/decoding.md). The checks read the native "
                           f"samples (the knots) where they can"))
    return out
