"""How well the tuner's predictive rollouts reproduce the flight: each vehicle flown by
the shipped policy under the Baseline gains for 2 s of a random min-snap, then the next 0.5 s
flown on and predicted with the true θ, the rotors started from each model's estimate (the
tuner's default), from the steady state of the last command (the tuner's ``steady`` mode) and
from the simulator's true rotor speeds (a diagnostic), on the default prior, the slow-actuator
prior and the paper vehicle with the "hardware" IMU (noise, bias, one step of latency).

    mjxsysid experiment prediction-error --out docs/runs/measurements/prediction-error    # 16 vehicles
"""
from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.experiments.common import leaf_table, write_results
from mjxsysid.experiments.tuning import HARDWARE_SIM
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.render.tuning import plot_prediction_error
from mjxsysid.rollout.flight import random_minsnaps
from mjxsysid.sim import Quadrotor
from mjxsysid.tune.tuner import prediction_error

START_S, HORIZON_S = 2.0, 0.5
"""Seconds flown before the prediction, and seconds predicted."""


def run(out, *, quick=False, policy=None, seed=0, progress=True) -> dict:
    """Predicted against flown position error (see the module doc) into OUT/results.json and
    OUT/prediction_error.png: 16 vehicles per case (``quick``: 2), θ and references drawn with
    ``seed``."""
    t0 = time.time()
    n = 2 if quick else 16
    policy = resolve_policy(policy or "mjxsysid")
    cases = {}
    for name, prior, cfg in (("default prior", "default", None), ("slow actuators (τ_m 0.05–0.10 s)", "slow_actuators", None),
                             ("default prior, hardware IMU", "default", HARDWARE_SIM)):
        sim = Quadrotor(cfg) if cfg is not None else Quadrotor()
        theta = np.asarray(P.get_prior(prior).sample(jax.random.PRNGKey(seed), n))
        start, steps = (int(round(x / sim.config.dt)) for x in (START_S, HORIZON_S))
        cases[name] = prediction_error(sim, theta, policy.batched(n), random_minsnaps(n, seed, START_S + HORIZON_S + 0.5),
                                       start=start, steps=steps)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_prediction_error(cases, out / "prediction_error.png",
                          title=f"Predicted vs flown, true θ, {n} vehicles: position error over the horizon")
    summary = {name: {mode: {"pos_err_end_median_m": float(np.median(c[mode]["pos_err"][:, -1])),
                             "pos_err_end_p95_m": float(np.percentile(c[mode]["pos_err"][:, -1], 95)),
                             "pos_err_max_m": float(c[mode]["pos_err"].max()),
                             "rotor_err_median_rad_s": float(np.median(c[mode]["rotor_err"]))}
                      for mode in ("estimate", "steady", "true")} for name, c in cases.items()}
    config = {"quick": quick, "vehicles": n, "start_s": START_S, "horizon_s": HORIZON_S, "gains": "baseline",
              "reference": f"random min-snap, seed {seed}"}
    if progress:
        for name, c in summary.items():
            print(name, {m: f"{v['pos_err_end_median_m'] * 1e3:.3g} mm (p95 {v['pos_err_end_p95_m'] * 1e3:.3g})" for m, v in c.items()})
    numbers = {**summary, "headline": {f"{name}_estimate_median_m": c["estimate"]["pos_err_end_median_m"]
                                       for name, c in summary.items()}}
    return write_results(out, "prediction-error", config=config, seeds={"seed": seed}, numbers=numbers,
                         table_md=leaf_table(summary), t0=t0, policy=policy)
