"""Closed-loop fidelity of decoded models (issue 5 item 4, extended to 20 vehicles in issue 11).

The paper vehicle and ``--vehicles - 1`` prior vehicles hover 4 s with a constant [1, 1, 0] N
world force from 0.5 s (prior vehicles: the force scaled by m / m_paper, the same acceleration);
``--models`` decoded models (flight-level posterior from every ẑ at 10 Hz of a held-out,
undisturbed 4 s identification lemniscate, or ``--window instant``: its last ẑ;
``--identification same``: the test flight's own latents, as measured before 2026-11-25) vs as
many ±20 % perturbations of the true θ, all under the same disturbance realisation. Targets (issue 11): the true error inside the decoded 5–95 %
envelope ≥ 90 % of the time, the decoded envelope no wider than the ±20 % one.

    python benchmarks/closed_loop_fidelity.py --out docs/runs/archive/previous_protocol/closed_loop_fidelity.json  # GPU: ~1 min
    python benchmarks/closed_loop_fidelity.py --vehicles 4 --models 16                    # CPU: a few min
    python benchmarks/closed_loop_fidelity.py --posterior log_grounded ...   # the log-grounded posterior's draws
"""
import argparse
import json
from pathlib import Path

from mjxsysid.uses.fidelity import fidelity_benchmark


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=20, help="the paper vehicle + N-1 prior draws (default 20)")
    ap.add_argument("--models", type=int, default=100, help="decoded / perturbed models per vehicle")
    ap.add_argument("--window", choices=("flight", "instant"), default="flight")
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--identification", choices=("held_out", "same"), default="held_out",
                    help="decode a separate identification flight (default) or the test flight itself")
    ap.add_argument("--posterior", choices=("decoded", "log_grounded", "log_grounded_weighed"), default="decoded",
                    help="fly the decoded models (default), draws of the log-grounded posterior of the "
                         "identification flight's IMU and motor commands, or those draws with the true mass")
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    args = ap.parse_args()
    if args.vehicles < 1:
        ap.error("--vehicles must be >= 1")
    res = fidelity_benchmark(vehicles=args.vehicles, models=args.models, window=args.window,
                             duration=args.duration, identification=args.identification, posterior=args.posterior,
                             log=lambda m: print(m, flush=True))
    print(json.dumps({k: res[k] for k in ("mean", "median", "width_ratio_decoded_over_pm20", "targets", "wall_s")}))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
