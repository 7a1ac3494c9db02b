"""The rate at which each column group was sampled before it reached the 2 ms grid: declared by
the reader (a ULog) or detected in the values (a CSV held or interpolated from a lower rate)."""
from __future__ import annotations

import numpy as np

from mjxsysid.logs.checks.findings import Finding
from mjxsysid.logs.checks.signals import DT

MIN_ORDER_RATE_HZ = 100.0
"""Hz: the motor-command rate below which the rotor order and τ_m cannot be told from the log:
the rotors follow their commands within τ_m (5–100 ms), so commands held for longer than 10 ms
no longer show which rotor moved the vehicle when (PX4 logs its motors at 10 Hz by default)."""

RESAMPLED_FRACTION = 0.3
"""Share of rows at which a column group is exactly held (no change) or exactly linear (zero
second difference on every channel) past which it is taken as resampled from a lower rate
(a 500 Hz log of a real vehicle: none; from 250 Hz: about half the rows)."""


def detect_resampled(t, x):
    """Whether the columns ``x`` (T, k) sampled at ``t`` (T,) were brought to their grid from a
    lower rate -> None (not resampled), or (how, native rate Hz, knot rows): 'held (zero-order)' if
    every channel repeats its previous row on most rows, 'interpolated (linear)' if every
    channel's second difference is zero (to the CSV's 7 digits) on most rows; the knot rows are
    the native samples."""
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    if len(x) < 10:
        return None
    span = max(float(t[-1] - t[0]), DT)
    same = np.all(np.diff(x, axis=0) == 0, axis=1)
    if same.mean() > RESAMPLED_FRACTION:
        knots = np.concatenate([[0], np.flatnonzero(~same) + 1])
        return "held (zero-order)", len(knots) / span, knots
    d2 = np.diff(x, 2, axis=0)
    scale = np.maximum(np.maximum(np.abs(x[:-2]), np.abs(x[1:-1])), np.abs(x[2:]))
    lin = np.all(np.abs(d2) <= 2.5e-6 * scale + 1e-12, axis=1)   # zero to the CSV's 7 digits (each ±5e-7)
    if lin.mean() > RESAMPLED_FRACTION:
        knots = np.concatenate([[0], np.flatnonzero(~lin) + 1, [len(x) - 1]])
        return "interpolated (linear)", len(knots) / span, knots
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
            d = np.diff(np.asarray(tn, np.float64))
            rate = float(1.0 / np.median(d[d > 0])) if np.any(d > 0) else 1.0 / DT
            out[key] = (rate, said.get(key, "native"), (np.asarray(tn, np.float64), np.asarray(xn, np.float64)))
            continue
        found = detect_resampled(t, rec[key])
        if found is None:
            out[key] = (1.0 / DT, "native", None)
        else:
            how, rate, knots = found
            x = np.asarray(rec[key], np.float64)
            out[key] = (rate, f"{how} from about {rate:.3g} Hz (detected: the column values)", (t[knots], x[knots]))
    return out


def is_resampled(rate: float) -> bool:
    return abs(rate * DT - 1.0) > 0.05


def check_resampled(rec: dict) -> list[Finding]:
    """A warning naming each column group a CSV carries resampled from a lower rate (held or
    linearly interpolated: detected from its values), what it was, and what the checks do about
    it. A reader that declares its resampling (``rec["resampled"]``, a ULog) is not warned for it
    here (the source says it); the checks that cannot work at its rate say so themselves."""
    out = []
    declared = rec.get("resampled") or {}
    for key, (rate, how, _) in column_rates(rec).items():
        if key in declared or not is_resampled(rate):
            continue
        cols = "gyro_x … acc_z" if key == "imu" else "motor_1, motor_2, motor_3, motor_4"
        out.append(Finding("warning", cols, f"the {key} columns look {how}: not sampled every 2 ms step. The "
                           f"decoders read the policy's 500 Hz inputs; a log resampled from another rate does not "
                           f"give the inputs the policy saw (docs/decoding.md). The checks read the native "
                           f"samples (the knots) where they can"))
    return out
