"""Training-seed spread of the probe loop's comparison: retrain a probe-loop run's
round-2 policy and its uniform-widening control with other seeds (same focus systems, config
and budget) and evaluate them like the loop does.

    mjxsysid experiment probe-loop-seeds --inputs RUN --seed 1 --out RUN/seeds     # RUN: a probe-loop --out

Writes OUT/seeds.json: per policy and seed, the evaluation of ``probe_loop.eval_sets``.
"""
import dataclasses
import json
import time
from pathlib import Path

from mjxsysid.runtime import jsonout
from mjxsysid.experiments.common import leaf_table, to_jsonable, write_results
from mjxsysid.experiments.probe_loop import FULL, eval_sets, train_config
from mjxsysid.policy.adaptive.train import train
from mjxsysid.policy.interface import resolve_policy

POLICIES = ("probed2", "uniform")
"""The policies retrained: the loop's round-2 policy and its uniform-widening control."""


def run(out, *, quick=False, policy=None, seed=1, progress=True, inputs=None) -> dict:
    """Retrain :data:`POLICIES` of the probe-loop run ``inputs`` (required: its focus_round2.npz
    and uniform_stress.npz) with training seed ``seed`` and evaluate them (full
    size; ``quick`` is not supported: the loop's own quick run is the smoke test)."""
    if inputs is None:
        raise ValueError("probe-loop-seeds needs --inputs RUN (a probe-loop run folder)")
    if quick:
        raise ValueError("probe-loop-seeds has no quick size (it retrains full policies)")
    t0 = time.time()
    run_dir, out = Path(inputs), Path(out)
    focus = {"probed2": run_dir / "focus_round2.npz", "uniform": run_dir / "uniform_stress.npz"}
    cfg = dataclasses.replace(FULL, latent_vehicles=0)
    res_path = out / "seeds.json"
    res = json.loads(res_path.read_text()) if res_path.is_file() else {}
    for name in POLICIES:
        key = f"{name}_seed{seed}"
        if key in res:
            continue
        train(train_config(FULL, seed, focus[name]), out / key)
        ev = eval_sets(resolve_policy(out / key / "policy.npz"), cfg, 0)
        res[key] = to_jsonable(ev)
        out.mkdir(parents=True, exist_ok=True)
        res_path.write_text(jsonout.dumps(res, indent=1) + "\n")
        if progress:
            print(key, {s: (ev[s]["success_policy"], ev[s]["rmse_ratio"]) for s in ("default", "stress")}, flush=True)
    return write_results(out, "probe-loop-seeds", config={"inputs": str(run_dir), "policies": list(POLICIES)},
                         seeds={"seed": seed}, numbers=res, table_md=leaf_table(res), t0=t0)
