"""Closed-loop fidelity of decoded models (issue 5, item 4).

For a true vehicle θ*: fly it with the frozen policy on a reference under a disturbance, read
ẑ at the end of a first (identification) flight, decode S models, fly each with the same policy,
reference, initial state and *the same disturbance realisation*, and compare position-error
envelopes: the fraction of time the true error lies inside the decoded 5–95 % envelope, and the
envelope's mean width against the one from ±20 % uniform perturbations of θ*.
"""
from __future__ import annotations

import jax
import numpy as np

from mjxsysid import params as P
from mjxsysid.analysis.flight import broadcast, make_low_level, make_reference
from mjxsysid.analysis.harness import Disturbance, fly_batch
from mjxsysid.cfm.sample import Decoder
from mjxsysid.control.high_level import Cascade
from mjxsysid.sim import Quadrotor


def fly_same_disturbance(theta, *, reference="lemniscate", period=10.0, duration=5.0,
                         force_step=(0.0, 0.0, 0.0), force_sigma=0.0, key=None, sim=None):
    """Fly θ (n, 19) with the shipped policy, every vehicle under the *same* disturbance
    realisation (one key for all). Returns the Flight (n, T, ...)."""
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    sim = sim or Quadrotor()
    steps = int(round(duration / sim.config.dt))
    ref, _ = make_reference(reference, period=period, duration=duration)
    low = make_low_level("policy", theta)
    dist = broadcast(Disturbance.make(step_force=force_step, step_time=0.5, sigma=force_sigma), n)
    return fly_batch(sim, theta, low, broadcast(Cascade.make("baseline"), n), broadcast(ref, n), dist,
                     key if key is not None else jax.random.PRNGKey(0), steps, same_key=True)


def envelope_stats(true_err, ens_err):
    """true_err (T,), ens_err (S, T) -> (fraction of time inside the 5–95 % envelope, mean width)."""
    lo, hi = np.percentile(ens_err, [5, 95], 0)
    inside = (true_err >= lo) & (true_err <= hi)
    return float(inside.mean()), float((hi - lo).mean())


def closed_loop_fidelity(theta_true, *, n_models: int = 32, seed: int = 0, decoder: Decoder | None = None,
                         **flight_kw) -> dict:
    """For each true vehicle (n, 19): decoded-model and ±20 % envelopes of the position error."""
    from mjxsysid.analysis.decode import PRETRAINED_DIR
    decoder = decoder or Decoder.load(PRETRAINED_DIR / "cfm.npz")
    theta_true = np.asarray(theta_true, np.float32).reshape(-1, P.N_PARAMS)
    key = jax.random.PRNGKey(seed)
    true_fl = fly_same_disturbance(theta_true, key=key, **flight_kw)
    err = lambda fl: np.linalg.norm(np.asarray(fl.frame.pos - fl.ref_pos), axis=-1)
    true_err = err(true_fl)                                         # (n, T)
    zhat = np.asarray(true_fl.latent[:, -1])                        # identification: end of the flight
    out = []
    for i, th in enumerate(theta_true):
        dec, _ = P.project_valid(np.asarray(decoder.sample_theta(zhat[i], jax.random.fold_in(key, i), n_models)))
        pert = th * np.asarray(jax.random.uniform(jax.random.fold_in(key, 1000 + i), (n_models, P.N_PARAMS),
                                                  minval=0.8, maxval=1.2))
        pert, _ = P.project_valid(pert)
        e_dec = err(fly_same_disturbance(dec, key=key, **flight_kw))
        e_pert = err(fly_same_disturbance(pert, key=key, **flight_kw))
        fd, wd = envelope_stats(true_err[i], e_dec)
        fp, wp = envelope_stats(true_err[i], e_pert)
        out.append({"inside_decoded": fd, "width_decoded_m": wd, "inside_pm20": fp, "width_pm20_m": wp})
    keys = out[0].keys()
    return {"per_vehicle": out, "mean": {k: float(np.mean([o[k] for o in out])) for k in keys},
            "n_models": n_models, **{k: (list(v) if isinstance(v, tuple) else v) for k, v in flight_kw.items()}}
