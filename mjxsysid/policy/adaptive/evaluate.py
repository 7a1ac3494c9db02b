"""Evaluation of an adaptive policy.

1. Command tracking: rate and collective-thrust error on the training environment's commands
   (cascade on random lemniscates + random excitation, noisy IMU, random forces), policy with
   its own ẑ, beside K_θ(true θ) on the same vehicles and command generator.
2. Closed loop: 10 s lemniscate with the baseline high-level gains: success rate and position
   RMSE for the policy, oracle K_θ(true θ) and nominal K_θ(paper θ).
3. Latent health after the history has filled under excitation: ‖z^θ − ẑ‖ relative to the
   spread of z^θ, per-dimension std (no collapse), linear-probe R² from ẑ to every normalised θ
   entry and to the identifiable combinations (held-out 30 %).
4. The same closed loop on the slow-actuator prior (τ_m ∈ [0.05, 0.10] s): reported, no target.

:func:`fast_eval` is the quick version for training trials: latent health on the
training commands and after a few seconds of collect-style closed-loop flight, and the
lemniscate success / RMSE against the oracle on a few hundred vehicles, summarised in
:func:`trial_summary` (probe R² of thrust-to-weight, κ, angular authority, τ_m; ‖z^θ − ẑ‖/spread).
"""
from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.runtime import distributed
from mjxsysid import theta as P
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.references import Lemniscate
from mjxsysid.policy.adaptive.config import EnvConfig
from mjxsysid.policy.adaptive.controller import PolicyController
from mjxsysid.policy.adaptive.env import TrainEnv, training_env
from mjxsysid.runtime.progress import stages
from mjxsysid.rollout.flight import broadcast, fly_vehicles, random_lemniscates
from mjxsysid.rollout.harness import (
    Disturbance,
    batch_metrics,
    failure_mask,
    fly_batch,
    summarize,
)
from mjxsysid.sim import Quadrotor

SERIES = ("rate_err", "thrust_err", "failed")  # (steps, n) outputs of env_rollout


def env_rollout(env: TrainEnv, params, key, n: int, steps: int, expert: bool):
    """Roll the training environment with the deterministic policy on ẑ (expert=False) or with
    K_θ(true θ) (expert=True). Returns dict of (steps, n) errors/failures and, at the last step,
    θ (n, 19), z^θ (n, 8), ẑ (n, 8). The n environments are sharded over every device
    (:mod:`mjxsysid.runtime.distributed`); the result does not depend on the device count."""
    keys = jax.random.split(key, n)
    keys, params = distributed.shard_batch((keys, params), n, axes=(0, None))
    r = _env_rollout(env, params, keys, steps, expert)
    return {k: distributed.unpad(v, n, axis=1 if k in SERIES else 0) for k, v in r.items()}


@partial(jax.jit, static_argnums=(0, 3, 4))
def _env_rollout(env: TrainEnv, params, keys, steps: int, expert: bool):
    """:func:`env_rollout` on per-environment keys (n, 2): the one vmap boundary."""
    st = jax.vmap(lambda k: env.reset(k, 1.0))(keys)  # policy sees ẑ everywhere
    rolled = training_env(env)

    def body(st, t):
        def one(s_):
            s, z, _, obs = env.policy_input(params, s_)
            raw = env.expert_raw(s_) if expert else env.nets.act(params, s, z)[0]
            new, tr = rolled.step(params, s_, raw, obs, 1.0, t % env.config.phi_every == 0)
            return new, (tr.rate_err, tr.thrust_err, tr.failed)
        return jax.vmap(one)(st)

    st_end, (rate, thrust, failed) = jax.lax.scan(body, st, jnp.arange(steps))
    return {"rate_err": rate, "thrust_err": thrust, "failed": failed, "theta": st_end.theta,
            "theta_norm": st_end.theta_norm, "z_theta": env.nets.encode(params, st_end.theta_norm),
            "zhat": st_end.zhat, "episode_step": st_end.step}


def linear_probe_r2(x, y, train_frac=0.7, seed=0):
    """R² on held-out rows of a least-squares fit y ≈ [x, 1] W. x (n, d), y (n, k) -> (k,).
    NaN where there is nothing to measure it on (fewer than 2 rows on either side of the
    split): an empty held-out set has no residual, which is not an R² of 1."""
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    idx = np.random.default_rng(seed).permutation(len(x))
    ntr = int(train_frac * len(x))
    tr, te = idx[:ntr], idx[ntr:]
    if len(tr) < 2 or len(te) < 2:
        return np.full(y.shape[1:] or (1,), np.nan)
    xa = np.concatenate([x, np.ones((len(x), 1))], 1)
    w, *_ = np.linalg.lstsq(xa[tr], y[tr], rcond=None)
    pred = xa[te] @ w
    ss_res = ((y[te] - pred) ** 2).sum(0)
    ss_tot = ((y[te] - y[te].mean(0)) ** 2).sum(0)
    return 1.0 - ss_res / np.maximum(ss_tot, 1e-12)


