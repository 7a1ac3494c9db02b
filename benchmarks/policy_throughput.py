"""Closed-loop throughput with a frozen latent policy in the loop, as ratios to K_θ in one run.

The full harness (MJX simulator, cascade, low-level controller, flight recording), 500 steps,
per low-level controller:

- ``oracle``:    K_θ (no networks) — the reference of the ratios;
- ``mjxsysid``:  mjxsysid's shipped policy (φ every 10th step, π every step);
- ``xadap``:     the released Xadap policy (φ over its 100-step history and π every step),
                 needs ``--xadap PATH`` (its folder or a converted .npz), float32 products
                 (``precision="highest"``, the default: matches onnxruntime);
- ``xadap_fast``: the same with the backend's default precision (TF32 on NVIDIA GPUs).

    python benchmarks/policy_throughput.py --envs 16 64 --xadap ../shared/external/xadap    # CPU
    python benchmarks/policy_throughput.py --envs 1024 16384 131072 --xadap .carry/xadap.npz  # GPU

Prints one JSON line per (controller, envs) and a table (env-steps/s and the ratio to K_θ).
"""
from __future__ import annotations

import argparse
import json
import time

import jax
import numpy as np


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--envs", type=int, nargs="+", default=[16, 64])
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--xadap", default=None, help="released Xadap weights (folder or .npz)")
    args = ap.parse_args()

    from mjxsysid import theta as P
    from mjxsysid.rollout.flight import broadcast, make_low_level, make_reference
    from mjxsysid.rollout.harness import Disturbance, fly_batch
    from mjxsysid.control.high_level import Cascade
    from mjxsysid.policy.interface import resolve_policy
    from mjxsysid.sim import Quadrotor

    dev = jax.devices()[0]
    device = f"{dev.platform}:{getattr(dev, 'device_kind', '')}"
    sim = Quadrotor()
    from mjxsysid.policy.xadap.controller import XAdapController
    ctrls = {"oracle": lambda th: make_low_level("oracle", th),
             "mjxsysid": lambda th: resolve_policy("mjxsysid").batched(len(th))}
    if args.xadap:
        w = resolve_policy("xadap", args.xadap).weights
        ctrls["xadap"] = lambda th: XAdapController.load(w).batched(len(th))
        ctrls["xadap_fast"] = lambda th: XAdapController.load(w, precision="default").batched(len(th))
    rows = []
    for n in args.envs:
        theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), n))
        ref, _ = make_reference("lemniscate", period=10.0)
        refs, high = broadcast(ref, n), broadcast(Cascade.make("baseline"), n)
        dist = broadcast(Disturbance.make(), n)
        base = None
        for name, make in ctrls.items():
            low = make(theta)
            run = lambda: fly_batch(sim, theta, low, high, refs, dist, jax.random.PRNGKey(1), args.steps)
            t = time.perf_counter()
            jax.block_until_ready(run())
            compile_s = time.perf_counter() - t
            best = float("inf")
            for _ in range(args.repeats):
                t = time.perf_counter()
                jax.block_until_ready(run().frame.pos)
                best = min(best, time.perf_counter() - t)
            sps = n * args.steps / best
            base = base or sps
            row = {"controller": name, "envs": n, "steps": args.steps, "env_steps_per_s": sps,
                   "ratio_to_k_theta": sps / base, "first_call_s": compile_s, "device": device,
                   "jax": jax.__version__}
            rows.append(row)
            print(json.dumps(row), flush=True)
    print("\n| controller | " + " | ".join(f"{n} envs" for n in args.envs) + " |")
    print("|---|" + "---|" * len(args.envs))
    for name in ctrls:
        cells = [f"{r['env_steps_per_s'] / 1e6:.2f} M/s ({r['ratio_to_k_theta']:.2f}×)"
                 for r in rows if r["controller"] == name]
        print(f"| {name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
