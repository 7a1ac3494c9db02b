"""The log-grounded posterior (mjxsysid.identify) on simulated flights: coverage, widths, time.

Flies N vehicles of a prior with the lag-aware oracle (MJX simulator, 10 s lemniscate, optional
white IMU noise × the hardware-like level: gyro 0.01 rad/s, accelerometer 0.1 m/s²), runs the
log-grounded posterior on each flight's IMU and motor commands (no decoded proposal: the prior
and the log alone), and reports per log-identifiable quantity whether the truth is inside the
90 % band and the band's width, plus the seconds per log.

    python benchmarks/log_grounded.py --vehicles 6 --noise 0 --out out/log_grounded.json
"""
from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np

from mjxsysid import params as P
from mjxsysid.identify.coords import LOG_NAMES, log_quantities
from mjxsysid.identify.inference import log_grounded_posterior
from mjxsysid.rollout.flight import fly_vehicles, seen_imu
from mjxsysid.sim import Quadrotor, SimConfig


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, default=6)
    ap.add_argument("--noise", type=float, default=0.0, help="× the hardware-like white IMU noise")
    ap.add_argument("--prior", default="wide_actuators")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    th = np.asarray(P.get_prior(a.prior).sample(jax.random.PRNGKey(a.seed), a.vehicles))
    sim = Quadrotor(SimConfig(gyro_noise=0.01 * a.noise, accel_noise=0.1 * a.noise))
    fl, m, _ = fly_vehicles(th, controller="oracle", reference="lemniscate", period=10.0, sim=sim)
    rows = []
    for i in range(a.vehicles):
        rec = {"imu": seen_imu(np.asarray(fl.frame.imu[i])), "motor": np.asarray(fl.frame.motor_cmd[i])}
        t0 = time.perf_counter()
        post = log_grounded_posterior(rec, None, seed=i)
        sec = time.perf_counter() - t0
        q, tq = log_quantities(post["theta"]), log_quantities(th[i])
        lo, hi = np.percentile(q, [5, 95], 0)
        rows.append({"seconds": sec, "method": post["method"], "inside": ((lo <= tq) & (tq <= hi)).tolist(),
                     "rel_error_median": (np.abs(np.median(q, 0) / tq - 1)).tolist(),
                     "log_width": np.log(hi[[0, 1, 2, 3]] / lo[[0, 1, 2, 3]]).tolist()})
        print(f"vehicle {i}: {sec:.1f} s, {post['method']}, inside {int(sum(rows[-1]['inside']))}/{len(LOG_NAMES)}", post.get("laplace_is"), np.round(post["weights"], 3))
    inside = np.array([r["inside"] for r in rows])
    err = np.array([r["rel_error_median"] for r in rows])
    res = {"vehicles": a.vehicles, "noise": a.noise, "prior": a.prior,
           "coverage_90": dict(zip(LOG_NAMES, inside.mean(0).round(3).tolist())),
           "median_rel_error_of_median": dict(zip(LOG_NAMES, np.median(err, 0).round(4).tolist())),
           "seconds_median": float(np.median([r["seconds"] for r in rows])), "rows": rows}
    print(json.dumps({k: v for k, v in res.items() if k != "rows"}, indent=1))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(res, f, indent=1)


if __name__ == "__main__":
    main()