LATENT_MIN_VEHICLES = 10


def latent_health(z_theta, zhat, theta_norm, theta) -> dict:
    """How well ẑ (n, 8) tracks z^θ (n, 8) and what a linear probe reads from it (θ_norm (n, 19),
    θ (n, 19)). With fewer than :data:`LATENT_MIN_VEHICLES` rows (e.g. a policy whose flights all
    failed: they are left out) every figure is NaN and ``note`` says why; ``n`` is the row count."""
    z_theta, zhat = np.asarray(z_theta), np.asarray(zhat)
    n = len(zhat)
    if n < LATENT_MIN_VEHICLES:
        nan = float("nan")
        return {"n": n, "note": f"latent statistics unavailable: {n} vehicle(s) to measure them on, "
                                f"at least {LATENT_MIN_VEHICLES} needed (failed flights are left out)",
                "z_err_rms": nan, "z_spread": nan, "z_err_rel": nan,
                "z_theta_std": [nan] * zhat.shape[-1], "zhat_std": [nan] * zhat.shape[-1],
                "probe_r2_theta": dict.fromkeys(P.PARAM_NAMES, nan),
                "probe_r2_identifiable": dict.fromkeys(P.IDENTIFIABLE_NAMES, nan)}
    spread = float(np.sqrt(z_theta.var(0).sum()))
    err = float(np.sqrt(((z_theta - zhat) ** 2).sum(-1).mean()))
    ident = np.asarray(P.identifiable(theta))
    ident = np.where(np.arange(ident.shape[1]) == 1, ident, np.log(ident))  # log of positive ratios
    return {
        "n": n, "z_err_rms": err, "z_spread": spread, "z_err_rel": err / spread,
        "z_theta_std": z_theta.std(0).tolist(), "zhat_std": zhat.std(0).tolist(),
        "probe_r2_theta": dict(zip(P.PARAM_NAMES, linear_probe_r2(zhat, theta_norm).tolist())),
        "probe_r2_identifiable": dict(zip(P.IDENTIFIABLE_NAMES, linear_probe_r2(zhat, ident).tolist())),
    }


def latent_of_rollout(r: dict) -> dict:
    """:func:`latent_health` of a policy's :func:`env_rollout`, leaving out the vehicles reset in
    the last 0.4 s (their history has not filled)."""
    ok = np.asarray(r["episode_step"]) >= 200
    return latent_health(r["z_theta"][ok], r["zhat"][ok], r["theta_norm"][ok], r["theta"][ok])


def closed_loop(controller: PolicyController, theta, *, period=10.0, seed=0, sim=None):
    """Policy under the baseline cascade on the lemniscate. theta (n, 19) -> metrics (n,)."""
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    sim = sim or Quadrotor()
    steps = int(round(period / sim.config.dt))
    low = controller.batched(n)
    high = broadcast(Cascade.make("baseline"), n)
    ref = broadcast(Lemniscate.make(period=period), n)
    dist = broadcast(Disturbance.make(), n)
    fl = fly_batch(sim, theta, low, high, ref, dist, jax.random.PRNGKey(seed), steps)
    return {k: np.asarray(v) for k, v in batch_metrics(fl).items()}


