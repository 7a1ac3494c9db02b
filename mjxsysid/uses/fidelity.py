"""Closed-loop fidelity of decoded models: does a decoded model fly like the true vehicle?

For a true vehicle θ*: fly a first, undisturbed identification flight (a 10 s-period lemniscate,
held out from the test flight, as the robustness experiment identifies) and decode S models from
its latents; then fly θ* with the frozen policy on a reference under a disturbance, and each
decoded model with the same policy,
reference, initial state and *the same disturbance realisation*, and compare position-error
envelopes: the fraction of time the true error lies inside the decoded 5–95 % envelope, and the
envelope's mean width against the one from ±20 % uniform perturbations of θ*.
"""
from __future__ import annotations

import time

import jax
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.cfm.sample import Decoder
from mjxsysid.cfm.sequence import SequenceDecoder
from mjxsysid.control.high_level import Cascade
from mjxsysid.dataset.collect import decode_indices
from mjxsysid.policy.interface import PRETRAINED_DIR, resolve_policy
from mjxsysid.rollout.flight import broadcast, flight_log, make_low_level, make_reference
from mjxsysid.rollout.harness import Disturbance, fly_batch
from mjxsysid.sim import Quadrotor


def fly_same_disturbance(theta, *, reference="lemniscate", period=10.0, duration=5.0,
                         force_step=(0.0, 0.0, 0.0), force_sigma=0.0, key=None, sim=None, policy="mjxsysid"):
    """Fly θ (n, 19) with ``policy`` (default: the shipped one), every vehicle under the *same*
    disturbance realisation (one key for all). Returns the Flight (n, T, ...)."""
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    sim = sim or Quadrotor()
    steps = int(round(duration / sim.config.dt))
    ref, _ = make_reference(reference, period=period, duration=duration)
    low = make_low_level("policy", theta, resolve_policy(policy))
    dist = broadcast(Disturbance.make(step_force=force_step, step_time=0.5, sigma=force_sigma), n)
    return fly_batch(sim, theta, low, broadcast(Cascade.make("baseline"), n), broadcast(ref, n), dist,
                     key if key is not None else jax.random.PRNGKey(0), steps, same_key=True)


def envelope(ens_err, q=(5.0, 95.0)):
    """ens_err (S, T) -> (lo (T,), hi (T,)): the q[0]–q[1] % envelope over the ensemble."""
    ens_err = np.asarray(ens_err, np.float64)
    if ens_err.ndim != 2 or ens_err.shape[0] < 1:
        raise ValueError(f"ensemble errors must have shape (S >= 1, T); got {ens_err.shape}")
    lo, hi = np.percentile(ens_err, list(q), 0)
    return lo, hi


def envelope_stats(true_err, ens_err, q=(5.0, 95.0)):
    """true_err (T,), ens_err (S, T) -> (fraction of time inside the 5–95 % envelope, mean width)."""
    true_err = np.asarray(true_err, np.float64)
    lo, hi = envelope(ens_err, q)
    if true_err.shape != lo.shape:
        raise ValueError(f"true error {true_err.shape} and ensemble {np.shape(ens_err)} differ in length")
    inside = (true_err >= lo) & (true_err <= hi)
    return float(inside.mean()), float((hi - lo).mean())


def energy_distance(u, v) -> float:
    """1-D energy distance between the samples u (n,) and v (m,), as
    ``scipy.stats.energy_distance``: sqrt(2 E|U−V| − E|U−U'| − E|V−V'|) with all pairs (the
    expectations over the empirical distributions, i.e. √2 × the L2 distance of the two
    CDFs). Units of the samples; 0 for identical samples. O((n + m) log(n + m))."""
    u = np.sort(np.asarray(u, np.float64).ravel())
    v = np.sort(np.asarray(v, np.float64).ravel())
    if u.size == 0 or v.size == 0:
        raise ValueError(f"energy distance needs two non-empty samples; got sizes {u.size}, {v.size}")
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(v))):
        raise ValueError("energy distance: samples must be finite")

    def mean_abs_within(x):  # E|X − X'| over all n² ordered pairs, x sorted
        n = x.size
        return 2.0 * np.sum(x * (2 * np.arange(n) - n + 1)) / n**2

    def mean_abs_between(x, y):  # E|X − Y|, x sorted
        cx = np.concatenate([[0.0], np.cumsum(x)])
        k = np.searchsorted(x, y, side="right")  # x[:k] <= y
        below = y * k - cx[k]
        above = (cx[-1] - cx[k]) - y * (x.size - k)
        return np.sum(below + above) / (x.size * y.size)

    d2 = 2.0 * mean_abs_between(u, v) - mean_abs_within(u) - mean_abs_within(v)
    return float(np.sqrt(max(d2, 0.0)))


WINDOWS = ("flight", "instant")


