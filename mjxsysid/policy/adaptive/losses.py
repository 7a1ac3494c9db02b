"""Losses of the unified training of μ, φ, π (paper §III-A): PPO + alignment + auxiliary losses,
with scheduled substitution and optional behaviour cloning from K_θ(true θ).

Joint loss per minibatch (shapes: B samples of the rollout, S snapshots of histories)::

    L = L_PPO(π, μ, V)                      clipped surrogate + value + entropy
      + λ1 ‖z^θ − sg[ẑ]‖² + λ2 ‖sg[z^θ] − ẑ‖²     on S (θ, history) snapshots
      + c_var Σ_d relu(γ − std_d(z^θ))             variance regulariser against collapse
      + c_rec ‖aux(z^θ) − θ_norm‖²                 reconstruction
      + c_id ‖(aux(z^θ) − θ_norm) A‖²               reconstruction of the identifiable combinations
                                                   (log T/W, log κ, log authority, log τ_m;
                                                   A: :func:`identifiable_projection`), off by default
      + β(t) ‖mean π(s, z) − r_expert‖²            behaviour cloning from K_θ(true θ), decaying

The policy sees z^θ = μ(θ) or, with probability p(t) per episode, ẑ = φ(history) (held,
stop-gradient); p(t) = 0 during warm-up, then rises linearly to p_max (:func:`schedules`). The
loss weights travel into the jitted iteration as a traced :class:`LossWeights` pytree, so trials
that differ only in them share one compile
(:meth:`~mjxsysid.policy.adaptive.trainer.Trainer.reweighted`).
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from mjxsysid import theta as P
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.policy.adaptive.config import TrainConfig


class Batch(NamedTuple):
    state: jax.Array      # (..., 14)
    theta_norm: jax.Array  # (..., 19)
    zhat: jax.Array       # (..., 8)
    use_zhat: jax.Array   # (...)
    raw: jax.Array        # (..., 4)
    logp: jax.Array
    value: jax.Array
    reward: jax.Array
    done: jax.Array
    expert: jax.Array     # (..., 4)
    failed: jax.Array
    rate_err: jax.Array
    thrust_err: jax.Array


def gaussian_logp(x, mean, log_std):
    """log N(x; mean, diag exp(log_std)²), summed over the last axis."""
    return jnp.sum(-0.5 * ((x - mean) / jnp.exp(log_std)) ** 2 - log_std - 0.5 * jnp.log(2 * jnp.pi), -1)


def gae(reward, value, done, last_value, gamma, lam):
    """Generalised advantage estimation. reward, value, done: (T, N); last_value (N,).
    Returns (advantages, returns), (T, N). ``done`` at t means the episode ended after step t."""
    def body(carry, x):
        adv_next, v_next = carry
        r, v, d = x
        nd = 1.0 - d.astype(jnp.float32)
        delta = r + gamma * v_next * nd - v
        adv = delta + gamma * lam * nd * adv_next
        return (adv, v), adv

    _, adv = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), (reward, value, done), reverse=True)
    return adv, adv + value


def schedules(cfg: TrainConfig, it):
    """(p(t), β(t)) at iteration ``it`` (jnp scalars)."""
    frac = it / cfg.iterations
    p = cfg.p_max * jnp.clip((frac - cfg.warmup) / max(cfg.ramp, 1e-9), 0.0, 1.0)
    beta = cfg.bc_final + (cfg.bc_coef - cfg.bc_final) * jnp.clip(1.0 - frac / max(cfg.bc_decay, 1e-9), 0.0, 1.0)
    return p, beta


def alignment_losses(nets, params, theta_norm, history, scale_invariant: bool = True):
    """(λ1 term, λ2 term) before weighting, each a mean over snapshots (S, ...).

    λ1: ‖z^θ − sg[ẑ]‖² (gradient to μ only); λ2: ‖sg[z^θ] − ẑ‖² (gradient to φ only).
    With ``scale_invariant`` both are measured in units of sg[std_d(z^θ)] over the snapshots,
    so shrinking the latent cannot lower them: alignment, not collapse."""
    z_theta = nets.encode(params, theta_norm)
    zhat = nets.adapt(params, history)
    scale = jax.lax.stop_gradient(jnp.std(z_theta, 0) + 1e-3) if scale_invariant else 1.0
    l1 = jnp.mean(jnp.sum(((z_theta - jax.lax.stop_gradient(zhat)) / scale) ** 2, -1))
    l2 = jnp.mean(jnp.sum(((jax.lax.stop_gradient(z_theta) - zhat) / scale) ** 2, -1))
    return l1, l2


def variance_loss(z, target):
    """Σ_d relu(target − std_d(z)) over a batch z (B, 8): penalises collapse."""
    return jnp.sum(jax.nn.relu(target - jnp.sqrt(jnp.var(z, 0) + 1e-6)))


IDENT_TARGET_NAMES = ("log_nominal_thrust_to_weight", "log_torque_ratio", "log_angular_authority[0]",
                      "log_angular_authority[1]", "log_angular_authority[2]", "log_motor_time_constant")


def identifiable_log(theta, yaw_authority: bool = False) -> jax.Array:
    """The identifiable combinations and τ_m in log space. θ (..., 19) physical -> (..., 6)
    (order :data:`IDENT_TARGET_NAMES`). ``yaw_authority``: replace κ (which flight cannot reveal
    alone) by the yaw authority κ k_t Ω_max² / J_zz = k_τ Ω_max² / J_zz that the yaw response shows."""
    theta = jnp.asarray(theta)
    ident = P.identifiable(theta)
    if yaw_authority:
        yaw = theta[..., P.KTAU] * theta[..., P.OMEGA_MAX] ** 2 / theta[..., P.INERTIA.stop - 1]
        ident = ident.at[..., 1].set(yaw)
    return jnp.log(jnp.concatenate([ident, theta[..., P.TAU_M, None]], -1))


def identifiable_projection(normalizer: P.Normalizer, prior: P.SizeFactorPrior, n: int = 20_000, seed: int = 0,
                            yaw_authority: bool = False):
    """A (19, 6) with (y − y') A = (identifiable_log(θ) − identifiable_log(θ')) / std_prior for
    normalised y = normalizer.normalize(θ). Exact: every combination is a signed sum of logs of
    log-normalised entries, so identifiable_log ∘ denormalize is affine in y. The prior std
    (over ``n`` seeded samples) makes each target weigh the same."""
    @jax.jit      # one compile instead of dozens of eager ops (seconds of every training start)
    def project(key):
        jac = jax.jacfwd(lambda y: identifiable_log(normalizer.denormalize(y), yaw_authority))(
            jnp.zeros(P.N_PARAMS))  # (6, 19)
        std = jnp.std(identifiable_log(prior.sample(key, n), yaw_authority), 0)  # (6,)
        return (jac / std[:, None]).T
    return project(jax.random.PRNGKey(seed))


LOSS_WEIGHT_FIELDS = ("lambda1", "lambda2", "var_coef", "var_target", "rec_coef", "rec_ident_coef")


@struct.dataclass
class LossWeights:
    """The loss weights of :class:`TrainConfig` as traced scalars (so configs that differ only
    here share one compiled iteration)."""
    lambda1: jax.Array
    lambda2: jax.Array
    var_coef: jax.Array
    var_target: jax.Array
    rec_coef: jax.Array
    rec_ident_coef: jax.Array

    @classmethod
    def of(cls, cfg: "TrainConfig") -> "LossWeights":
        return cls(**{f: jnp.float32(getattr(cfg, f)) for f in LOSS_WEIGHT_FIELDS})


def normalize_advantages(adv):
    """Advantages (..., B) standardised over their last axis (each minibatch on its own). Done for
    all of an epoch's minibatches before its gradient steps: the statistics do not depend on the
    parameters, so a sharded update needs no collective for them inside each step."""
    return (adv - adv.mean(-1, keepdims=True)) / (adv.std(-1, keepdims=True) + 1e-8)


def loss_fn(params, nets, cfg: TrainConfig, w: LossWeights, ident_proj, mb: Batch, adv, ret,
            snap_theta, snap_hist, beta):
    """Joint loss of one minibatch (mb leaves (B, ...), snapshots (S, ...)); ``adv`` (B,) already
    normalised over the minibatch (:func:`normalize_advantages`); ident_proj (19, 6) from
    :func:`identifiable_projection`. Returns (loss, aux)."""
    z_theta = nets.encode(params, mb.theta_norm)
    z = jnp.where(mb.use_zhat[:, None], jax.lax.stop_gradient(mb.zhat), z_theta)
    mean, log_std = nets.act(params, mb.state, z)
    logp = gaussian_logp(mb.raw, mean, log_std)
    ratio = jnp.exp(logp - mb.logp)
    pg = -jnp.mean(jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - cfg.clip, 1 + cfg.clip) * adv))
    v = nets.value(params, mb.state, mb.theta_norm, jax.lax.stop_gradient(z))
    vf = 0.5 * jnp.mean((v - ret) ** 2)
    ent = jnp.sum(log_std) + 0.5 * N.ACT * (1 + jnp.log(2 * jnp.pi))
    bc = jnp.mean(jnp.sum((mean - mb.expert) ** 2, -1))
    l1, l2 = alignment_losses(nets, params, snap_theta, snap_hist, cfg.align_scale_invariant)
    var = variance_loss(z_theta, w.var_target)
    resid = nets.decode(params, z_theta) - mb.theta_norm           # (B, 19)
    rec = jnp.mean(jnp.sum(resid ** 2, -1))
    rec_id = jnp.mean(jnp.sum((resid @ ident_proj) ** 2, -1))
    loss = (pg + cfg.value_coef * vf - cfg.entropy_coef * ent + beta * bc
            + w.lambda1 * l1 + w.lambda2 * l2 + w.var_coef * var + w.rec_coef * rec
            + w.rec_ident_coef * rec_id)
    return loss, {"pg": pg, "vf": vf, "bc": bc, "align1": l1, "align2": l2, "var": var, "rec": rec,
                  "rec_ident": rec_id, "approx_kl": jnp.mean(mb.logp - logp), "log_std": jnp.mean(log_std)}

