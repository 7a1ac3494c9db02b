"""Agreement of one device and all devices (issue 30 §3): where it is exact, and why closed loops drift.

Three measurements, each on one device (``limit_devices(1)``) and on every device, same inputs:

- ``step``: one control step of ``--vehicles`` vehicles flown by the shipped policy (the first
  recorded state after the start): relative difference max|a − b| / max(1, max|a|);
- ``update``: one PPO/alignment gradient step (``Trainer._update``, 1 epoch × 1 minibatch) on the
  same rollout batch: relative difference of the updated parameters;
- ``rollout``: the position difference between the two runs over a ``--seconds`` closed-loop flight
  of the same vehicles (max over vehicles, per 0.1 s), beside the same curve for a float-level
  perturbation on one device (θ scaled by 1 + 2⁻²³, one ulp): if the device difference grows like
  the one-ulp perturbation, it is float reassociation amplified by the closed loop, not a
  difference in what is computed.

    python benchmarks/device_agreement.py --out docs/runs/measurements/benchmarks/device_agreement.json      # 2 GPUs
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python benchmarks/device_agreement.py \\
        --vehicles 16 --seconds 1 --envs 16 --out /tmp/agreement.json                    # CPU check
"""
from __future__ import annotations

import argparse
import datetime
import os
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from _bench import write_json


def rel_diff(a, b) -> float:
    """max |a − b| / max(1, max |a|) over every leaf of two pytrees."""
    worst = 0.0
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        worst = max(worst, float(np.max(np.abs(x - y)) / max(1.0, float(np.max(np.abs(x))))))
    return worst


def flight_positions(theta, seconds: float, devices):
    from mjxsysid.runtime import distributed as D
    from mjxsysid.policy.interface import resolve_policy
    from mjxsysid.rollout.flight import fly_vehicles
    with D.limit_devices(devices):
        f, _, _ = fly_vehicles(theta, controller="policy", policy=resolve_policy("mjxsysid"),
                               reference="lemniscate", duration=seconds, seed=3)
    return np.asarray(f.frame.pos, np.float64)          # (B, T, 3)


def update_params(envs: int, devices):
    from mjxsysid.runtime import distributed as D
    from mjxsysid.policy.adaptive.config import TrainConfig
    from mjxsysid.policy.adaptive.losses import schedules
    from mjxsysid.policy.adaptive.train import training_mesh
    from mjxsysid.policy.adaptive.trainer import Trainer
    cfg = TrainConfig(num_envs=envs, unroll=8, epochs=1, minibatches=1, iterations=100)
    # The rollout batch comes from one device (the same data for both updates).
    one = Trainer(cfg)
    ts = one.init(jax.random.PRNGKey(0))
    env = one.reset(jax.random.PRNGKey(1), jnp.float32(0.0))
    p, beta = schedules(cfg, jnp.int32(50))
    env, batch, last_value = jax.jit(lambda prm, e: one._rollout(prm, e, jax.random.PRNGKey(2), p, 50))(ts.params, env)
    with D.limit_devices(devices):
        tr = Trainer(cfg, training_mesh(cfg))
        params, opt_state = tr.place((ts.params, ts.opt_state))
        snap_theta, snap_hist = (D.shard_batch(x, envs) if tr.mesh is not None else x
                                 for x in (env.theta_norm, env.history))
        flat = jax.jit(tr._advantages)(batch, last_value)   # on a mesh: (D, T·N/D, ...), device by device
        out = jax.jit(tr._update)(params, opt_state, flat, snap_theta, snap_hist, jax.random.PRNGKey(4),
                                  tr.place(beta), tr.weights)
        return jax.tree.map(np.asarray, out[0]), (tr.mesh.size if tr.mesh is not None else 1)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=1024)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--envs", type=int, default=4096, help="environments of the update check")
    ap.add_argument("--out", type=Path, default=Path("docs/runs/measurements/benchmarks/device_agreement.json"))
    args = ap.parse_args()
    from mjxsysid.runtime import distributed as D
    from mjxsysid import theta as P
    n = D.device_count()
    if n < 2:
        print("one device: this needs at least 2 (on a CPU: XLA_FLAGS=--xla_force_host_platform_device_count=2)",
              file=sys.stderr)
        return 2
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), args.vehicles))
    one = flight_positions(theta, args.seconds, 1)
    many = flight_positions(theta, args.seconds, None)
    ulp = flight_positions((theta * (1 + 2.0 ** -23)).astype(np.float32), args.seconds, 1)
    scale = max(1.0, float(np.abs(one).max()))
    dev = np.abs(one - many).max(axis=(0, 2)) / scale     # (T,)
    pert = np.abs(one - ulp).max(axis=(0, 2)) / scale
    every = max(1, int(round(0.1 / 0.002)))
    p1, d1 = update_params(args.envs, 1)
    p2, d2 = update_params(args.envs, None)
    res = {"command": " ".join([os.path.basename(sys.executable), *sys.argv]),
           "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "device": str(jax.devices()[0]), "devices": n, "jax": jax.__version__,
           "vehicles": args.vehicles, "seconds": args.seconds, "envs": args.envs,
           "step_rel_diff": float(dev[1]), "update_rel_diff": rel_diff(p1, p2), "update_devices": [d1, d2],
           "rollout_t_s": [float(i * 0.002) for i in range(0, len(dev), every)],
           "rollout_rel_diff_devices": [float(x) for x in dev[::every]],
           "rollout_rel_diff_one_ulp": [float(x) for x in pert[::every]],
           "final_rel_diff_devices": float(dev[-1]), "final_rel_diff_one_ulp": float(pert[-1]),
           "vehicles_differing_devices": int((np.abs(one - many).max(axis=(1, 2)) > 0).sum())}
    print(f"one step: {res['step_rel_diff']:.2e} | one update: {res['update_rel_diff']:.2e} "
          f"({d1} vs {d2} devices) | after {args.seconds:g} s: devices {res['final_rel_diff_devices']:.2e}, "
          f"one-ulp θ {res['final_rel_diff_one_ulp']:.2e} | vehicles differing {res['vehicles_differing_devices']}"
          f"/{args.vehicles}", flush=True)
    write_json(args.out, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
