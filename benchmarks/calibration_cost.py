"""The calibration's own cost inside ``decode --log``: the log-grounded posterior of one 10 s simulated
log with and without the shipped calibration (``calibration="shipped"`` against ``None``), warm, in one
process, alternating (shared machines are noisy: compare within one run).

    python benchmarks/calibration_cost.py --repeats 5
"""
import argparse
import json
import time

import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    from mjxsysid import theta as P
    from mjxsysid.identify.inference import log_grounded_posterior
    from mjxsysid.identify.logdata import prepare
    from mjxsysid.rollout.flight import flight_log, fly_vehicles
    fl, _, _ = fly_vehicles(P.paper_hardware()[None], controller="oracle", reference="lemniscate", period=10.0)
    data = prepare(flight_log(fl.frame, 0))
    log_grounded_posterior(data, None, seed=0)                       # compile
    times = {"shipped": [], "none": []}
    for r in range(a.repeats):
        for cal in ("shipped", None):
            t = time.perf_counter()
            log_grounded_posterior(data, None, seed=r, calibration=cal)
            times["shipped" if cal else "none"].append(time.perf_counter() - t)
    med = {k: float(np.median(v)) for k, v in times.items()}
    print(json.dumps({"median_s": med, "ratio": med["shipped"] / med["none"], "runs": times}))


if __name__ == "__main__":
    main()
