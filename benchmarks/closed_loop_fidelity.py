"""Closed-loop fidelity of decoded models (issue 5 item 4, extended to 20 vehicles in issue 11).

The paper vehicle and ``--vehicles - 1`` prior vehicles hover 4 s with a constant [1, 1, 0] N
world force from 0.5 s (prior vehicles: the force scaled by m / m_paper, the same acceleration);
``--models`` decoded models (flight-level posterior from every ẑ at 10 Hz of a held-out,
undisturbed 4 s identification lemniscate, or ``--window instant``: its last ẑ;
``--identification same``: the test flight's own latents, as measured before 2026-11-25) vs as
many ±20 % perturbations of the true θ, all under the same disturbance realisation. Targets (issue 11): the true error inside the decoded 5–95 %
envelope ≥ 90 % of the time, the decoded envelope no wider than the ±20 % one.

    python benchmarks/closed_loop_fidelity.py --out docs/runs/closed_loop_fidelity.json  # GPU: ~1 min
    python benchmarks/closed_loop_fidelity.py --vehicles 4 --models 16                    # CPU: a few min
"""
import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import params as P
from mjxsysid.studies.fidelity import closed_loop_fidelity


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=20, help="the paper vehicle + N-1 prior draws (default 20)")
    ap.add_argument("--models", type=int, default=100, help="decoded / perturbed models per vehicle")
    ap.add_argument("--window", choices=("flight", "instant"), default="flight")
    ap.add_argument("--duration", type=float, default=4.0)
    ap.add_argument("--identification", choices=("held_out", "same"), default="held_out",
                    help="decode a separate identification flight (default) or the test flight itself")
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    args = ap.parse_args()
    if args.vehicles < 1:
        ap.error("--vehicles must be >= 1")
    th = np.concatenate([P.PAPER_HARDWARE[None],
                         np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(7), args.vehicles - 1))])
    t0 = time.time()
    per = []  # one call per vehicle (its own force scale); its models fly in one batch
    for i, t in enumerate(th):
        scale = float(t[P.MASS] / P.PAPER_HARDWARE[P.MASS])
        r = closed_loop_fidelity(t, n_models=args.models, window=args.window, reference="hover",
                                 identification=args.identification,
                                 duration=args.duration, force_step=(scale, scale, 0.0))
        per.append({"vehicle": "paper" if i == 0 else f"prior_{i}", "force_scale": scale, **r["per_vehicle"][0]})
        print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in per[-1].items()}), flush=True)
    keys = ("inside_decoded", "width_decoded_m", "inside_pm20", "width_pm20_m")
    ratio = [p["width_decoded_m"] / max(p["width_pm20_m"], 1e-9) for p in per]
    res = {
        "protocol": {"vehicles": args.vehicles, "models": args.models, "window": args.window,
                     "identification": args.identification,
                     "duration_s": args.duration, "reference": "hover", "force_step_N": "[1, 1, 0] × m / m_paper",
                     "prior_seed": 7},
        "device": str(jax.devices()[0]), "jax": jax.__version__, "wall_s": time.time() - t0,
        "date": time.strftime("%Y-%m-%d"),
        "mean": {k: float(np.mean([p[k] for p in per])) for k in keys},
        "median": {k: float(np.median([p[k] for p in per])) for k in keys},
        "width_ratio_decoded_over_pm20": {"median": float(np.median(ratio)), "mean": float(np.mean(ratio))},
        "targets": {"mean_inside_decoded_ge_0.90": float(np.mean([p["inside_decoded"] for p in per])) >= 0.90,
                    "median_width_ratio_le_1": float(np.median(ratio)) <= 1.0},
        "per_vehicle": per,
    }
    print(json.dumps({k: res[k] for k in ("mean", "median", "width_ratio_decoded_over_pm20", "targets", "wall_s")}))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
