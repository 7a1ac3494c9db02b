"""Training-seed spread of the probe loop's comparison (issue 18): retrain a probe-loop run's
round-2 policy and its uniform-widening control with other seeds (same focus systems, config
and budget) and evaluate them like the loop does.

    python tools/probe_loop_seeds.py RUN --seeds 1 --out RUN/seeds     # RUN: a probe-loop --out

Writes OUT/seeds.json: per policy and seed, the evaluation of ``probe_loop.eval_sets``.
"""
import argparse
import dataclasses
import json
from pathlib import Path

from mjxsysid.experiments.common import to_jsonable
from mjxsysid.experiments.probe_loop import FULL, eval_sets, train_config
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.policy.train import train


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("run", type=Path, help="the probe-loop run folder (focus_round2.npz, uniform_stress.npz)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1])
    ap.add_argument("--policies", default="probed2,uniform")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    focus = {"probed2": args.run / "focus_round2.npz", "probed": args.run / "probe" / "weak.npz",
             "uniform": args.run / "uniform_stress.npz"}
    cfg = dataclasses.replace(FULL, latent_vehicles=0)
    res_path = args.out / "seeds.json"
    res = json.loads(res_path.read_text()) if res_path.is_file() else {}
    for seed in args.seeds:
        for name in args.policies.split(","):
            key = f"{name}_seed{seed}"
            if key in res:
                continue
            train(train_config(FULL, seed, focus[name]), args.out / key)
            ev = eval_sets(resolve_policy(args.out / key / "policy.npz"), cfg, 0)
            res[key] = to_jsonable(ev)
            args.out.mkdir(parents=True, exist_ok=True)
            res_path.write_text(json.dumps(res, indent=1) + "\n")
            print(key, {s: (ev[s]["success_policy"], ev[s]["rmse_ratio"]) for s in ("default", "stress")}, flush=True)


if __name__ == "__main__":
    main()
