"""The lag-aware oracle: K_θ (the paper's appendix controller, which ignores τ_m)
against :class:`~mjxsysid.control.low_level.KThetaLag` (K_θ that pre-compensates θ's motor lag),
both with each vehicle's true θ and the Baseline cascade, on the default, stress and stress_wide
priors (and the slow-actuator prior), 10 s lemniscate, seeded draws; with the lag-aware oracle's
design choices taken out one at a time (the collective-thrust cut where a rotor saturates, the
cancelled external torque).

    mjxsysid experiment lag-oracle --out docs/runs/measurements/lag-oracle      # 1,000 vehicles per prior
"""
from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import jax
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.low_level import KTheta, KThetaLag
from mjxsysid.experiments.common import leaf_table, write_results
from mjxsysid.rollout.flight import broadcast, make_reference
from mjxsysid.rollout.harness import Disturbance, batch_metrics, fly_batch
from mjxsysid.sim import Quadrotor


def fly(ctrl, theta, sim, steps, ref):
    n = len(theta)
    m = batch_metrics(fly_batch(sim, theta, ctrl, broadcast(Cascade.make("baseline"), n), broadcast(ref, n),
                                broadcast(Disturbance.make(), n), jax.random.PRNGKey(0), steps))
    return np.asarray(m["failed"]) > 0.5, np.asarray(m["pos_rmse_m"], np.float64)


FULL = {"vehicles": 1000, "priors": "default,stress,stress_wide,slow_actuators", "target_tau": [0.02],
        "all_variants": False}
"""The committed run's settings; ``all_variants`` adds the variant that keeps yaw with roll and
pitch when a rotor saturates."""
QUICK = {**FULL, "vehicles": 8, "priors": "default"}


def run(out, *, quick=False, policy=None, seed=0, progress=True) -> dict:
    """The oracle table (see the module doc) into OUT/results.json: per prior, each controller's
    success rate and position RMSE over the vehicles every controller flies (``common``) and over
    its own successes. ``policy`` is not used (no policy flies)."""
    t0 = time.time()
    a = SimpleNamespace(**(QUICK if quick else FULL))
    sim = Quadrotor()
    ref, duration = make_reference("lemniscate", period=10.0)
    steps = int(round(duration / sim.config.dt))
    found = {"config": {"vehicles": a.vehicles, "reference": "lemniscate 10 s", "cascade": "baseline",
                      "seed": seed, "device": jax.devices()[0].device_kind, "date": time.strftime("%Y-%m-%d")}}
    for prior in a.priors.split(","):
        theta = np.asarray(P.get_prior(prior).sample(jax.random.PRNGKey(seed), a.vehicles), np.float32)
        ctrls = {"k_theta": KTheta.make(theta)}
        for t in a.target_tau:
            mk = lambda **kw: KThetaLag.make(theta, dt=sim.config.dt, target_tau=t, **kw)  # noqa: E731
            ctrls.update({f"k_theta_lag_{t:g}": mk(),
                          f"k_theta_lag_{t:g}_no_thrust_cut": mk(thrust_cut=False),
                          f"k_theta_lag_{t:g}_no_thrust_cut_no_torque_cancel": mk(thrust_cut=False, cancel_torque=False)})
            if a.all_variants:
                ctrls[f"k_theta_lag_{t:g}_yaw_with_roll_pitch"] = mk(yaw_last=False, cancel_torque=False)
        res = {k: fly(c, theta, sim, steps, ref) for k, c in ctrls.items()}
        ok = ~np.any([f for f, _ in res.values()], 0)
        row = {k: {"success": float(1 - f.mean()), "pos_rmse_m_common": float(r[ok].mean()) if ok.any() else None,
                   "pos_rmse_m_own": float(r[~f].mean()) if (~f).any() else None} for k, (f, r) in res.items()}
        row["common_n"] = int(ok.sum())
        found[prior] = row
        if progress:
            print(prior, jsonout.dumps(row), flush=True)
    numbers = {**found, "headline": {f"{p}_k_theta_success": found[p]["k_theta"]["success"]
                                     for p in a.priors.split(",")}}
    return write_results(Path(out), "lag-oracle", config={"quick": quick, **vars(a)}, seeds={"seed": seed},
                         numbers=numbers, table_md=leaf_table(found), t0=t0)
