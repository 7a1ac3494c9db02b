"""Which latents each decode time conditions on (``--window``: the whole flight so far, a sliding
window of seconds, or the instant latent), and the decode times themselves."""
from __future__ import annotations

import numpy as np


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
