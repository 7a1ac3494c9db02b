"""Latency of one online-tuner update (issue 10): K models × N candidates × H seconds of
predictive rollouts plus CEM, for one vehicle and for a batch of vehicles at once.

    python benchmarks/tuner_latency.py --vehicles 1 100 --models 32 --candidates 64 --horizon 0.5

Times the jitted, batched update (``OnlineTuner.update``) after a warm-up call; best of
``--repeats``. Reports updates/s and predicted env-steps/s.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time

import jax
import jax.numpy as jnp
import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, nargs="+", default=[1, 100])
    ap.add_argument("--models", type=int, default=32)
    ap.add_argument("--candidates", type=int, default=64)
    ap.add_argument("--iterations", type=int, default=2)
    ap.add_argument("--horizon", type=float, default=0.5)
    ap.add_argument("--method", default="cfm")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--unroll", type=int, nargs="+", default=[1],
                    help="predictive-loop unroll factors to compare in the same run")
    ap.add_argument("--out", default=None, help="also write the results as JSON here")
    a = ap.parse_args(argv)

    from mjxsysid import theta as P
    from mjxsysid.cfm.load import load_decoders
    from mjxsysid.rollout.flight import broadcast, make_reference
    from mjxsysid.rollout.harness import Disturbance
    from mjxsysid.policy.interface import resolve_policy
    from mjxsysid.sim import Quadrotor
    from mjxsysid.tune.cem import CEMConfig
    from mjxsysid.tune.tuner import OnlineTuner, TunerConfig, fly_tuned

    sim = Quadrotor()
    cfg = TunerConfig(models=a.models, horizon=a.horizon,
                      cem=CEMConfig(candidates=a.candidates, iterations=a.iterations))
    dec = load_decoders()[0]
    rows = []
    for b, unroll in [(b, u) for b in a.vehicles for u in a.unroll]:
        cfg = dataclasses.replace(cfg, unroll=unroll)
        theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(1), b))
        ref, _ = make_reference("lemniscate", period=10.0)
        refs = broadcast(ref, b)
        low = resolve_policy("mjxsysid").batched(b)
        # a realistic state to tune from: 0.3 s of flight with naive gains
        tf = fly_tuned(sim, theta, low, refs, broadcast(Disturbance.make(), b), "naive", jax.random.PRNGKey(0), 150)
        from mjxsysid.tune import rotor_state as R
        from mjxsysid.tune import tuner as T
        carry = T._start(sim, *T._axes(low))(jnp.asarray(theta), low, refs,
                                             jnp.stack([jax.random.split(jax.random.PRNGKey(0), 2)] * b))
        hist = R.push_history(R.empty_history(cfg.window(sim.config.dt), b), jnp.asarray(tf.flight.frame.motor_cmd))
        incumbent = jnp.broadcast_to(jnp.asarray(tf.gains[:, -1]), (b, 8))
        tuner = OnlineTuner(sim, a.method, cfg, dec)
        state = tuner.init(b)
        t0 = time.perf_counter()
        out = tuner.update(low, theta, refs, carry, hist, incumbent, 150, state, jax.random.PRNGKey(2))
        jax.block_until_ready(out)
        compile_s = time.perf_counter() - t0
        best = np.inf
        for r in range(a.repeats):
            t0 = time.perf_counter()
            out = tuner.update(low, theta, refs, carry, hist, incumbent, 150, state, jax.random.PRNGKey(3 + r))
            jax.block_until_ready(out)
            best = min(best, time.perf_counter() - t0)
        steps = b * a.models * a.candidates * a.iterations * cfg.steps(sim.config.dt)[1]
        row = {"vehicles": b, "unroll": unroll, "models": a.models, "candidates": a.candidates, "iterations": a.iterations,
               "horizon_s": a.horizon, "method": a.method, "update_s": best, "updates_per_s": 1.0 / best,
               "predicted_env_steps_per_s": steps / best, "first_call_s": compile_s}
        rows.append(row)
        print(json.dumps(row), flush=True)
    info = {"device": str(jax.devices()[0].device_kind), "jax": jax.__version__, "rows": rows,
            "date": time.strftime("%Y-%m-%d")}
    if a.out:
        with open(a.out, "w") as f:
            json.dump(info, f, indent=2)
    return info


if __name__ == "__main__":
    main()
