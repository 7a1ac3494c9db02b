"""The airborne part of a log, found from its motor commands: ground time, spin-up and landing cut.

Every reader calls :func:`airborne_segment` when the user gives no ``--segment``; the cut is said
(``why``) in ``rec["source"]["segment"]``.
"""
from __future__ import annotations

import numpy as np

GAP_S = 0.2
"""s: dips of the motor commands shorter than this (a flip, a motor cut) do not end a segment."""

TRIM_S = 0.5
"""s: cut at each end of a segment that starts or ends on the ground (take-off and touch-down)."""

MIN_SPREAD = 0.1
"""Ω_cmd/Ω_max: a log whose mean motor command spans less than this never sat idle on the ground."""

IDLE_LEVEL = 0.35
"""Ω_cmd/Ω_max: the highest low level (2nd percentile of the mean command) that is surely a rotor
stopped or idling on the ground (PX4's idle, 10 % throttle, is √0.1 ≈ 0.32 of Ω_max). Above it, a
dip inside the log shorter than :data:`AIR_DIP_S` is a manoeuvre in the air, not a landing."""

AIR_DIP_S = 2.0
"""s: the longest dip inside a log whose low level is above :data:`IDLE_LEVEL` that is bridged as a
manoeuvre in the air (ground time at either end is still cut)."""


def _runs(mask):
    """Start and stop indices [i0, i1) of each run of True in ``mask`` (N,)."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def airborne_segment(t, motor, min_s: float = 1.0):
    """The longest stretch of ``t`` (N,) s during which the mean motor command ``motor`` (N, 4)
    (Ω_cmd/Ω_max in [0, 1]) is above halfway between its idle level (2nd percentile) and its flight
    level (median of the upper half) -> (t0, t1, why). Dips shorter than :data:`GAP_S` are bridged;
    :data:`TRIM_S` is cut at an end that touches idle. A log that never idles (levels closer than
    :data:`MIN_SPREAD`) is kept whole; when the low level is above :data:`IDLE_LEVEL`, dips inside the
    log, or at its ends, shorter than :data:`AIR_DIP_S` are bridged too (manoeuvres, not landings). ValueError
    when no stretch of ``min_s`` seconds is found, naming the levels and the next step."""
    t = np.asarray(t, np.float64)
    m = np.mean(np.asarray(motor, np.float64), axis=-1)
    if len(t) < 2:
        raise ValueError("the log has fewer than two motor samples: no airborne segment can be found")
    lo = float(np.percentile(m, 2))
    hi = float(np.median(m[m >= np.median(m)]))
    if hi - lo < MIN_SPREAD:
        return float(t[0]), float(t[-1]), (f"motors spun for the whole log (mean command {lo:.2f}–{hi:.2f}): "
                                           f"kept whole, {t[-1] - t[0]:.1f} s")
    thr = lo + 0.5 * (hi - lo)
    up = m > thr
    starts, stops = _runs(~up)
    longest = AIR_DIP_S if lo > IDLE_LEVEL else GAP_S
    for a, b in zip(starts, stops):                       # bridge short dips inside the flight
        inside = 0 < a and b < len(m)
        span = t[min(b, len(m) - 1)] - t[max(a - 1, 0)]
        if (inside and span < longest) or (not inside and lo > IDLE_LEVEL and span < AIR_DIP_S):
            up[a:b] = True
    starts, stops = _runs(up)
    if len(starts) == 0:
        raise ValueError(f"no airborne segment: the mean motor command never exceeds {thr:.2f} (idle {lo:.2f}); "
                         f"give the flight's part with --segment t0:t1")
    if up.all():
        return float(t[0]), float(t[-1]), (f"motors above idle for the whole log (mean command {lo:.2f}–{hi:.2f}, "
                                           f"dips shorter than {AIR_DIP_S:g} s read as manoeuvres): kept whole, "
                                           f"{t[-1] - t[0]:.1f} s")
    spans = [(t[b - 1] - t[a], a, b) for a, b in zip(starts, stops)]
    spans.sort(reverse=True)
    _, a, b = spans[0]
    t0 = t[a] + (TRIM_S if a > 0 else 0.0)
    t1 = t[b - 1] - (TRIM_S if b < len(t) else 0.0)
    if t1 - t0 < min_s:
        raise ValueError(f"no airborne segment of {min_s:g} s: the longest stretch with motors above {thr:.2f} "
                         f"(idle {lo:.2f}, flight {hi:.2f}) is {t1 - t0:.2f} s; give the flight's part with --segment t0:t1")
    others = [f"{t[x]:.1f}–{t[y - 1]:.1f} s" for _, x, y in spans[1:] if t[y - 1] - t[x] >= min_s]
    why = (f"airborne from the motor commands (mean above {thr:.2f}: idle {lo:.2f}, flight {hi:.2f}), the longest "
           f"stretch, {TRIM_S:g} s cut at a take-off or touch-down end: {t0:.2f}–{t1:.2f} s"
           + (f"; other airborne stretches not used: {', '.join(others)} (--segment picks one)" if others else ""))
    return float(t0), float(t1), why
