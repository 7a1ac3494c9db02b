"""Profile of one policy-training iteration (issue 30): where the wall time goes.

For each training configuration (``--envs`` × ``--unroll``, ``--epochs`` × ``--minibatches``),
after a compile, the median over ``--repeats`` of:

- ``iteration``: the whole jitted iteration (what training runs), dispatched back to back;
- ``iteration_synced``: the same with a host round trip after each (``int(ts.iteration)``, as the
  training loop did before issue 30): the difference is what host round trips cost;
- ``rollout``: the simulator + policy forward unroll alone (``Trainer._rollout``); beside it the
  same unroll with the other way of starting episodes (``reset_per_unroll``: a fresh reset
  computed for every environment at every step, or once per unroll), and ``networks_forward``:
  the unroll's network evaluations alone (μ, π, V every step, φ every ``phi_every``);
- ``gae``: advantages and flattening (``Trainer._advantages``);
- ``update``: the ``epochs × minibatches`` PPO/alignment gradient steps (``Trainer._update``),
  and ``one_minibatch``: a single gradient step (latency of one update).

Each part is its own jit, timed on device-resident inputs with ``block_until_ready``; parts
sum to slightly more than the fused iteration (each pays its own launch). Prints a table
(ms per call and the share of the iteration) and writes JSON.

    python benchmarks/train_profile.py --configs 4096x32x4x8 16384x32x4x8 --out docs/runs/measurements/benchmarks/train_profile.json
    python benchmarks/train_profile.py --configs 64x8x2x2 --repeats 2   # CPU smoke test
    python benchmarks/train_profile.py --configs 16384x32x4x8 --set flat_optimizer=true reset_per_unroll=true

``--set KEY=VALUE`` applies further TrainConfig fields to every profiled config.
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
import jax.numpy as jnp
import numpy as np
from _bench import config_overrides, wall_times, write_json


def median_time(fn, repeats: int) -> float:
    """Median wall time (s) of ``fn()`` (which blocks) over ``repeats`` calls."""
    return float(np.median(wall_times(fn, repeats)))


def parse_config(text: str) -> dict:
    try:
        envs, unroll, epochs, mbs = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise SystemExit(f"--configs: expected ENVSxUNROLLxEPOCHSxMINIBATCHES (e.g. 4096x32x4x8), got {text!r}")
    return dict(num_envs=envs, unroll=unroll, epochs=epochs, minibatches=mbs)


def profile(overrides: dict, repeats: int, iters: int) -> dict:
    from mjxsysid.policy.adaptive.config import TrainConfig
    from mjxsysid.policy.adaptive.losses import schedules
    from mjxsysid.policy.adaptive.trainer import Trainer
    cfg = TrainConfig(**overrides)
    tr = Trainer(cfg)
    ts = tr.init(jax.random.PRNGKey(0))
    env = tr.reset(jax.random.PRNGKey(1), jnp.float32(0.0))
    # Mid-training schedule (ẑ substituted for some episodes, BC decaying): a representative iteration.
    ts = ts.replace(iteration=jnp.int32(cfg.iterations // 2))
    p, beta = schedules(cfg, ts.iteration)
    out = {"config": overrides, "env_steps_per_iteration": cfg.num_envs * cfg.unroll}

    t0 = time.perf_counter()
    jax.block_until_ready(tr.iteration(ts, env))
    out["compile_iteration_s"] = time.perf_counter() - t0
    state = {"ts": ts, "env": env}

    def run_free():
        s, e = state["ts"], state["env"]
        for _ in range(iters):
            s, e, st = tr.iteration(s, e)
        jax.block_until_ready((s, e, st))

    def run_synced():
        s, e = state["ts"], state["env"]
        for _ in range(iters):
            s, e, st = tr.iteration(s, e)
            int(s.iteration)
        jax.block_until_ready((s, e, st))

    run_free()
    ms = {"iteration": median_time(run_free, repeats) / iters * 1e3,
          "iteration_synced": median_time(run_synced, repeats) / iters * 1e3}

    k = jax.random.PRNGKey(2)
    roll = jax.jit(lambda prm, e, key: tr._rollout(prm, e, key, p, ts.iteration))
    env_state, batch, last_value = jax.block_until_ready(roll(ts.params, env, k))
    ms["rollout"] = median_time(lambda: jax.block_until_ready(roll(ts.params, env, k)), repeats) * 1e3
    # The same unroll with the other way of starting episodes (reset every step vs once per unroll).
    other = Trainer(TrainConfig(**dict(overrides, reset_per_unroll=not cfg.reset_per_unroll)))
    roll2 = jax.jit(lambda prm, e, key: other._rollout(prm, e, key, p, ts.iteration))
    jax.block_until_ready(roll2(ts.params, env, k))
    ms["rollout_reset_per_unroll" if not cfg.reset_per_unroll else "rollout_reset_per_step"] = median_time(
        lambda: jax.block_until_ready(roll2(ts.params, env, k)), repeats) * 1e3
    # The networks' forward of the unroll alone (μ, π, V every step; φ every phi_every steps) on
    # the environments' current inputs: the policy's share of the rollout.
    nets, phi_every = tr.nets, cfg.env.phi_every

    def forward(prm, e):
        s, _, _, _ = jax.vmap(lambda st: tr.env.policy_input(prm, st))(e)

        # The small terms in t and the carry keep every step's forwards live and unhoisted (XLA
        # would otherwise drop unused outputs or lift loop-invariant work out of the scan).
        def body(c, t):
            z_theta = nets.encode(prm, e.theta_norm)
            z = jax.lax.cond(t % phi_every == 0, lambda h: nets.adapt(prm, h), lambda h: c, e.history)
            mean, _ = nets.act(prm, s + 1e-3 * t, jnp.where(e.use_zhat[:, None], z, z_theta))
            v = nets.value(prm, s, e.theta_norm, z)
            return z + 1e-6 * mean.sum() + 1e-6 * v.sum(), None
        return jax.lax.scan(body, jnp.zeros((cfg.num_envs, 8)), jnp.arange(cfg.unroll))[0]
    fwd = jax.jit(forward)
    jax.block_until_ready(fwd(ts.params, env))
    ms["networks_forward"] = median_time(lambda: jax.block_until_ready(fwd(ts.params, env)), repeats) * 1e3

    adv = jax.jit(tr._advantages)
    flat = jax.block_until_ready(adv(batch, last_value))
    ms["gae"] = median_time(lambda: jax.block_until_ready(adv(batch, last_value)), repeats) * 1e3

    upd = jax.jit(tr._update)
    args = (ts.params, ts.opt_state, flat, env_state.theta_norm, env_state.history, k, beta, tr.weights)
    jax.block_until_ready(upd(*args))
    ms["update"] = median_time(lambda: jax.block_until_ready(upd(*args)), repeats) * 1e3

    one_cfg = dict(overrides, epochs=1, minibatches=1)
    n_mb = cfg.num_envs * cfg.unroll // cfg.minibatches
    tr1 = Trainer(TrainConfig(**dict(one_cfg, num_envs=cfg.num_envs // cfg.minibatches)))
    flat1 = jax.tree.map(lambda a: a[:n_mb], flat)
    s_n = cfg.num_envs // cfg.minibatches
    upd1 = jax.jit(tr1._update)
    args1 = (ts.params, ts.opt_state, flat1, env_state.theta_norm[:s_n], env_state.history[:s_n], k, beta,
             tr1.weights)
    jax.block_until_ready(upd1(*args1))
    ms["one_minibatch"] = median_time(lambda: jax.block_until_ready(upd1(*args1)), repeats) * 1e3

    out["ms"] = ms
    out["host_round_trip_ms"] = ms["iteration_synced"] - ms["iteration"]
    out["env_steps_per_s"] = out["env_steps_per_iteration"] / (ms["iteration"] / 1e3)
    out["rollout_env_steps_per_s"] = out["env_steps_per_iteration"] / (ms["rollout"] / 1e3)
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--configs", nargs="+", default=["4096x32x4x8", "16384x32x4x8"],
                    help="ENVSxUNROLLxEPOCHSxMINIBATCHES, one profile each")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--iterations", type=int, default=10, help="iterations per timed call of the whole iteration")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE",
                    help="further TrainConfig fields for every config (e.g. flat_optimizer=true)")
    ap.add_argument("--out", type=Path, default=Path("docs/runs/measurements/benchmarks/train_profile.json"))
    args = ap.parse_args()
    if args.repeats < 1 or args.iterations < 1:
        ap.error("--repeats and --iterations must be >= 1")
    extra = config_overrides(args.set)
    configs = [dict(parse_config(c), **extra) for c in args.configs]
    dev = jax.devices()[0]
    res = {"command": " ".join([os.path.basename(sys.executable), *sys.argv]),
           "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
           "machine": {"platform": dev.platform, "device_kind": getattr(dev, "device_kind", ""),
                       "host": platform.node(), "cpu_count": os.cpu_count(), "jax": jax.__version__,
                       "xla_flags": os.environ.get("XLA_FLAGS", "")},
           "profiles": []}
    for c in configs:
        r = profile(c, args.repeats, args.iterations)
        res["profiles"].append(r)
        m = r["ms"]
        it = m["iteration"]
        print(f"\n{c['num_envs']} envs × {c['unroll']} steps, {c['epochs']} epochs × {c['minibatches']} minibatches: "
              f"{it:.1f} ms/iteration = {r['env_steps_per_s'] / 1e6:.2f} M env-steps/s "
              f"(compile {r['compile_iteration_s']:.0f} s)")
        for k in [k for k in m if k != "iteration"]:
            print(f"  {k:22s} {m[k]:9.2f} ms  {m[k] / it * 100:6.1f} %")
        print(f"  host round trip        {r['host_round_trip_ms']:9.2f} ms per iteration", flush=True)
    write_json(args.out, res)


if __name__ == "__main__":
    main()
