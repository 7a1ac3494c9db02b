"""A PX4 ULog's state-estimate velocity in the body frame (``velocity_body``, :func:`~mjxsysid.logs.ulog.read_ulog`).

PX4's estimator publishes the velocity in the local NED frame (``vehicle_local_position`` vx, vy, vz,
with ``v_xy_valid`` / ``v_z_valid``) and the attitude as the rotation from the FRD body to NED
(``vehicle_attitude`` q, w x y z). The velocity is rotated into FRD by the attitude interpolated to
its times, then brought to FLU as the IMU is (y and z negated). A velocity flagged invalid, not finite,
or not covering the segment (within one of its steps at either end) is not used: the record says so instead (``missing`` and a sentence).
"""
from __future__ import annotations

import numpy as np

from mjxsysid.logs.grid import cut, interp_linear, world_to_body
from mjxsysid.logs.record import sorted_unique

FLU_FROM_FRD = np.array([1.0, -1.0, -1.0])


def _times(d, start_us):
    """A topic's sample times (s since the log's start): ``timestamp_sample`` where logged, else ``timestamp``."""
    ts = d["timestamp_sample"] if "timestamp_sample" in d else d["timestamp"]
    return (np.asarray(ts, np.float64) - float(start_us)) * 1e-6


def continuous_quaternions(q):
    """Unit quaternions (N, 4) with each sign flipped to the hemisphere of the one before (q and −q
    are one rotation): their components then interpolate without passing through zero."""
    q = np.asarray(q, np.float64).copy()
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0:
            q[i] = -q[i]
    return q


def ulog_velocity_body(lp, att, start_us, t0: float, t1: float):
    """``vehicle_local_position`` ``lp`` and ``vehicle_attitude`` ``att`` (pyulog's data dicts, or
    None) -> ((t (N,) s, v (N, 3) m/s FLU) the native samples in the segment t0..t1 s (one more on
    each side), or None when not usable; the sentence saying what was done or why not)."""
    if lp is None or not all(k in lp for k in ("vx", "vy", "vz")):
        return None, "velocity_body: not given: the log has no vehicle_local_position (vx, vy, vz)"
    if att is None or not all(f"q[{i}]" in att for i in range(4)):
        return None, ("velocity_body: not given: vehicle_local_position is logged but vehicle_attitude (q) is not; "
                      "the NED velocity cannot be rotated into the body")
    t_v, v_ned = sorted_unique(_times(lp, start_us), np.stack([lp["vx"], lp["vy"], lp["vz"]], -1))
    checks = {"not finite": ~np.isfinite(v_ned).all(1)}
    flags = [k for k in ("v_xy_valid", "v_z_valid") if k in lp]
    for k in flags:
        checks[f"{k} false"] = sorted_unique(_times(lp, start_us), np.asarray(lp[k], np.float64))[1] < 0.5
    t_a, q = sorted_unique(_times(att, start_us), np.stack([att[f"q[{i}]"] for i in range(4)], -1))
    good_q = np.isfinite(q).all(1) & (np.linalg.norm(q, axis=1) > 0.5)
    t_a, q = t_a[good_q], q[good_q]
    tn = cut(t_v, v_ned, t0, t1)[0]
    step = 1.5 * float(np.median(np.diff(t_v))) if len(t_v) > 1 else 0.0    # the ends: held under one step
    if len(tn) < 2 or tn[0] > t0 + step or tn[-1] < t1 - step:
        return None, (f"velocity_body: not given: vehicle_local_position does not cover the segment "
                      f"{t0:.2f}–{t1:.2f} s")
    bad = {why: int(cut(t_v, m, t0, t1)[1].sum()) for why, m in checks.items()}
    bad = {why: n for why, n in bad.items() if n}
    if bad:
        return None, ("velocity_body: not used: vehicle_local_position's velocity has "
                      + ", ".join(f"{why} on {n}" for why, n in bad.items())
                      + f" of its {len(tn)} samples in the segment (not estimated there: e.g. no GPS or optical "
                      f"flow for the horizontal velocity)")
    if len(t_a) < 2 or t_a[0] > tn[0] + 0.1 or t_a[-1] < tn[-1] - 0.1:
        return None, f"velocity_body: not given: vehicle_attitude does not cover the segment {t0:.2f}–{t1:.2f} s"
    t_v, v_ned = cut(t_v, v_ned, t0, t1)
    q_v = interp_linear(t_a, continuous_quaternions(q), t_v)
    v_body = world_to_body(q_v, v_ned) * FLU_FROM_FRD
    rate_a = 1.0 / float(np.median(np.diff(t_a)))
    said = (f"velocity_body: vehicle_local_position vx, vy, vz (NED, m/s{', ' + ' and '.join(flags) + ' set' if flags else ''}) "
            f"rotated into the body (FRD) by vehicle_attitude q (FRD to NED, {rate_a:.0f} Hz, interpolated to the "
            f"velocity's times), FRD to FLU (y and z negated); interpolated (linear) to 2 ms")
    return (t_v, v_body), said
