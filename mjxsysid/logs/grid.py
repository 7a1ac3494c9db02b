"""The 2 ms grid every log reader resamples onto: segments (``--segment``, the airborne cut), linear
interpolation and zero-order hold, and world-to-body rotation of vectors."""
from __future__ import annotations

import numpy as np

DT = 0.002
"""s: the grid the decoders read (500 Hz)."""

MIN_ROWS = 100
"""Rows (0.2 s at 500 Hz) a segment needs at least: the policy's history."""


def parse_segment(segment):
    """``--segment``: 't0:t1' (seconds since the log's start, either side may be empty) or a pair
    -> (t0 or None, t1 or None); None -> None."""
    if segment is None:
        return None
    if isinstance(segment, str):
        parts = segment.split(":")
        if len(parts) != 2:
            raise ValueError(f"--segment must be T0:T1 in seconds (either may be empty), got {segment!r}")
        try:
            segment = tuple(float(p) if p.strip() else None for p in parts)
        except ValueError:
            raise ValueError(f"--segment must be T0:T1 in seconds, got {segment!r}") from None
    t0, t1 = segment
    if t0 is not None and t1 is not None and not t1 > t0:
        raise ValueError(f"--segment {t0:g}:{t1:g}: the end must come after the start")
    return t0, t1


def interp_linear(t_native, x, grid):
    """Linear interpolation of ``x`` (N, ...) sampled at ``t_native`` onto ``grid`` (clamped at the ends)."""
    x = np.asarray(x, np.float64)
    flat = x.reshape(len(x), -1)
    out = np.stack([np.interp(grid, t_native, flat[:, k]) for k in range(flat.shape[1])], -1)
    return out.reshape((len(grid),) + x.shape[1:])


def hold(t_native, x, grid):
    """Zero-order hold: at each grid time the latest native sample (the first before it starts)."""
    idx = np.clip(np.searchsorted(t_native, grid, side="right") - 1, 0, len(t_native) - 1)
    return np.asarray(x, np.float64)[idx]


def user_segment(path, segment, lo: float, hi: float, clock: str = "seconds since the log's start"):
    """A ``--segment`` 't0:t1' (or a pair) clamped to the log's span lo..hi s -> (t0, t1, why), or None
    when no segment is given; ValueError naming ``path`` when it holds under :data:`MIN_ROWS` steps."""
    seg = parse_segment(segment)
    if seg is None:
        return None
    t0 = lo if seg[0] is None else max(lo, seg[0])
    t1 = hi if seg[1] is None else min(hi, seg[1])
    if not t1 - t0 >= MIN_ROWS * DT:
        raise ValueError(f"{path}: --segment {segment}: {max(t1 - t0, 0):.3g} s of data in it (the log runs "
                         f"{lo:.2f}–{hi:.2f} s, {clock}); need at least {MIN_ROWS * DT:g} s")
    return t0, t1, f"--segment ({clock})"


def cut(t, x, t0: float, t1: float):
    """The native samples (t (N,), x (N, ...)) inside [t0, t1] with one more on each side (for the resampling)."""
    i0 = max(int(np.searchsorted(t, t0, side="right")) - 1, 0)
    i1 = min(int(np.searchsorted(t, t1, side="left")) + 1, len(t))
    return t[i0:i1], np.asarray(x, np.float64)[i0:i1]


def segment_grid(path, t0: float, t1: float):
    """The 2 ms grid (T,) over a segment t0..t1 s; ValueError naming ``path`` when under :data:`MIN_ROWS` steps."""
    n = int(np.floor((t1 - t0) / DT + 1e-9)) + 1
    if n < MIN_ROWS:
        raise ValueError(f"{path}: the segment {t0:.3f}–{t1:.3f} s is shorter than {MIN_ROWS * DT:g} s")
    return t0 + DT * np.arange(n)


def world_to_body(q_wxyz, v):
    """World-frame vectors ``v`` (N, 3) in the body frame of the unit quaternions ``q_wxyz`` (N, 4)
    (w, x, y, z; Hamilton, body to world): Rᵀ v."""
    q = np.asarray(q_wxyz, np.float64)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                  np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                  np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)
    return np.einsum("nji,nj->ni", R, np.asarray(v, np.float64))
