"""A rotor vibration in the gyro, and the fixed filter that whitens it for the innovations' rate term.

A rotor's vibration reaches the gyro as a narrow-band oscillation at the (aliased) rotor frequency:
coloured measurement noise. The innovations' steady-state Kalman filter (:mod:`.likelihood`) models the
measurement noise as white; under a vibration its prediction errors are coloured, the controller's
reaction to the vibration correlates with them, and the prediction-error fit reads the vibration as
rate signal (τ_m 95 % off on simulated flights at × 5 vibration). Here the gyro's noise spectrum per
axis is estimated where the body's own rates have no power (above :data:`BODY_HZ`, continued flat
below it), and an autoregressive filter A (q) of order :data:`ORDER` is fitted to it (Yule–Walker):
A n is white for that noise n. The innovations are then those of the model y = ω + n with n = ε / A,
ε white: the same Kalman filter run on A y with the regressors filtered by A (A commutes with the
filter: both are time-invariant), the Box–Jenkins form of the prediction-error method (Ljung, *System
Identification*, §4.2 and §13), with the noise model's coloured part fixed per log. A log without a
spectral peak keeps A = 1 (its innovations unchanged).
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import solve_toeplitz
from scipy.signal import welch

BODY_HZ = 15.0
"""Hz: below it the gyro carries the body's own rates (a flight's manoeuvres and its controller's
response); above it, on a simulated clean flight, the rates' spectrum is 1e-3 of the × 1 white noise's
and falling. The noise's spectrum is estimated above it and continued flat below."""
ORDER = 16
"""The whitening filter's order: room for a resonance whose frequency follows the rotor speeds over a flight
(on simulated × 5 vibration flights the spectrum is above a tenth of its peak over 55–105 Hz). Not tuned:
the first value tried, τ_m within 2 % on them."""
PEAK_RATIO = 10.0
"""A vibration is detected on an axis where the spectrum's peak above :data:`BODY_HZ` + 10 Hz is at least
this many times its 10th percentile above :data:`BODY_HZ` (white noise: 1.7–2.1 on 10 s simulated logs;
the simulator's × 5 vibration: 78–1800) ..."""
RISE = 2.5
"""... and at least this many times its level at :data:`BODY_HZ` (the median of the next 10 Hz): a peak,
not the body's spectrum falling from below (a clean log: 0.18–0.22; white noise 0.9–1.6; × 5
vibration 3.4–1700)."""
FLOOR = 1e-4
"""The noise spectrum's floor relative to its peak: the whitening filter's depth at the peak is at most
1 / FLOOR in power (a float32 Gram matrix's range; a deeper notch is not better determined)."""
SEGMENT = 256
"""Samples per Welch segment (0.5 s at 500 Hz: 2 Hz bins)."""


def noise_spectrum(y: np.ndarray, dt: float, max_hz: float | None = None) -> tuple[np.ndarray, np.ndarray, bool]:
    """The noise's one-sided spectral density of gyro axis samples y (n,) at spacing ``dt`` s ->
    (frequencies (F,) Hz, density (F,), whether a vibration peak is detected (:data:`PEAK_RATIO`)): the
    Welch estimate above :data:`BODY_HZ`, its level there (the median of the next 10 Hz) below, at least
    :data:`FLOOR` × its peak. ``max_hz``: the detection looks below it only (the gyro's native Nyquist
    frequency, where a log was resampled: above it lie the resampling's images, not the rotors)."""
    f, p = welch(np.asarray(y, np.float64), fs=1.0 / dt, nperseg=min(SEGMENT, len(y)), detrend="linear")
    band = f >= BODY_HZ
    if band.sum() < 4 or not np.all(np.isfinite(p)):
        return f, p, False              # too short a log, or a non-finite reading: nothing detected
    low = float(np.median(p[band & (f < BODY_HZ + 10.0)]))
    q = np.where(band, p, low)
    upper = f >= BODY_HZ + 10.0
    peak = float(p[upper].max())
    seen = band & (f <= (np.inf if max_hz is None else max_hz))
    look = seen & upper
    if look.sum() < 4:                  # a gyro logged too slowly to show a rotor's frequency
        return f, np.maximum(q, FLOOR * peak), False
    top = float(p[look].max())          # the peak below max_hz (``peak`` without it)
    detected = bool(top > PEAK_RATIO * max(float(np.percentile(p[seen], 10)), 1e-30) and top > RISE * low)
    return f, np.maximum(q, FLOOR * peak), detected


def detected_axes(gyro: np.ndarray, dt: float, max_hz: float | None = None) -> np.ndarray:
    """Whether each axis of ``gyro`` (n, 3) shows a rotor vibration below ``max_hz`` (:func:`noise_spectrum`)
    -> (3,) bool."""
    return np.array([noise_spectrum(gyro[:, a], dt, max_hz)[2] for a in range(3)], bool)


def whitening_filter(density: np.ndarray, order: int = ORDER) -> tuple[np.ndarray, float]:
    """The autoregressive whitening polynomial of a one-sided spectral density (F,) on a uniform grid
    from 0 to the Nyquist frequency -> (a (order + 1,), a[0] = 1, the prediction error's variance
    relative to the noise's): Yule–Walker on the density's autocorrelation."""
    r = np.fft.irfft(np.asarray(density, np.float64))[:order + 1]
    if not r[0] > 0:
        raise ValueError(f"a noise spectrum with no power (autocorrelation at lag 0: {r[0]}): nothing to whiten")
    r = r / r[0]
    a = solve_toeplitz(r[:order], -r[1:order + 1])
    err = float(1.0 + a @ r[1:order + 1])
    return np.concatenate([[1.0], a]), max(err, 1e-12)


def gyro_whiteners(gyro: np.ndarray, dt: float, order: int = ORDER,
                   max_hz: float | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per gyro axis of ``gyro`` (n, 3): the whitening polynomial (3, order + 1), the variance of the
    whitened noise ε = A n (3,) in the gyro's units squared, and whether a vibration was detected (3,).
    Axes without a detected vibration below ``max_hz`` get A = 1 and NaN; if none has one, the polynomials are
    (3, 1)."""
    out = np.zeros((3, order + 1))
    out[:, 0] = 1.0
    eps = np.full(3, np.nan)
    found = np.zeros(3, bool)
    for a in range(3):
        f, dens, found[a] = noise_spectrum(gyro[:, a], dt, max_hz)
        if found[a]:
            out[a], err = whitening_filter(dens, order)
            eps[a] = err * float(np.sum(dens) * (f[1] - f[0]))      # the noise's variance × the error's share
    return (out if found.any() else out[:, :1]), eps, found
