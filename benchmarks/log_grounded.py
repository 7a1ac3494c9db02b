"""The log-grounded posterior (mjxsysid.identify) on simulated flights: coverage, widths, time.

Flies N vehicles of a prior with the lag-aware oracle (MJX simulator, 10 s lemniscate) at each IMU
noise level of :data:`mjxsysid.uses.imu_noise.LEVELS` asked for (clean, × 1 white + bias, × 5 white,
× 5 rotor vibration, × 20 white + bias: the decoders' noise study's levels), runs the
log-grounded posterior on each flight's IMU and motor commands (no decoded proposal: the prior
and the log alone), and reports per log-identifiable quantity whether the truth is inside the
90 % band and the band's width, plus the seconds per log.

    python benchmarks/log_grounded.py --vehicles 24 --levels clean,x1,x5_white,x5_vibration,x20 \
        --out docs/runs/measurements/log-grounded/calibration.json
    python benchmarks/log_grounded.py --prior weak_motor --vehicles 12 \
        --out docs/runs/measurements/log-grounded/families/weak_motor.json    # a held-out family
    python benchmarks/log_grounded.py --summarise docs/runs/measurements/log-grounded/families

Many vehicles in parallel processes (one GPU or several): ``--shard i/k`` flies and identifies
every k-th vehicle of the same draw, from the i-th on (vehicle indices, posterior seeds and
truths are those of the unsharded run; the flights' noise draws depend on the batch, so the
numbers are those of another draw of the same noise); ``--merge OUT SHARD.json ...`` joins the
shards into one run::

    for i in 0 1 2 3 4 5 6 7; do python benchmarks/log_grounded.py --vehicles 200 --shard $i/8 \
        --out /tmp/cal/$i.json & done; wait
    python benchmarks/log_grounded.py --merge calibration-200.json /tmp/cal/*.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import numpy as np
from _bench import merge_paths, shard

from mjxsysid import theta as P
from mjxsysid.experiments.log_grounded_coverage import RATES, compact_json, figure, merge, run_level, summarise


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--figure-only", default=None, help="draw the figure of an earlier run's JSON and exit")
    ap.add_argument("--summarise", default=None, metavar="DIR",
                    help="one table (DIR/summary.md) and heat map (DIR/coverage.png) of the runs in DIR, and exit")
    ap.add_argument("--vehicles", type=int, default=24)
    ap.add_argument("--levels", default="clean,x1,x5_white,x5_vibration,x20")
    ap.add_argument("--prior", default="wide_actuators",
                    help="a prior or a held-out family (mjxsysid.theta.priors.HELDOUT_FAMILIES: out of the decoders' prior)")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--shard", default=None, metavar="I/K", help="identify every K-th vehicle from the I-th (parallel runs; join with --merge)")
    ap.add_argument("--merge", nargs="+", default=None, metavar=("OUT", "SHARD"),
                    help="join the JSON files of --shard runs into OUT and exit")
    ap.add_argument("--out", default=None)
    ap.add_argument("--drag", type=float, default=None, metavar="KG_PER_S",
                    help="a diagnostic: fly every vehicle with this body drag on each axis (the likelihood has no drag "
                         "term; e.g. 1e-6 to take it out of the flights)")
    ap.add_argument("--no-velocity", action="store_true",
                    help="logs without the body velocity (the likelihood's drag term then vanishes)")
    ap.add_argument("--rates", default=RATES, choices=("innovations", "windows"),
                    help="the posterior's rate term (default: the library's)")
    a = ap.parse_args()
    try:
        _main(a)
    except ValueError as e:
        raise SystemExit(str(e)) from None


def _main(a):
    if a.merge:
        res = merge(*merge_paths(a.merge))
        for lv in res["levels"]:
            print(json.dumps({k: v for k, v in lv.items() if k != "rows"}))
        return
    if a.summarise:
        print(summarise(Path(a.summarise)), end="")
        return
    if a.figure_only:
        figure(json.loads(Path(a.figure_only).read_text()), Path(a.figure_only).with_suffix(".png"))
        return
    prior = P.get_prior(a.prior)
    # a held-out family (out of the decoders' prior): its fixed, validated and flyable evaluation vehicles
    th = (prior.vehicles(a.vehicles) if a.prior in P.HELDOUT_FAMILIES
          else np.asarray(prior.sample(jax.random.PRNGKey(a.seed), a.vehicles)))
    if a.drag is not None:
        if not a.drag > 0:
            raise SystemExit(f"--drag must be > 0 kg/s, got {a.drag}")
        th = np.array(th, np.float32)
        th[:, P.DRAG] = a.drag
    th, index, flight_seed = shard(th, a.shard, a.seed)   # the flights' noise: another draw per shard
    res = {"command": "python benchmarks/log_grounded.py " + " ".join(f"--{k} {v}" for k, v in vars(a).items()
                                                                        if v is not None),
           "prior": a.prior, "rates": a.rates, "velocity": not a.no_velocity, "drag": a.drag, "vehicles": a.vehicles, "seed": a.seed, "shard": a.shard,
           "levels": []}
    for lv in a.levels.split(","):
        r = run_level(th, lv, flight_seed, index, a.rates, velocity=not a.no_velocity)
        res["levels"].append(r)
        print(json.dumps({k: v for k, v in r.items() if k != "rows"}), flush=True)
        if a.out:
            Path(a.out).parent.mkdir(parents=True, exist_ok=True)
            Path(a.out).write_text(compact_json(res))
            figure(res, Path(a.out).with_suffix(".png"))


if __name__ == "__main__":
    main()
