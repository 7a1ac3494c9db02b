"""The drag a log shows: the body drag per mass the log-grounded posterior fits through a log's velocity
(x, y from the accelerometer's x and y, z from its term at the mode) against the truth d / m, on MJX flights
(the lag-aware oracle, 10 s lemniscate, clean IMU) of vehicles of a prior.

    python benchmarks/log_drag.py --vehicles 4 [--prior default] [--seed 3]
"""
from __future__ import annotations

import argparse
import json

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.identify import log_grounded_posterior
from mjxsysid.rollout.flight import flight_log, fly_vehicles


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=4)
    ap.add_argument("--prior", default="default")
    ap.add_argument("--seed", type=int, default=3)
    a = ap.parse_args()
    th = np.asarray(P.get_prior(a.prior).sample(jax.random.PRNGKey(a.seed), a.vehicles))
    fl, _, _ = fly_vehicles(th, controller="oracle", reference="lemniscate", period=10.0, seed=a.seed + 1)
    rows = []
    for i in range(a.vehicles):
        post = log_grounded_posterior(flight_log(fl.frame, i), None, samples=64, particles=256, seed=i)
        fit, true = np.asarray(post["drag_per_mass"], float), th[i, P.DRAG] / th[i, P.MASS]
        rows.append({"vehicle": i, "log": np.round(fit, 4).tolist(), "true": np.round(true.astype(float), 4).tolist()})
        print(json.dumps(rows[-1]))
    err = np.array([np.abs(np.array(r["log"]) - np.array(r["true"])) for r in rows])
    print(json.dumps({"max_abs_error_per_axis": np.round(err.max(0), 4).tolist()}))


if __name__ == "__main__":
    main()
