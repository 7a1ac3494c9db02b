"""Simulator throughput: env-steps/s of batched rollouts, as ratios to bare `mjx.step`.

Three workloads on the same model, in the same process, 500 control steps each:

- ``bare``:      ``mjx.step`` in a scan, per-environment body mass / inertia / actuator gear /
                 rotor sites (the fields mjxsysid rewrites), constant ctrl; nothing else.
- ``sim``:       the full mjxsysid step: θ → model, exact rotor dynamics, quadratic thrust,
                 drag, τ_ext, a per-step Gaussian world force, IMU with noise, divergence check.
- ``closed``:    ``sim`` plus the cascaded high-level controller and K_θ every step, tracking a
                 lemniscate (the closed-loop harness).

    python benchmarks/sim_throughput.py --envs 16 64 --steps 500     # CPU
    python benchmarks/sim_throughput.py --envs 1024 16384 131072     # GPU

Prints one JSON line per (workload, envs) and a summary table.
"""
from __future__ import annotations

import argparse
import json
import platform
import time

import jax


def timed(fn, *args, repeats=3):
    out = fn(*args)
    jax.block_until_ready(out)  # compile + warm-up
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - t)
    return best


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--envs", type=int, nargs="+", default=[16, 64])
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--workloads", nargs="+", default=["bare", "sim", "closed"])
    args = ap.parse_args()

    from mujoco import mjx

    from mjxsysid import theta as P
    from mjxsysid.rollout.flight import broadcast
    from mjxsysid.rollout.harness import Disturbance, fly
    from mjxsysid.control.high_level import Cascade
    from mjxsysid.control.low_level import KTheta
    from mjxsysid.control.references import Lemniscate
    from mjxsysid.sim import Quadrotor, SimConfig, hover_rotor_speed, init_batch

    dev = jax.devices()[0]
    device = f"{dev.platform}:{getattr(dev, 'device_kind', '')}"
    sim = Quadrotor(SimConfig(gyro_noise=0.01, accel_noise=0.05))
    T = args.steps
    rows = []
    for n in args.envs:
        theta = P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(0), n)
        theta = theta.at[:, P.TAU_EXT].set(0.0)
        hover = hover_rotor_speed(theta) / theta[:, P.OMEGA_MAX, None]
        state = init_batch(sim, theta, jax.random.PRNGKey(1))
        res = {}

        if "bare" in args.workloads:
            models = jax.vmap(sim.model)(theta)
            ctrl = theta[:, P.ETA] * theta[:, P.KT, None] * (hover * theta[:, P.OMEGA_MAX, None]) ** 2

            @jax.jit
            def bare(models, data, ctrl):
                def one(m, d, c):
                    d = d.replace(ctrl=c)
                    return jax.lax.scan(lambda d, _: (mjx.step(m, d), None), d, None, length=T)[0].qpos
                return jax.vmap(one)(models, data, ctrl)

            res["bare"] = timed(bare, models, state.data, ctrl, repeats=args.repeats)

        if "sim" in args.workloads:
            @jax.jit
            def full(theta, state, u, key):
                def one(th, s, uu, k):
                    f = 0.1 * jax.random.normal(k, (T, 3))
                    def body(s, f):
                        return sim.step(th, s, uu, f), None
                    return jax.lax.scan(body, s, f)[0].data.qpos
                return jax.vmap(one)(theta, state, u, jax.random.split(key, theta.shape[0]))

            res["sim"] = timed(full, theta, state, hover, jax.random.PRNGKey(2), repeats=args.repeats)

        if "closed" in args.workloads:
            low = KTheta.make(theta)
            high = broadcast(Cascade.make("baseline"), n)
            ref = broadcast(Lemniscate.make(period=10.0), n)
            dist = broadcast(Disturbance.make(sigma=0.1), n)

            @jax.jit
            def closed(theta, low, high, ref, dist, keys):
                fl = jax.vmap(lambda *a: fly(sim, *a, T))(theta, low, high, ref, dist, keys)
                return fl.frame.pos[:, -1]

            res["closed"] = timed(closed, theta, low, high, ref, dist,
                                  jax.random.split(jax.random.PRNGKey(3), n), repeats=args.repeats)

        for w, sec in res.items():
            row = {"workload": w, "envs": n, "steps": T, "seconds": sec,
                   "env_steps_per_s": n * T / sec,
                   "ratio_to_bare": (res["bare"] / sec) if "bare" in res else None,
                   "device": device, "jax": jax.__version__}
            rows.append(row)
            print(json.dumps(row), flush=True)

    print(f"\n{device}, jax {jax.__version__}, {platform.node()}")
    print(f"{'envs':>8} " + " ".join(f"{w:>18}" for w in args.workloads))
    for n in args.envs:
        cells = []
        for w in args.workloads:
            r = next(r for r in rows if r["envs"] == n and r["workload"] == w)
            ratio = f" ({r['ratio_to_bare']:.2f}x)" if r["ratio_to_bare"] is not None else ""
            cells.append(f"{r['env_steps_per_s'] / 1e6:8.2f}M{ratio:>9}")
        print(f"{n:>8} " + " ".join(f"{c:>18}" for c in cells))


if __name__ == "__main__":
    main()
