"""How well the tuner's predictive rollouts reproduce the flight (issue 26): each vehicle flown by
the shipped policy under the Baseline gains for 2 s of a random min-snap, then the next 0.5 s
flown on and predicted with the true θ, the rotors started from each model's estimate (the
tuner's default), from the steady state of the last command (the tuner before 2026-11-25) and
from the simulator's true rotor speeds (a diagnostic), on the default prior, the slow-actuator
prior and the paper vehicle with the "hardware" IMU (noise, bias, one step of latency).

    python tools/prediction_error.py --vehicles 16 --out docs/runs/tuning/prediction_error
"""
import argparse
import json
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.experiments.tuning import HARDWARE_SIM
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.render.tuning import plot_prediction_error
from mjxsysid.rollout.flight import random_minsnaps
from mjxsysid.sim import Quadrotor
from mjxsysid.tune.tuner import prediction_error


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=16)
    ap.add_argument("--start", type=float, default=2.0, help="s flown before the prediction")
    ap.add_argument("--horizon", type=float, default=0.5, help="s predicted")
    ap.add_argument("--out", default="docs/runs/tuning/prediction_error")
    a = ap.parse_args(argv)
    n = a.vehicles
    policy = resolve_policy("mjxsysid")
    cases = {}
    for name, prior, cfg in (("default prior", "default", None), ("slow actuators (τ_m 0.05–0.10 s)", "slow_actuators", None),
                             ("default prior, hardware IMU", "default", HARDWARE_SIM)):
        sim = Quadrotor(cfg) if cfg is not None else Quadrotor()
        theta = np.asarray(P.get_prior(prior).sample(jax.random.PRNGKey(0), n))
        start, steps = (int(round(x / sim.config.dt)) for x in (a.start, a.horizon))
        cases[name] = prediction_error(sim, theta, policy.batched(n), random_minsnaps(n, 0, a.start + a.horizon + 0.5),
                                       start=start, steps=steps)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    plot_prediction_error(cases, out / "prediction_error.png",
                          title=f"Predicted vs flown, true θ, {n} vehicles: position error over the horizon")
    summary = {name: {mode: {"pos_err_end_median_m": float(np.median(c[mode]["pos_err"][:, -1])),
                             "pos_err_end_p95_m": float(np.percentile(c[mode]["pos_err"][:, -1], 95)),
                             "pos_err_max_m": float(c[mode]["pos_err"].max()),
                             "rotor_err_median_rad_s": float(np.median(c[mode]["rotor_err"]))}
                      for mode in ("estimate", "steady", "true")} for name, c in cases.items()}
    summary["config"] = {"vehicles": n, "start_s": a.start, "horizon_s": a.horizon, "gains": "baseline",
                         "policy": "mjxsysid (shipped)", "reference": "random min-snap, seed 0"}
    (out / "prediction_error.json").write_text(json.dumps(summary, indent=1))
    for name, c in summary.items():
        if name != "config":
            print(name, {m: f"{v['pos_err_end_median_m'] * 1e3:.3g} mm (p95 {v['pos_err_end_p95_m'] * 1e3:.3g})" for m, v in c.items()})


if __name__ == "__main__":
    main()
