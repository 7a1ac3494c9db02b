"""Where does the oracle (K_θ with the true θ) still fly? The ablation behind the stress prior
(docs/probing.md): the oracle on the first stress prior (``stress_wide``) with one of
its edges at a time brought back, on the stress prior that replaced it, and with rate gains
lowered for slow motors (K_ω = min(K_ω, c / τ_m)). 10 s lemniscate, seeded draws.

    mjxsysid experiment stress-prior-oracle --out docs/runs/measurements/stress-prior-oracle   # 128 vehicles
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.low_level import DEFAULT_RATE_GAINS, KTheta
from mjxsysid.experiments.common import leaf_table, write_results
from mjxsysid.rollout.flight import broadcast, make_reference
from mjxsysid.rollout.harness import Disturbance, batch_metrics, fly_batch
from mjxsysid.sim import Quadrotor


def oracle_lost(theta, rate_scale=None) -> float:
    """Fraction of θ (n, 19) the oracle loses; ``rate_scale`` c: K_ω = min(K_ω, c / τ_m)."""
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    gains = np.broadcast_to(np.asarray(DEFAULT_RATE_GAINS, np.float32), (n, 3))
    if rate_scale is not None:
        gains = np.minimum(gains, rate_scale / theta[:, P.TAU_M, None])
    ref, duration = make_reference("lemniscate", period=10.0)
    sim = Quadrotor()
    flight = fly_batch(sim, theta, KTheta.make(theta, gains), broadcast(Cascade.make("baseline"), n),
                       broadcast(ref, n), broadcast(Disturbance.make(), n), jax.random.PRNGKey(0),
                       int(round(duration / sim.config.dt)))
    return float(np.mean(np.asarray(batch_metrics(flight)["failed"]) > 0.5))


def run(out, *, quick=False, policy=None, seed=17, progress=True) -> dict:
    """The oracle's losses per prior variant (see the module doc) into OUT/results.json: 128
    vehicles per variant (``quick``: 8), drawn with PRNGKey(seed). ``policy`` is not used."""
    t0 = time.time()
    vehicles = 8 if quick else 128
    W, D = P.STRESS_WIDE_PRIOR, P.DEFAULT_PRIOR
    variants = {
        "stress_wide": W,
        "stress_wide, default external torque": dataclasses.replace(W, ext_torque_xy=D.ext_torque_xy,
                                                                    ext_torque_z=D.ext_torque_z),
        "stress_wide, default motor effectiveness": dataclasses.replace(W, eta=D.eta),
        "stress_wide, tau_m 0.04-0.08": dataclasses.replace(W, motor_time_constant=(0.04, 0.08)),
        "stress_wide, default tau_m": dataclasses.replace(W, motor_time_constant=D.motor_time_constant),
        "stress_wide, default tau_m, rotors >= 1.5x": dataclasses.replace(W, motor_time_constant=D.motor_time_constant,
                                                                         twr_min_eff=1.5),
        "stress (tau_m 0.04-0.06, rotors >= 1.5x, 2x torque)": P.STRESS_PRIOR,
        "default": D,
    }
    key = jax.random.PRNGKey(seed)
    res = {"vehicles": vehicles, "oracle_lost": {}, "oracle_lost_rate_gains_lowered": {}}
    for name, prior in variants.items():
        res["oracle_lost"][name] = oracle_lost(np.asarray(prior.sample(key, vehicles)))
        if progress:
            print(f"{name:55s} oracle loses {res['oracle_lost'][name]:.1%}", flush=True)
    theta = np.asarray(dataclasses.replace(W, twr_min_eff=1.5).sample(key, vehicles))
    res["oracle_lost_rate_gains_lowered"]["stress_wide, rotors >= 1.5x"] = {"fixed gains": oracle_lost(theta)}
    for c in (1.6, 1.2, 0.8):
        res["oracle_lost_rate_gains_lowered"]["stress_wide, rotors >= 1.5x"][f"K_w = min(K_w, {c}/tau_m)"] = \
            oracle_lost(theta, c)
    if progress:
        print(jsonout.dumps(res["oracle_lost_rate_gains_lowered"], indent=1))
    numbers = {**res, "headline": {"stress_oracle_lost": res["oracle_lost"][next(k for k in variants if
                                                                                 k.startswith("stress ("))]}}
    return write_results(Path(out), "stress-prior-oracle", config={"quick": quick, "vehicles": vehicles},
                         seeds={"seed": seed}, numbers=numbers, table_md=leaf_table(res), t0=t0)
