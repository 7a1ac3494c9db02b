"""The IMU's white-noise level from the log alone, and the limit past which the decoders are not
calibrated (docs/noise.md)."""
from __future__ import annotations

import numpy as np

from mjxsysid.logs.checks.findings import Finding
from mjxsysid.logs.checks.rates import column_rates, is_resampled
from mjxsysid.logs.checks.signals import DT, FIT_ROWS, fit_rows

NOISE_DIFF_ORDER = 2
"""The finite difference whose spread estimates the IMU noise: for white noise of std σ the k-th
difference has std σ √C(2k, k) (√6 for k = 2), while a smooth signal's shrinks by dt² per order."""

IMU_NOISE_LIMIT = {"gyro_noise": 0.015, "accel_noise": 0.15}
"""rad/s and m/s² per 2 ms sample: the white-noise level past which :func:`check_imu_noise` warns.
The shipped decoders were trained on flights without IMU noise and the policy with gyro 0.005 rad/s
and accelerometer 0.05 m/s²; at twice that (0.01 / 0.1, the tuning experiment's hardware-like
simulator) their 90 % intervals cover the truth as often as on clean flights, at four times that the
angular authorities' coverage falls 6–10 points, at ten times 25 (docs/noise.md): the limit lies
between, at three times. Correct logs of the prior read at most 0.008 rad/s (docs/decoding.md)."""


def imu_noise_limit(*decoders) -> dict:
    """The IMU noise past which a log is flagged, for these decoders (objects with a ``meta``
    dict, as :func:`~mjxsysid.cfm.load.load_decoders` returns; None entries skipped): the IMU their
    training pairs flew (``meta['data']['pairs_meta']['imu']``, recorded by ``collect``) where it
    reaches past :data:`IMU_NOISE_LIMIT` — white noise or rotor vibration, the larger, per sensor;
    with ``randomize_imu`` those are the maxima of the per-flight levels — else
    :data:`IMU_NOISE_LIMIT`. Several decoders: the strictest (the smallest limit)."""
    limits = []
    for d in decoders:
        imu = ((getattr(d, "meta", None) or {}).get("data") or {}).get("pairs_meta", {}).get("imu")
        if not imu:
            limits.append(dict(IMU_NOISE_LIMIT))
            continue
        trained = {"gyro_noise": max(float(imu.get("gyro_noise", 0.0)), float(imu.get("gyro_vibration", 0.0))),
                   "accel_noise": max(float(imu.get("accel_noise", 0.0)), float(imu.get("accel_vibration", 0.0)))}
        limits.append({k: max(IMU_NOISE_LIMIT[k], trained[k]) for k in IMU_NOISE_LIMIT})
    if not limits:
        return dict(IMU_NOISE_LIMIT)
    return {k: min(lim[k] for lim in limits) for k in IMU_NOISE_LIMIT}


def estimate_imu_noise(rec: dict) -> dict:
    """The IMU's white-noise level per sample from the log alone: 1.4826 · MAD of the
    :data:`NOISE_DIFF_ORDER`-th difference of each channel over √C(2k, k), the median over the
    three axes -> ``gyro_noise`` (rad/s), ``accel_noise`` (m/s²). A per-flight bias does not enter
    (differences remove it); narrow-band vibration counts as far as it reaches the upper band (a
    tone at a quarter of the sampling rate or above reads as about its std, far below it less).
    The first 0.2 s are skipped (take-off); a long log reads :func:`fit_rows` of it. An IMU
    resampled from a lower rate (:func:`column_rates`) is read at its native samples: the level
    is then per native sample (``imu_rate_hz`` says at which rate)."""
    from math import comb
    imu = None
    rate, _, nat = column_rates(rec)["imu"]
    if nat is not None and len(nat[1]) >= 4 * (NOISE_DIFF_ORDER + 2):
        imu = nat[1][-FIT_ROWS:]        # interpolated values have no noise: read the native samples
    if imu is None:                     # (a few "native" samples: a held constant column, read as logged)
        imu = np.asarray(fit_rows(rec)["imu"], np.float64)
    skip = int(round(0.2 * rate))           # the first 0.2 s (take-off)
    imu = imu[min(skip, len(imu) // 4):]
    k = NOISE_DIFF_ORDER
    d = np.diff(imu, n=k, axis=0)
    sd = 1.4826 * np.median(np.abs(d - np.median(d, 0)), 0) / np.sqrt(comb(2 * k, k))
    return {"gyro_noise": float(np.median(sd[:3])), "accel_noise": float(np.median(sd[3:])), "imu_rate_hz": float(rate)}


def check_imu_noise(rec: dict, limit: dict | None = None, est: dict | None = None) -> list[Finding]:
    """A warning if the IMU noise :func:`estimate_imu_noise` finds (or ``est``) is past ``limit``
    (default :data:`IMU_NOISE_LIMIT`) on the gyro or the accelerometer."""
    limit = IMU_NOISE_LIMIT if limit is None else limit
    est = estimate_imu_noise(rec) if est is None else est
    over = [k for k in ("gyro_noise", "accel_noise") if est[k] > limit[k]]
    if not over:
        return []
    cols = ", ".join(c for k, c in (("gyro_noise", "gyro_x/y/z"), ("accel_noise", "acc_x/y/z")) if k in over)
    rate = est.get("imu_rate_hz", 1.0 / DT)
    per = "per sample" if not is_resampled(rate) else f"per native sample at {rate:.3g} Hz"
    return [Finding("warning", cols, f"IMU noise about {est['gyro_noise']:.2g} rad/s (gyro) and "
                    f"{est['accel_noise']:.2g} m/s² (accelerometer) {per}, from the log's sample-to-sample "
                    f"changes: past what the decoders were calibrated under ({limit['gyro_noise']:g} rad/s, "
                    f"{limit['accel_noise']:g} m/s²). High-frequency IMU noise (rotor vibration, an unfiltered "
                    f"sensor) reads as a smaller, quicker vehicle: the decoded bands are likely too low in mass "
                    f"and inertia and too high in angular authority, and not calibrated. Fly with the IMU "
                    f"filtered or the vibration damped (the policy must read the same IMU the log records); "
                    f"docs/noise.md")]
