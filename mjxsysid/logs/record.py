"""The log contract's last steps, shared by the readers of non-PX4 formats (DataFlash, ROS bags).

A reader converts its channels to SI units, body frame FLU and mjxsysid's rotor order on their own
timestamps, picks the segment (:func:`pick_segment`) and hands the native samples to
:func:`assemble`, which brings them to the 2 ms grid and says how (``rec["resampled"]``). The binary readers
(ULog, DataFlash, Crazyflie, ROS bags) take their fixed-size records out of the file's bytes with
:func:`gather`; the writers (:mod:`~mjxsysid.logs.formats_write`, :mod:`~mjxsysid.logs.ulog_write`) merge
theirs in time order with :func:`interleave`.
"""
from __future__ import annotations

import numpy as np

from mjxsysid.logs.segment import airborne_segment
from mjxsysid.logs.grid import DT, MIN_ROWS, cut, hold, interp_linear, user_segment

LINEAR, HELD = "interpolated (linear)", "held (zero-order)"


def gather(buf, starts, dtype) -> np.ndarray:
    """The records of ``dtype`` at byte offsets ``starts`` (N,) of ``buf`` (bytes or (B,) uint8) -> (N,) of
    ``dtype`` ((N, k) for a subarray dtype of k items). A view of ``buf`` where the records lie back to back,
    else a copy."""
    buf, dtype, n = np.frombuffer(buf, np.uint8), np.dtype(dtype), len(starts)
    if n > 1 and np.all(np.diff(starts) == dtype.itemsize):
        return np.ndarray((n,), dtype, buf, int(starts[0]))
    rows = np.lib.stride_tricks.sliding_window_view(buf, dtype.itemsize)[starts] if n else np.empty(0, np.uint8)
    return np.ndarray((n,), dtype, rows)


def rate_hz(t) -> float:
    """Native rate of samples at times ``t`` (N,) s: 1 / the median positive step (NaN under two samples)."""
    d = np.diff(np.asarray(t, np.float64))
    d = d[d > 0]
    return float(1.0 / np.median(d)) if d.size else float("nan")


def native_rates(channels: dict) -> tuple[dict, dict]:
    """({name: native rate Hz (median step)}, {name: longest step s}) of ``channels`` {name: (t (N,), ...)}:
    a bursty stream (mavros) has a median rate well above its mean; the longest gap says so."""
    rates = {k: round(rate_hz(c[0]), 2) for k, c in channels.items()}
    gaps = {k: round(float(np.max(np.diff(c[0]))), 4) if len(c[0]) > 1 else float("nan") for k, c in channels.items()}
    return rates, gaps


def rate_text(hz: float) -> str:
    return f"{hz:.0f} Hz" if hz >= 2 else f"{hz:.2g} Hz"


def sorted_unique(t, x):
    """Samples (t (N,), x (N, ...)) in time order, a repeated time stamp kept once (its first sample)."""
    t = np.asarray(t, np.float64)
    o = np.argsort(t, kind="stable")
    t, x = t[o], np.asarray(x, np.float64)[o]
    keep = np.concatenate([[True], np.diff(t) > 0])
    return t[keep], x[keep]


def pick_segment(path, segment, t_motor, motor, span, within=None, within_why=""):
    """(t0, t1, why): ``segment`` ('t0:t1' or a pair, in the reader's clock) clamped to ``span``
    (lo, hi) s, else :func:`~mjxsysid.logs.segment.airborne_segment` on the native motor commands
    ``motor`` (N, 4) at ``t_motor`` (N,) s, restricted to ``within`` (a0, a1) s when given (an armed
    stretch, said by ``within_why``). ValueError naming ``path`` when under :data:`MIN_ROWS` steps."""
    given = user_segment(path, segment, *span, clock="the reader's clock")
    if given is not None:
        return given
    lo, hi = span
    t_motor = np.asarray(t_motor, np.float64)
    keep = np.ones(len(t_motor), bool) if within is None else (t_motor >= within[0]) & (t_motor <= within[1])
    try:
        t0, t1, why = airborne_segment(t_motor[keep], np.asarray(motor)[keep])
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    t0, t1 = max(t0, lo), min(t1, hi)
    if not t1 - t0 >= MIN_ROWS * DT:
        raise ValueError(f"{path}: the airborne segment {t0:.2f}–{t1:.2f} s is shorter than {MIN_ROWS * DT:g} s; "
                         f"give the flight's part with --segment t0:t1")
    return t0, t1, (within_why + "; " if within_why else "") + why


def assemble(channels: dict, t0: float, t1: float) -> dict:
    """The contract's arrays on the 2 ms grid t0..t1 from ``channels`` {name: (t (N,) s, values (N, ...),
    LINEAR or HELD)} -> {"t", name: (T, ...), "native": {name: (t, values) in the segment},
    "resampled": {name: "native (N Hz)" or "<how> from N Hz"}}."""
    n = int(np.floor((t1 - t0) / DT + 1e-9)) + 1
    grid = t0 + DT * np.arange(n)
    rec, native, resampled = {"t": grid}, {}, {}
    for name, (t, x, how) in channels.items():
        tn, xn = cut(t, x, t0, t1)
        native[name] = (tn, xn)
        rec[name] = (interp_linear if how == LINEAR else hold)(tn, xn, grid)
        r = rate_hz(t)
        resampled[name] = f"{how} from {rate_text(r)}" if abs(r * DT - 1) > 0.05 else f"native ({rate_text(r)})"
    rec["native"], rec["resampled"] = native, resampled
    return rec


def body_velocity_from_world(v_world, R_world_body):
    """Velocity in the body frame (N, 3): Rᵀ v for world velocities ``v_world`` (N, 3) and the rotations
    ``R_world_body`` (N, 3, 3) taking body vectors to world vectors (same frames' handedness)."""
    return np.einsum("nji,nj->ni", R_world_body, v_world)


def interleave(blocks, chunk: int = 1 << 17) -> bytes:
    """Records of several types in time order: ``blocks`` [(stamps (N,), rows (N, size) uint8)], records
    of equal stamps in block order -> their bytes, concatenated."""
    stamps = np.concatenate([np.asarray(s, np.float64) for s, _ in blocks])
    kind = np.concatenate([np.full(len(s), k) for k, (s, _) in enumerate(blocks)])
    index = np.concatenate([np.arange(len(s)) for s, _ in blocks])
    sizes = np.array([r.shape[1] for _, r in blocks], np.int64)
    flat = np.concatenate([np.ascontiguousarray(r, np.uint8).reshape(-1) for _, r in blocks])
    base = np.concatenate([[0], np.cumsum([r.size for _, r in blocks])[:-1]]).astype(np.int64)
    order = np.lexsort((index, kind, stamps))
    out = []
    for i in range(0, len(order), chunk):              # bounded memory: gather a chunk of records at a time
        o = order[i:i + chunk]
        k = kind[o]
        start, size = base[k] + index[o] * sizes[k], sizes[k]
        first = np.cumsum(size) - size
        out.append(flat[np.repeat(start - first, size) + np.arange(int(size.sum()))].tobytes())
    return b"".join(out)