def evaluate_policy(path=None, *, n: int = 1000, seed: int = 0, steps: int = 1000, sim=None, log=print) -> dict:
    """The four evaluations of this module (command tracking, closed loop, latent health, slow
    actuators) for the policy at ``path`` (default: the shipped one).
    ``sim``: a Quadrotor to share compiled flights with earlier calls (default: a fresh one)."""
    ctrl = PolicyController.load(path)
    env = TrainEnv(EnvConfig(episode_steps=steps + 1))
    params = ctrl.params
    sim = sim or Quadrotor()  # one instance, so flights of equal shape share their compile
    key = jax.random.PRNGKey(seed)
    out = {"n": n}
    st = stages(["command tracking", "lemniscate", "paper vehicle", "slow actuators"], desc="evaluate-policy")

    st.start("command tracking")
    log(f"[1/4] command tracking on {n} vehicles ({steps} steps, training-distribution commands)")
    res = {}
    for name, expert in (("policy", False), ("oracle_k_theta", True)):
        r = env_rollout(env, params, key, n, steps, expert)
        settle = 100  # history filled
        res[name] = r
        out[f"tracking_{name}"] = {
            "rate_err_mean_rad_s": float(np.mean(r["rate_err"][settle:])),
            "thrust_err_mean_m_s2": float(np.mean(r["thrust_err"][settle:])),
            "failures_per_vehicle_s": float(np.sum(r["failed"]) / (n * steps * 0.002)),
        }
    out["latent"] = latent_of_rollout(res["policy"])

    st.start("lemniscate")
    log(f"[2/4] closed loop, 10 s lemniscate, baseline gains, {n} prior vehicles")
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.fold_in(key, 1), n))
    cl = {"policy": closed_loop(ctrl, theta, seed=seed, sim=sim)}
    for c in ("oracle", "nominal"):
        cl[c] = {k: np.asarray(v) for k, v in fly_vehicles(theta, controller=c, reference="lemniscate", sim=sim)[1].items()}
    out["lemniscate"] = {k: summarize(v) for k, v in cl.items()}
    po = out["lemniscate"]["policy"]
    if po["pos_rmse_m"]["mean"] is not None:
        both = ~cl["policy"]["failed"] & ~cl["oracle"]["failed"]
        out["lemniscate"]["rmse_ratio_policy_over_oracle"] = float(
            cl["policy"]["pos_rmse_m"][both].mean() / cl["oracle"]["pos_rmse_m"][both].mean())

    st.start("paper vehicle")
    log("[3/4] paper vehicle")
    out["paper_vehicle"] = {k: float(v[0]) for k, v in closed_loop(ctrl, P.PAPER_HARDWARE[None], seed=seed, sim=sim).items()}

    st.start("slow actuators")
    log("[4/4] slow actuators (τ_m ∈ [0.05, 0.10] s)")
    slow = np.asarray(P.SLOW_ACTUATOR_PRIOR.sample(jax.random.fold_in(key, 2), n))
    out["slow_actuators"] = {"policy": summarize(closed_loop(ctrl, slow, seed=seed, sim=sim)),
                             "oracle": summarize({k: np.asarray(v) for k, v in fly_vehicles(
                                 slow, controller="oracle", reference="lemniscate", sim=sim)[1].items()})}
    pv = P.PAPER_HARDWARE.copy()
    slow_paper = np.repeat(pv[None], 6, 0)
    slow_paper[:, P.TAU_M] = np.linspace(0.05, 0.10, 6)
    m = closed_loop(ctrl, slow_paper, seed=seed, sim=sim)
    out["slow_actuators"]["paper_vehicle"] = {
        f"tau_m={t:.2f}": {"pos_rmse_m": float(m["pos_rmse_m"][i]), "failed": bool(m["failed"][i])}
        for i, t in enumerate(slow_paper[:, P.TAU_M])}
    st.close()
    return out


def flight_latents(ctrl: PolicyController, theta, key, *, steps: int = 1500, sim=None):
    """ẑ after ``steps`` control steps of the decoder-data flight of :mod:`mjxsysid.dataset.collect`
    (baseline cascade on a random 3-D lemniscate, random world force up to 0.1 m g).
    θ (n, 19) -> (ẑ (n, 8), failed (n,))."""
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    sim = sim or Quadrotor()
    k_ref, k_force, k_fly = jax.random.split(key, 3)
    sigma = jax.random.uniform(k_force, (n, 1), minval=0.0, maxval=0.1) * theta[:, P.MASS, None] * P.GRAVITY
    dist = broadcast(Disturbance.make(), n).replace(sigma=jnp.broadcast_to(sigma, (n, 3)))
    fl = fly_batch(sim, theta, ctrl.batched(n), broadcast(Cascade.make("baseline"), n),
                   random_lemniscates(k_ref, n), dist, k_fly, steps)
    return np.asarray(fl.latent[:, -1]), np.asarray(jax.vmap(failure_mask)(fl))[:, -1]


