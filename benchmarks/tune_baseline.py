"""How the `baseline` high-level gains were hand-tuned: coordinate search on the paper vehicle.

K_θ with the paper vehicle's true θ flies the 10 s lemniscate and four random 5 s min-snap
trajectories (seeds 100-103); cost = mean position RMSE + 0.002 × mean heading RMSE (deg) +
failures. Each sweep tries 9 values per gain inside GAIN_BOUNDS (log-spaced), all candidates of
one gain in one batched, jitted flight. Two sweeps from the `naive` gains.

    python benchmarks/tune_baseline.py
"""
import time

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import theta as P
from mjxsysid.rollout.harness import Disturbance, batch_metrics, fly_batch
from mjxsysid.control.high_level import GAIN_BOUNDS, GAIN_NAMES, PRESETS, Cascade
from mjxsysid.control.low_level import KTheta
from mjxsysid.control.references import Lemniscate, MinSnap, stack
from mjxsysid.sim import Quadrotor

STEPS = 2500  # 5 s per flight (first half of the lemniscate)


def main():
    sim = Quadrotor()
    refs_l = [Lemniscate.make(period=10.0)]
    refs_m = [MinSnap.random(seed=100 + i, duration=5.0, start=(0.0, 0.0, 1.0)) for i in range(4)]
    n_val = 9

    def cost_of(candidates):  # (K, 8) -> (K,)
        k = len(candidates)
        costs = np.zeros(k)
        for refs in (refs_l, refs_m):
            r = len(refs)
            b = k * r
            th = np.broadcast_to(P.PAPER_HARDWARE, (b, 19))
            ref = stack([refs[j] for _ in range(k) for j in range(r)])
            high = Cascade(jnp.asarray(np.repeat(candidates, r, 0)), jnp.full((b,), 12.0))
            low = KTheta.make(th)
            dist = jax.tree.map(lambda a: jnp.broadcast_to(a, (b,) + a.shape), Disturbance.make())
            fl = fly_batch(sim, th, low, high, ref, dist, jax.random.PRNGKey(0), STEPS)
            m = batch_metrics(fl)
            c = (np.asarray(m["pos_rmse_m"]) + 0.002 * np.asarray(m["heading_rmse_deg"])
                 + 10.0 * np.asarray(m["failed"], float))
            costs += c.reshape(k, r).mean(1) / 2
        return costs

    g = PRESETS["naive"].copy()
    best = cost_of(g[None])[0]
    print(f"start naive: cost {best:.4f}")
    t0 = time.time()
    for sweep in range(2):
        for j, name in enumerate(GAIN_NAMES):
            lo, hi = GAIN_BOUNDS[j]
            vals = np.geomspace(max(lo, 0.05), hi, n_val) if lo > 0 else np.concatenate([[0.0], np.geomspace(0.1, hi, n_val - 1)])
            cand = np.repeat(g[None], n_val, 0)
            cand[:, j] = vals
            c = cost_of(cand)
            i = int(np.argmin(c))
            if c[i] < best:
                best, g = c[i], cand[i]
            print(f"sweep {sweep} {name:8s} -> {g[j]:.3g}  cost {best:.4f}")
    print("tuned gains:", np.round(g, 2).tolist(), f"cost {best:.4f}", f"({time.time() - t0:.0f} s)")


if __name__ == "__main__":
    main()