def check_decoder_window(decoder, window: str, what: str = "window") -> None:
    """A named error unless ``decoder`` fits ``window``: the sequence decoder
    (:class:`~mjxsysid.cfm.sequence.SequenceDecoder`, ``cfm_seq.npz``) for 'flight', a
    single-latent decoder (``cfm.npz``) for 'instant'."""
    if window not in WINDOWS:
        raise ValueError(f"{what} must be one of {WINDOWS}; got {window!r}")
    if (window == "flight") != isinstance(decoder, SequenceDecoder):
        need = "the sequence decoder (cfm_seq.npz)" if window == "flight" else "a single-latent decoder (cfm.npz)"
        raise TypeError(f"{what}={window!r} needs {need}; got {type(decoder).__name__}")


IDENTIFICATIONS = ("held_out", "same")
POSTERIORS = ("decoded", "log_grounded", "log_grounded_weighed")


def posterior_draws(posterior: str, decoded, log: dict, *, mass_kg: float, seed: int) -> np.ndarray:
    """The models an envelope flies (S, 19), by :data:`POSTERIORS`: the ``decoded`` ones (S, 19) as
    they are, or as many draws of the log-grounded posterior of the identification flight's ``log``
    (:func:`mjxsysid.rollout.flight.flight_log`), the decoded models its proposal, and for
    'log_grounded_weighed' with the true mass ``mass_kg`` (:func:`mjxsysid.identify.coords.with_mass`)."""
    if posterior == "decoded":
        return np.asarray(decoded)
    from mjxsysid.identify import log_grounded_posterior
    from mjxsysid.identify.coords import with_mass
    th = log_grounded_posterior(log, np.asarray(decoded), samples=len(decoded), seed=seed)["theta"]
    return with_mass(th, mass_kg) if posterior == "log_grounded_weighed" else th


def closed_loop_fidelity(theta_true, *, n_models: int = 32, seed: int = 0, decoder=None,
                         window: str = "flight", rate: float = 10.0, identification: str = "held_out",
                         policy="mjxsysid", posterior: str = "decoded", **flight_kw) -> dict:
    """For each true vehicle (n, 19): decoded-model and ±20 % envelopes of the position error.

    ``identification="held_out"`` (default) decodes the latents of a separate, undisturbed
    identification flight (10 s-period lemniscate, 1 × 1 × 0.3 m, as long as the test flight,
    its own key); ``"same"`` decodes those of the test flight itself (not a held-out figure: the models
    are scored on the flight they were decoded from). ``window="flight"`` decodes every ẑ of the
    identification flight read at ``rate`` Hz with the sequence decoder (``cfm_seq.npz``, the
    flight-level posterior, default), ``"instant"`` the last ẑ with the single-latent CFM (``cfm.npz``).
    ``decoder`` overrides the shipped one of that kind (it must be one trained on ``policy``'s
    latents; ``policy``: the flying policy, default the shipped one). ``posterior="log_grounded"``
    flies, in place of the decoded models, as many draws of the log-grounded posterior of the
    identification flight's IMU and motor commands (:mod:`mjxsysid.identify`, the decoded models its
    proposal): its hidden directions (mass, arm length, drag, …) are as broad as its physical prior,
    because an IMU log does not see them; ``"log_grounded_weighed"`` the same draws with the true mass
    (:func:`mjxsysid.identify.coords.with_mass`: a vehicle put on a scale). The n × n_models decoded and the
    n × n_models perturbed vehicles fly in one batch each, all under the same disturbance
    realisation. Returns per-vehicle and mean ``inside_*`` (fraction of time the true error lies
    in the 5–95 % envelope) and ``width_*_m`` (mean envelope width)."""
    if int(n_models) < 2:
        raise ValueError(f"n_models must be >= 2 for an envelope; got {n_models}")
    if identification not in IDENTIFICATIONS:
        raise ValueError(f"identification must be one of {IDENTIFICATIONS}; got {identification!r}")
    if posterior not in POSTERIORS:
        raise ValueError(f"posterior must be one of {POSTERIORS}; got {posterior!r}")
    if decoder is None:
        if window == "flight":
            decoder = SequenceDecoder.load(PRETRAINED_DIR / "cfm_seq.npz")
        else:
            decoder = Decoder.load(PRETRAINED_DIR / "cfm.npz")
    check_decoder_window(decoder, window)
    theta_true = np.asarray(theta_true, np.float32).reshape(-1, P.N_PARAMS)
    n = len(theta_true)
    key = jax.random.PRNGKey(seed)
    flight_kw = dict(flight_kw, policy=policy)
    true_fl = fly_same_disturbance(theta_true, key=key, **flight_kw)
    err = lambda fl: np.linalg.norm(np.asarray(fl.frame.pos - fl.ref_pos), axis=-1)
    true_err = err(true_fl)                                         # (n, T)
    id_fl = true_fl if identification == "same" else fly_same_disturbance(
        theta_true, reference="lemniscate", period=10.0, duration=flight_kw.get("duration", 5.0),
        key=jax.random.fold_in(key, 77), sim=flight_kw.get("sim"), policy=policy)
    latent = np.asarray(id_fl.latent)                               # (n, T, 8)
    if window == "flight":
        idx = decode_indices(np.asarray(id_fl.time[0]), rate)[-decoder.max_len:]
        zs = latent[:, idx]                                         # (n, W, 8)
    dec, pert = [], []
    for i, th in enumerate(theta_true):
        k = jax.random.fold_in(key, i)
        d = decoder.sample_theta(zs[i] if window == "flight" else latent[i, -1], k, n_models)
        d = posterior_draws(posterior, d, flight_log(id_fl.frame, i) if posterior != "decoded" else None,
                            mass_kg=float(th[P.MASS]), seed=seed + i)
        dec.append(P.project_valid(d)[0])
        p = th * np.asarray(jax.random.uniform(jax.random.fold_in(key, 1000 + i), (n_models, P.N_PARAMS),
                                               minval=0.8, maxval=1.2))
        pert.append(P.project_valid(p)[0])
    shape = (n, n_models, -1)
    e_dec = err(fly_same_disturbance(np.concatenate(dec), key=key, **flight_kw)).reshape(shape)
    e_pert = err(fly_same_disturbance(np.concatenate(pert), key=key, **flight_kw)).reshape(shape)
    out = []
    for i in range(n):
        fd, wd = envelope_stats(true_err[i], e_dec[i])
        fp, wp = envelope_stats(true_err[i], e_pert[i])
        out.append({"inside_decoded": fd, "width_decoded_m": wd, "inside_pm20": fp, "width_pm20_m": wp})
    keys = out[0].keys()
    return {"per_vehicle": out, "mean": {k: float(np.mean([o[k] for o in out])) for k in keys},
            "median": {k: float(np.median([o[k] for o in out])) for k in keys},
            "n_models": n_models, "window": window, "rate_hz": rate, "identification": identification,
            "posterior": posterior,
            **{k: (list(v) if isinstance(v, tuple) else v) for k, v in flight_kw.items() if k != "policy"}}