def fast_eval(params, *, n_probe: int = 2000, n_lem: int = 500, seed: int = 0, steps: int = 1000,
              flight_steps: int = 1500, period: float = 10.0, phi_every: int = 10,
              env: TrainEnv | None = None, sim=None,
              cache: dict | None = None, log=print) -> dict:
    """Quick evaluation of policy ``params`` ({'mu', 'phi', 'pi', ...}) for training trials.

    - ``latent``: :func:`latent_health` after ``steps`` steps of the training commands
      (n_probe vehicles, policy on ẑ, vehicles reset in the last 0.4 s left out), plus tracking;
    - ``latent_flight``: :func:`latent_health` of ẑ after ``flight_steps`` of the collect flight
      (what the decoders see), n_probe fresh vehicles;
    - ``lemniscate``: lemniscate of ``period`` s, baseline gains, n_lem prior vehicles, policy
      and oracle K_θ(true θ).
    Pass the same ``env``, ``sim`` and ``cache`` (dict) to successive calls to share compiles
    and the oracle flights. Returns the nested results and ``summary`` (:func:`trial_summary`)."""
    env = env or TrainEnv(EnvConfig(episode_steps=steps + 1))
    sim = sim or Quadrotor()
    cache = {} if cache is None else cache
    key = jax.random.PRNGKey(seed)
    ctrl = PolicyController(params=params, z_override=jnp.zeros(8), use_override=jnp.array(False),
                            phi_every=phi_every)
    out = {"n_probe": n_probe, "n_lem": n_lem, "steps": steps, "flight_steps": flight_steps}
    st = stages(["training commands", "collect flight", "lemniscate"], desc="fast eval")
    st.start("training commands")
    log(f"  fast eval: training commands ({n_probe} vehicles, {steps} steps)")
    r = env_rollout(env, params, key, n_probe, steps, False)
    ok = np.asarray(r["episode_step"]) >= min(200, steps)
    out["tracking"] = {"rate_err_mean_rad_s": float(np.mean(r["rate_err"][100:])),
                       "thrust_err_mean_m_s2": float(np.mean(r["thrust_err"][100:])),
                       "failures": int(np.sum(r["failed"]))}
    out["latent"] = latent_health(r["z_theta"][ok], r["zhat"][ok], r["theta_norm"][ok], r["theta"][ok])
    st.start("collect flight")
    log(f"  fast eval: collect flight ({n_probe} vehicles, {flight_steps} steps)")
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.fold_in(key, 3), n_probe))
    zhat, failed = flight_latents(ctrl, theta, jax.random.fold_in(key, 4), steps=flight_steps, sim=sim)
    tn = env.normalizer.normalize(theta)
    good = ~failed
    out["latent_flight"] = latent_health(env.nets.encode(params, tn)[good], zhat[good], tn[good], theta[good])
    out["latent_flight"]["failed"] = int(failed.sum())
    for k in ("latent", "latent_flight"):
        if "note" in out[k]:
            log(f"  fast eval: {k}: {out[k]['note']}")
    st.start("lemniscate")
    log(f"  fast eval: lemniscate ({n_lem} vehicles)")
    theta = np.asarray(P.DEFAULT_PRIOR.sample(jax.random.fold_in(key, 1), n_lem))
    ck = ("oracle", n_lem, seed, period)
    if ck not in cache:
        cache[ck] = {k: np.asarray(v) for k, v in fly_vehicles(
            theta, controller="oracle", reference="lemniscate", period=period, seed=seed, sim=sim)[1].items()}
    cl = {"policy": closed_loop(ctrl, theta, period=period, seed=seed, sim=sim), "oracle": cache[ck]}
    out["lemniscate"] = {k: summarize(v) for k, v in cl.items()}
    both = ~cl["policy"]["failed"] & ~cl["oracle"]["failed"]
    out["lemniscate"]["rmse_ratio_policy_over_oracle"] = (
        float(cl["policy"]["pos_rmse_m"][both].mean() / cl["oracle"]["pos_rmse_m"][both].mean())
        if both.any() else None)
    st.close()
    out["summary"] = trial_summary(out)
    return out


def trial_summary(ev: dict) -> dict:
    """The headline numbers of a :func:`fast_eval` (or :func:`evaluate_policy`) result."""
    def probes(lat):
        idn, th = lat["probe_r2_identifiable"], lat["probe_r2_theta"]
        return {"r2_thrust_to_weight": idn["nominal_thrust_to_weight"], "r2_kappa": idn["torque_ratio"],
                "r2_authority": float(np.mean([idn[f"angular_authority[{i}]"] for i in range(3)])),
                "r2_tau_m": th["motor_time_constant"], "z_err_rel": lat["z_err_rel"],
                "z_min_std": float(min(lat["z_theta_std"]))}
    lem = ev["lemniscate"]
    out = {"train_cmds": probes(ev["latent"]),
           "success_policy": lem["policy"]["success_rate"], "success_oracle": lem["oracle"]["success_rate"],
           "rmse_ratio": lem.get("rmse_ratio_policy_over_oracle")}
    if "latent_flight" in ev:
        out["flight"] = probes(ev["latent_flight"])
    if "tracking" in ev:
        out.update(rate_err=ev["tracking"]["rate_err_mean_rad_s"], thrust_err=ev["tracking"]["thrust_err_mean_m_s2"])
    return out
