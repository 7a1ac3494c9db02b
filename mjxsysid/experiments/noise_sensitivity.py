"""Decoder calibration under IMU noise (docs/noise.md): the shipped policy (or ``--policy``) flies
held-out vehicles of the decoders' prior with white noise, a per-flight bias and rotor vibration
on the IMU it reads, and its decoders (or ``--decoders``) decode the latents of each flight.

    mjxsysid experiment noise-sensitivity --out docs/runs/measurements/noise-sensitivity
    mjxsysid experiment noise-sensitivity --variant low --out …     # clean, × 0.5 and × 1 white

The measurement is :func:`mjxsysid.uses.imu_noise.noise_sensitivity` (its module doc says what
it measures); this experiment runs it, writes results.json and results.md (its table) and draws
noise_sensitivity.png. The `noise` stage of `mjxsysid release` runs the same measurement on a
release's policy and decoders.
"""
from __future__ import annotations

import time
from pathlib import Path

from mjxsysid.experiments.common import write_results
from mjxsysid.uses.imu_noise import DEFAULT_LEVELS, figure, noise_sensitivity, table

FULL = {"vehicles": 128, "seconds": 4.0, "samples": 100}
"""The docs' sizes (those of the release's noise stage)."""
QUICK = {"vehicles": 10, "seconds": 1.0, "samples": 20}
VARIANTS = {"low": ("clean", "x0.5_white", "x1_white")}
"""Levels other than :data:`~mjxsysid.uses.imu_noise.DEFAULT_LEVELS`, by variant name."""


def run(out, *, quick=False, policy=None, seed=4242, progress=True, decoders=None, variant=None) -> dict:
    """Noise sensitivity into OUT/results.json (``numbers``: the measurement's dict), results.md
    (its table) and OUT/noise_sensitivity.png. ``seed`` draws the held-out vehicles (the pairs
    used 0 and 1); ``decoders``: a folder with cfm.npz, regression.npz and cfm_seq.npz (default:
    the policy's shipped ones); ``variant`` 'low': the levels below × 1."""
    if variant is not None and variant not in VARIANTS:
        raise ValueError(f"noise-sensitivity has no variant {variant!r}; choose from {', '.join(VARIANTS)}")
    t0 = time.time()
    sz = QUICK if quick else FULL
    levels = VARIANTS[variant] if variant else tuple(DEFAULT_LEVELS)
    res = noise_sensitivity(policy=policy or "mjxsysid", decoders=decoders, seed=seed, levels=levels,
                            log=(lambda m: print(m, flush=True)) if progress else (lambda m: None), **sz)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figure(res, out / "noise_sensitivity.png")
    head = {f"{lv}_flight_level_identifiable_within_5": v["flight_level"]["identifiable_90_within_5_points"]
            for lv, v in res["levels"].items()}
    return write_results(out, "noise-sensitivity", config={"quick": quick, "variant": variant, "levels": list(levels),
                                                           **sz}, seeds={"seed": seed}, numbers={**res, "headline": head},
                         table_md=table(res), t0=t0)
