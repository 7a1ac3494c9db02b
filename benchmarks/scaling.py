"""Scaling over the local devices: 1 device vs all of them, same process, same run.

Two workloads, each timed on ``limit_devices(1)`` (the one-device path, no sharding) and on
every device (:mod:`mjxsysid.runtime.distributed`), after a warm-up call that compiles:

- ``collect``: ``latents_in_flight`` — the shipped policy flying ``--vehicles`` prior vehicles
  ``--steps`` control steps under excitation (what ``mjxsysid collect`` does per batch);
  env-steps/s = vehicles × steps / wall; also the flight alone (``fly_batch`` with the inputs
  drawn beforehand: ``flight_*`` in the JSON), which leaves out the policy's loading and the
  excitation's draws on the host;
- ``train``: iterations of the policy training (rollout + GAE + PPO/alignment updates) with
  ``--envs`` environments × ``--unroll`` steps; env-steps/s = envs × unroll × iterations / wall.

It also records how far the all-device results are from the one-device ones (latents; the
training loss after the timed iterations), as a check that the sharded run computes the same.

    # one GPU vs both GPUs of a 2-GPU machine (e.g. nvidia-h200-x2)
    python benchmarks/scaling.py --vehicles 16384 --envs 4096 --out docs/runs/measurements/benchmarks/scaling.json
    # correctness run on a CPU with 2 forced host devices (not a speed figure)
    XLA_FLAGS=--xla_force_host_platform_device_count=2 python benchmarks/scaling.py \\
        --vehicles 8 --steps 100 --envs 16 --unroll 8 --iterations 2 --repeats 1 \\
        --out docs/runs/measurements/benchmarks/scaling_cpu_forced2.json

Strong scaling (the same batch on 1 and on every device) and weak scaling (the per-device batch
kept: every device × ``--vehicles`` / ``--envs``; the throughput ratio is n for perfect scaling).

Prints a table and writes the JSON (machine, date, command, per workload and device count:
wall seconds, env-steps/s, speed-up over one device).
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from pathlib import Path

import jax
import numpy as np
from _bench import config_overrides, wall_times, write_json


def best_of(fn, repeats: int) -> float:
    """Minimum wall time (s) of ``fn()`` (which blocks on its result) over ``repeats`` calls."""
    return min(wall_times(fn, repeats))


def bench_collect(devices: int, args, vehicles: int | None = None) -> dict:
    from mjxsysid.runtime import distributed as D
    from mjxsysid import theta as P
    from mjxsysid.control.high_level import Cascade
    from mjxsysid.dataset.collect import (
        last_latent_and_failure,
        latents_in_flight,
        lemniscate_excitation,
    )
    from mjxsysid.policy.interface import resolve_policy
    from mjxsysid.rollout.flight import broadcast
    from mjxsysid.rollout.harness import fly_batch
    from mjxsysid.sim import Quadrotor
    ref, sim = resolve_policy("mjxsysid"), Quadrotor()
    vehicles = vehicles or args.vehicles
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), vehicles))
    key = jax.random.PRNGKey(1)
    # the flight alone (inputs drawn beforehand; their sharding and the results' return included)
    flight_args = (sim, theta, ref.batched(vehicles), broadcast(Cascade.make("baseline"), vehicles),
                   *lemniscate_excitation(key, theta), args.steps)
    with D.limit_devices(devices):
        run = lambda: latents_in_flight(ref, theta, key, steps=args.steps, sim=sim)  # host arrays: blocks
        t0 = time.perf_counter()
        z, _ = run()
        first = time.perf_counter() - t0
        wall = best_of(run, args.repeats)
        flight = best_of(lambda: jax.block_until_ready(
            fly_batch(*flight_args, reduce=last_latent_and_failure)), args.repeats)
    return {"devices": D.device_count() if devices is None else devices, "vehicles": vehicles,
            "first_call_s": first, "wall_s": wall, "env_steps_per_s": vehicles * args.steps / wall,
            "flight_wall_s": flight, "flight_env_steps_per_s": vehicles * args.steps / flight, "_z": z}


def bench_train(devices: int, args, envs: int | None = None) -> dict:
    from mjxsysid.runtime import distributed as D
    from mjxsysid.policy.adaptive.config import TrainConfig
    from mjxsysid.policy.adaptive.train import training_mesh
    from mjxsysid.policy.adaptive.trainer import Trainer
    cfg = TrainConfig(**{"iterations": 1500, "unroll": args.unroll, "minibatches": args.minibatches,
                         "reset_per_unroll": args.reset_per_unroll, **config_overrides(args.set),
                         "num_envs": envs or args.envs})
    with D.limit_devices(devices):
        mesh = training_mesh(cfg)
        tr = Trainer(cfg, mesh)
        ts = tr.place(tr.init(jax.random.PRNGKey(0)))
        env = tr.reset(*tr.place((jax.random.PRNGKey(1), np.float32(0.0))))
        t0 = time.perf_counter()
        ts, env, stats = jax.block_until_ready(tr.iteration(ts, env))  # compile + 1 iteration
        first = time.perf_counter() - t0
        state = {"ts": ts, "env": env, "stats": stats}

        def run():
            s, e, st = state["ts"], state["env"], None
            for _ in range(args.iterations):
                s, e, st = tr.iteration(s, e)
            jax.block_until_ready((s, e, st))
            state.update(ts=s, env=e, stats=st)

        wall = best_of(run, args.repeats)
    return {"devices": mesh.size, "envs": cfg.num_envs, "first_call_s": first, "wall_s": wall,
            "iterations": args.iterations, "iterations_per_s": args.iterations / wall,
            "env_steps_per_s": cfg.num_envs * cfg.unroll * args.iterations / wall,
            "_loss": float(state["stats"]["loss"])}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=16384, help="collect: vehicles per batch")
    ap.add_argument("--steps", type=int, default=750, help="collect: control steps per flight")
    ap.add_argument("--envs", type=int, default=4096, help="training environments")
    ap.add_argument("--unroll", type=int, default=32)
    ap.add_argument("--minibatches", type=int, default=8)
    ap.add_argument("--iterations", type=int, default=10, help="training iterations per timed repeat")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats (best of) after the warm-up")
    ap.add_argument("--reset-per-unroll", action="store_true",
                    help="train: TrainConfig.reset_per_unroll (episode starts drawn once per unroll)")
    ap.add_argument("--no-weak", action="store_true", help="skip the weak-scaling runs")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="train: further TrainConfig fields (e.g. epochs=4 flat_optimizer=true)")
    ap.add_argument("--out", type=Path, default=Path("docs/runs/measurements/benchmarks/scaling.json"))
    args = ap.parse_args()
    for k in ("vehicles", "steps", "envs", "unroll", "minibatches", "iterations", "repeats"):
        if getattr(args, k) < 1:
            ap.error(f"--{k} must be >= 1")

    from mjxsysid.runtime import distributed as D
    D.maybe_initialize()
    n_all = D.device_count()
    if n_all < 2:
        print("only one device: the scaling run needs at least 2 (on a CPU, set "
              "XLA_FLAGS=--xla_force_host_platform_device_count=2 for a correctness run)", file=sys.stderr)
        return 2
    dev = jax.devices()[0]
    res = {"command": " ".join([os.path.basename(sys.executable), *sys.argv]),
           "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "machine": {"platform": dev.platform, "device_kind": getattr(dev, "device_kind", ""),
                       "devices": n_all, "processes": jax.process_count(), "host": platform.node(),
                       "cpu_count": os.cpu_count(), "jax": jax.__version__,
                       "xla_flags": os.environ.get("XLA_FLAGS", "")},
           "config": {**{k: getattr(args, k) for k in ("vehicles", "steps", "envs", "unroll", "minibatches",
                                                        "iterations", "repeats")}, "set": config_overrides(args.set)}}
    if dev.platform == "cpu":
        res["note"] = ("CPU run: a correctness run of the sharded path end to end, not a speed figure "
                       "(forced host devices share the same cores)")
    for name, fn in (("collect", bench_collect), ("train", bench_train)):
        one, many = fn(1, args), fn(None, args)
        if name == "collect":
            diff = float(np.max(np.abs(one.pop("_z") - many.pop("_z"))))
            check = {"max_abs_latent_diff": diff}
        else:
            l1, l2 = one.pop("_loss"), many.pop("_loss")
            check = {"loss_1_device": l1, "loss_all_devices": l2, "abs_loss_diff": abs(l1 - l2)}
        res[name] = {"one_device": one, "all_devices": many,
                     "speedup": one["wall_s"] / many["wall_s"],
                     "check": check}
        print(f"{name:8s} strong: 1 device {one['env_steps_per_s'] / 1e6:8.3f} M env-steps/s | "
              f"{many['devices']} devices {many['env_steps_per_s'] / 1e6:8.3f} M env-steps/s | "
              f"speed-up {res[name]['speedup']:.2f}x | check {check}", flush=True)
        if not args.no_weak:
            # Weak scaling: the same batch per device, n devices -> n × the batch; the figure is
            # the ratio of throughputs (env-steps/s), n for perfect scaling.
            size = {"collect": args.vehicles, "train": args.envs}[name] * many["devices"]
            weak = fn(None, args, size)
            weak.pop("_z", None)
            weak.pop("_loss", None)
            res[name]["weak"] = {"all_devices": weak,
                                 "throughput_ratio": weak["env_steps_per_s"] / one["env_steps_per_s"]}
            if name == "collect":
                res[name]["weak"]["flight_throughput_ratio"] = (weak["flight_env_steps_per_s"]
                                                                / one["flight_env_steps_per_s"])
            print(f"{name:8s} weak:   {many['devices']} devices × the per-device batch "
                  f"{weak['env_steps_per_s'] / 1e6:8.3f} M env-steps/s | "
                  f"throughput ×{res[name]['weak']['throughput_ratio']:.2f}"
                  + (f" (the flight alone ×{res[name]['weak']['flight_throughput_ratio']:.2f})"
                     if name == "collect" else ""), flush=True)
    if jax.process_index() == 0:
        write_json(args.out, res)
    return 0


if __name__ == "__main__":
    sys.exit(main())