def fidelity_benchmark(*, vehicles: int = 20, models: int = 100, window: str = "flight", duration: float = 4.0,
                       identification: str = "held_out", policy="mjxsysid", decoder=None, posterior: str = "decoded",
                       log=None) -> dict:
    """The closed-loop fidelity benchmark (``benchmarks/closed_loop_fidelity.py``): the paper
    vehicle and ``vehicles - 1`` default-prior draws (key 7) hover ``duration`` s with a constant
    [1, 1, 0] N world force from 0.5 s (a prior vehicle's scaled by m / m_paper: the same
    acceleration), each through :func:`closed_loop_fidelity` with ``models`` decoded and perturbed
    models (``posterior``: the decoded models, or draws of the log-grounded posterior of the
    identification flight: :func:`closed_loop_fidelity`). Returns the protocol, per-vehicle results, their means and medians, the decoded over
    ±20 % width ratio and the issue's targets (≥ 90 % inside, ratio ≤ 1). ``log`` is told each
    vehicle's result."""
    if vehicles < 1:
        raise ValueError(f"vehicles must be >= 1, got {vehicles}")
    th = np.concatenate([P.PAPER_HARDWARE[None],
                         np.asarray(P.DEFAULT_PRIOR.sample(jax.random.PRNGKey(7), vehicles - 1))])
    t0 = time.time()
    per = []  # one call per vehicle (its own force scale); its models fly in one batch
    for i, t in enumerate(th):
        scale = float(t[P.MASS] / P.PAPER_HARDWARE[P.MASS])
        r = closed_loop_fidelity(t, n_models=models, window=window, reference="hover", identification=identification,
                                 duration=duration, force_step=(scale, scale, 0.0), policy=policy, decoder=decoder,
                                 posterior=posterior)
        per.append({"vehicle": "paper" if i == 0 else f"prior_{i}", "force_scale": scale, **r["per_vehicle"][0]})
        if log is not None:
            log(jsonout.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in per[-1].items()}))
    keys = ("inside_decoded", "width_decoded_m", "inside_pm20", "width_pm20_m")
    ratio = [p["width_decoded_m"] / max(p["width_pm20_m"], 1e-9) for p in per]
    return {
        "protocol": {"vehicles": vehicles, "models": models, "window": window, "identification": identification,
                     "posterior": posterior,
                     "duration_s": duration, "reference": "hover", "force_step_N": "[1, 1, 0] × m / m_paper",
                     "prior_seed": 7},
        "device": str(jax.devices()[0]), "jax": jax.__version__, "wall_s": time.time() - t0,
        "date": time.strftime("%Y-%m-%d"),
        "mean": {k: float(np.mean([p[k] for p in per])) for k in keys},
        "median": {k: float(np.median([p[k] for p in per])) for k in keys},
        "width_ratio_decoded_over_pm20": {"median": float(np.median(ratio)), "mean": float(np.mean(ratio))},
        "targets": {"mean_inside_decoded_ge_0.90": float(np.mean([p["inside_decoded"] for p in per])) >= 0.90,
                    "median_width_ratio_le_1": float(np.median(ratio)) <= 1.0},
        "per_vehicle": per,
    }
