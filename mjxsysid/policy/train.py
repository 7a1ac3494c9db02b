"""Unified training of μ, φ, π (paper §III-A): PPO + alignment + auxiliary losses, with
scheduled substitution and optional behaviour cloning from K_θ(true θ).

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
stop-gradient); p(t) = 0 during warm-up, then rises linearly to p_max. The whole iteration
(rollout scan, GAE, epochs × minibatches scans) is one jitted function; the host loop prints
progress and checkpoints between iterations. The loss weights travel into the jitted
iteration as a traced :class:`LossWeights` pytree, so trials that differ only in them share one
compile (:meth:`Trainer.reweighted`).
"""
from __future__ import annotations

import copy
import dataclasses
import json
import os
import threading
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from jax.sharding import NamedSharding, PartitionSpec

from mjxsysid import distributed
from mjxsysid import theta as P
from mjxsysid.checkpoint import load_meta, load_tree, save_tree
from mjxsysid.policy import networks as N
from mjxsysid.policy.env import EnvConfig, EnvState, TrainEnv
from mjxsysid.policy.focus import load_weak
from mjxsysid.progress import progress


PARAM_MODULES = ("mu", "phi", "pi", "v", "aux")   # the networks' parameter groups (Networks.init)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Defaults reproduce the shipped weights (see mjxsysid/pretrained/policy.json)."""
    seed: int = 0
    num_envs: int = 4096
    unroll: int = 32
    iterations: int = 1500
    epochs: int = 4
    minibatches: int = 8
    learning_rate: float = 3e-4
    gamma: float = 0.98
    gae_lambda: float = 0.95
    clip: float = 0.2
    value_coef: float = 0.5
    entropy_coef: float = 0.0
    max_grad_norm: float = 1.0
    lambda1: float = 1.0
    lambda2: float = 1.0
    align_scale_invariant: bool = False   # True collapsed a latent dimension in a 2500-it trial
    var_coef: float = 1.0
    var_target: float = 0.1
    rec_coef: float = 0.1
    # Reconstruction of the identifiable combinations (log T/W, log angular authorities, log τ_m
    # and, with ident_yaw_authority, the yaw authority k_τ Ω_max²/J_zz in place of κ, which flight
    # does not reveal): what makes the latent carry T/W (probe R² 0.44 -> 0.92, docs/runs/archive/latent_trials/latent_trials.md).
    # The policy shipped before 2026-11-24 had 0.0 / False (the latent trials' control).
    rec_ident_coef: float = 1.0
    ident_yaw_authority: bool = True
    bc_coef: float = 2.0
    bc_final: float = 0.05
    bc_decay: float = 0.7          # fraction of training over which β decays to bc_final
    warmup: float = 0.2            # fraction with p = 0
    ramp: float = 0.3              # fraction over which p rises to p_max
    p_max: float = 0.5
    # Episode starts: False (the shipped policy's training) computes a fresh reset for every
    # environment at every step and keeps it where an episode ended; True draws one per
    # environment per unroll (``unroll`` × fewer resets; the rollout's largest cost after the
    # simulator step, docs/runs/measurements/benchmarks/train_profile.json).
    reset_per_unroll: bool = False
    # Options of issue 30 (off by default: the shipped policy's protocol). ``flat_optimizer``: Adam and
    # the gradient clip on one concatenated parameter vector (optax.flatten; the same update up to float
    # reassociation; no measurable speed-up on an H200, docs/runs/measurements/benchmarks/train_profile_16k_4x8_flat_*.json).
    # ``lr_decay``: the learning rate falls linearly to ``lr_final`` × learning_rate over the run's
    # gradient steps (what brought the fast configs to the shipped quality, BENCHMARKS.md).
    flat_optimizer: bool = False
    lr_decay: bool = False
    lr_final: float = 0.1
    # Modules (of :data:`PARAM_MODULES`) whose learning rate stays constant under ``lr_decay``: the
    # adaptation module φ learns only from the alignment loss, and Adam makes its step size the learning
    # rate whatever that loss's weight, so a short run with a decayed rate leaves ẑ short of z^θ.
    lr_constant: tuple[str, ...] = ()
    checkpoint_every: int = 50
    log_every: int = 10
    env: EnvConfig = EnvConfig()
    focus: str | None = None       # weak.npz of `mjxsysid probe`: its systems mixed into training (env.focus_weight)
    # Warm start: a policy.npz whose μ, φ, π and auxiliary decoder replace the fresh ones (the critic
    # and the optimiser start afresh; the schedules run from iteration 0): fine-tuning a trained policy.
    init_from: str | None = None

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "TrainConfig":
        d = dict(d)
        env = EnvConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.pop("env", {}).items()})
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown training config key(s) {unknown}; known: {sorted(known)}")
        cfg = cls(**d, env=env)
        for k in ("num_envs", "unroll", "iterations", "epochs", "minibatches"):
            if getattr(cfg, k) < 1:
                raise ValueError(f"config {k} must be >= 1, got {getattr(cfg, k)}")
        if (cfg.num_envs * cfg.unroll) % cfg.minibatches or cfg.num_envs % cfg.minibatches:
            raise ValueError("num_envs and num_envs × unroll must be divisible by minibatches")
        if not 0.0 <= cfg.lr_final <= 1.0:
            raise ValueError(f"config lr_final must be in [0, 1] (a fraction of learning_rate), got {cfg.lr_final}")
        return cfg

    def __post_init__(self):
        if isinstance(self.lr_constant, list):    # JSON gives a list
            object.__setattr__(self, "lr_constant", tuple(self.lr_constant))
        bad = sorted(set(self.lr_constant) - set(PARAM_MODULES))
        if bad:
            raise ValueError(f"config lr_constant: unknown module(s) {bad}; modules: {list(PARAM_MODULES)}")
        if self.lr_constant and self.flat_optimizer:
            raise ValueError("config lr_constant needs flat_optimizer=false (one flat Adam has one learning rate)")
        if self.lr_constant and not self.lr_decay:
            raise ValueError("config lr_constant needs lr_decay=true (without the decay every rate is constant)")


def _same_normalizer(a: dict, b: dict) -> bool:
    """Two normalisers' dicts (:meth:`mjxsysid.theta.Normalizer.to_dict`: lists of numbers) alike:
    the same keys and shapes, numbers equal to float32 rounding (a normaliser fitted on another
    device or with other XLA optimisations differs in the last bits of its reductions)."""
    if set(a) != set(b):
        return False
    for k in a:
        x, y = np.asarray(a[k], np.float64), np.asarray(b[k], np.float64)
        if x.shape != y.shape or not np.allclose(x, y, rtol=1e-5, atol=1e-6):
            return False
    return True


def config_with_overrides(path=None) -> dict:
    """The default :class:`TrainConfig` as a dict, with the overrides of the JSON file ``path``
    (an object of TrainConfig keys, and an ``env`` object of EnvConfig keys) merged in; checked
    keys are left to :meth:`TrainConfig.from_dict`. A missing file is a FileNotFoundError, a file
    that is not such an object a ValueError, both naming the file."""
    cfg = TrainConfig().to_dict()
    if path is None:
        return cfg
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"config file not found: {path}")
    try:
        over = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(over, dict) or not isinstance(over.get("env", {}), dict):
        raise ValueError(f"{path}: expected a JSON object of TrainConfig keys (and an 'env' object)")
    env = dict(cfg["env"], **over.pop("env", {}))
    cfg.update(over)
    cfg["env"] = env
    return cfg


@struct.dataclass
class TrainState:
    params: dict
    opt_state: optax.OptState
    iteration: jax.Array
    key: jax.Array


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


IDENT_TARGET_NAMES = ("log_thrust_to_weight", "log_torque_ratio", "log_angular_authority[0]",
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


def optimizer(cfg: TrainConfig) -> optax.GradientTransformation:
    """Gradient clip + Adam of ``cfg``: constant learning rate, or with ``lr_decay`` a linear fall to
    ``lr_final`` × learning_rate over the run's gradient steps (except the modules of
    ``lr_constant``); with ``flat_optimizer`` on one concatenated parameter vector."""
    lr = cfg.learning_rate
    if cfg.lr_decay:
        lr = optax.linear_schedule(cfg.learning_rate, cfg.learning_rate * cfg.lr_final,
                                   cfg.iterations * cfg.epochs * cfg.minibatches)
    adam = optax.adam(lr)
    if cfg.lr_constant:     # (only with lr_decay: TrainConfig checks)
        # Adam is per parameter: two Adams on a split of the modules are one Adam with two rates.
        const = set(cfg.lr_constant)
        adam = optax.multi_transform(
            {"decay": adam, "constant": optax.adam(cfg.learning_rate)},
            lambda params: {k: jax.tree.map(lambda _, k=k: "constant" if k in const else "decay", v)
                            for k, v in params.items()})
    opt = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm), adam)
    return optax.flatten(opt) if cfg.flat_optimizer else opt


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


def _host_device():
    """JAX's CPU device, or None (the default device) where JAX runs without a CPU backend."""
    try:
        return jax.devices("cpu")[0]
    except RuntimeError:
        return None


class Trainer:
    """Builds the jitted iteration for a config. ``init(key)``, ``iteration(ts, env_state)``;
    ``reweighted(cfg)``: the same compiled iteration under another config's loss weights.

    ``mesh`` (a 1-D ``'batch'`` mesh, :func:`mjxsysid.distributed.batch_mesh`): data-parallel
    training. The environments (``num_envs``, which the mesh size must divide) are sharded over
    its devices, the training state is replicated, and every minibatch is sharded, so the
    compiler all-reduces the gradients; the update is that of one device up to float
    reassociation. Pass states through :meth:`place` first. None or one device: unchanged."""

    def __init__(self, cfg: TrainConfig = TrainConfig(), mesh=None):
        self.cfg = cfg
        # The one-off constants (the prior's normaliser, the identifiable projection) on the CPU:
        # their dozens of eager ops compile in milliseconds there, in tenths of seconds each on a
        # GPU (seconds of every training start); the jitted functions take them as constants.
        with jax.default_device(_host_device()):
            self.env = TrainEnv(cfg.env, focus_theta=None if cfg.focus is None else load_weak(cfg.focus)[0])
            self.ident_proj = identifiable_projection(self.env.normalizer, self.env.prior,
                                                      yaw_authority=cfg.ident_yaw_authority)
        self.nets = self.env.nets
        self.opt = optimizer(cfg)
        self._compiling = {}     # background compiles (start_compile): name -> (thread, box)
        self._compiled = {}
        self.mesh = mesh if mesh is not None and mesh.size > 1 else None
        if self.mesh is None:
            self.weights = LossWeights.of(cfg)
            self._iteration_jit = jax.jit(self._iteration)
            self.reset = jax.jit(self._reset)
            self._start_jit = jax.jit(self._start)
            return
        if cfg.num_envs % (self.mesh.size * cfg.minibatches):
            raise ValueError(f"num_envs ({cfg.num_envs}) must be a multiple of the {self.mesh.size} devices × "
                             f"{cfg.minibatches} minibatches (each device shuffles its own environments' samples)")
        shared = NamedSharding(self.mesh, PartitionSpec())
        envs = self._batch_sharding = NamedSharding(self.mesh, PartitionSpec(distributed.AXIS))
        self.weights = self.place(LossWeights.of(cfg))
        self._iteration_jit = jax.jit(self._iteration, in_shardings=(shared, envs, shared),
                                      out_shardings=(shared, envs, shared))
        self.reset = jax.jit(self._reset, in_shardings=(shared, shared), out_shardings=envs)
        self._start_jit = jax.jit(self._start, in_shardings=(shared, shared), out_shardings=(shared, envs))

    def place(self, tree):
        """Replicate a training state (or any pytree of shared arrays) over the mesh."""
        return distributed.replicate(tree, self.mesh) if self.mesh is not None else tree

    def iteration(self, ts: TrainState, env_state: EnvState):
        """One training iteration under ``self.weights`` -> (ts, env_state, stats). After
        :meth:`start_compile`, the first call waits for that compile and later ones run its executable."""
        compiled = self._ready("iteration")
        if compiled is not None:
            return compiled(ts, env_state, self.weights)
        return self._iteration_jit(ts, env_state, self.weights)

    def start(self, key):
        """A fresh run: the training state of :meth:`init` and the environments of :meth:`reset` at
        the first iteration's schedule, on ``jax.random.fold_in(ts.key, 123)`` -> (TrainState,
        EnvState). The parameters come from :meth:`initial_params`; optimiser state and episodes
        from one compiled call."""
        compiled = self._ready("start")
        run = compiled if compiled is not None else self._start_jit
        return run(*self.place((self.initial_params(key), key)))

    def initial_params(self, key) -> dict:
        """The networks' fresh parameters (their own, shared init), with a warm start's μ, φ, π and
        auxiliary decoder in place where ``init_from`` is set."""
        params = self.nets.init(key)
        if self.cfg.init_from is not None:
            params = {**params, **self.warm_start_params()}
        return params

    def _start(self, params, key):
        ts = self._fresh_state(params, key)
        return ts, self._reset(jax.random.fold_in(ts.key, 123), schedules(self.cfg, ts.iteration)[0])

    def _abstract_start_inputs(self):
        """Shapes and dtypes of :meth:`_start`'s inputs (parameters, key)."""
        key = jax.eval_shape(lambda: jax.random.PRNGKey(0))
        return jax.eval_shape(self.nets.init, key), key

    def abstract_state(self):
        """Shapes and dtypes (jax.ShapeDtypeStruct trees) of (TrainState, EnvState) as
        :meth:`start` makes them, without computing them."""
        return jax.eval_shape(self._start, *self._abstract_start_inputs())

    def _ready(self, name):
        """The executable of a background compile ``name`` (waiting for it), or None."""
        if name in self._compiling:
            thread, box = self._compiling.pop(name)
            thread.join()
            if "error" in box:
                raise box["error"]
            self._compiled[name] = box["compiled"]
        return self._compiled.get(name)

    def start_compile(self) -> None:
        """Compile the iteration and :meth:`start` in background threads (XLA compiles without
        holding the GIL), so that they compile side by side and the iteration's compile overlaps
        the setup that follows (starting, loading a checkpoint): the cold start of ``train`` costs
        the longest of them instead of their sum. :meth:`start` and :meth:`iteration` wait for
        their executable (and raise what its compile raised). ``compile_seconds``: each compile's
        wall time once done."""
        if self._compiling or self._compiled:
            return
        params, key = self._abstract_start_inputs()
        ts, env = jax.eval_shape(self._start, params, key)
        self.compile_seconds = {}
        jobs = {"start": lambda: self._start_jit.lower(params, key),
                "iteration": lambda: self._iteration_jit.lower(ts, env, self.weights)}
        for name, lower in jobs.items():
            box = {}

            def work(lower=lower, box=box, name=name):
                try:
                    t0 = time.time()
                    box["compiled"] = lower().compile()
                    self.compile_seconds[name] = time.time() - t0
                except Exception as e:   # noqa: BLE001 - re-raised in the caller's thread by _ready()
                    box["error"] = e

            thread = threading.Thread(target=work, name=f"mjxsysid-compile-{name}", daemon=True)
            thread.start()
            self._compiling[name] = (thread, box)

    def reweighted(self, cfg: TrainConfig) -> "Trainer":
        """A trainer for ``cfg`` sharing this one's compiled iteration; ``cfg`` may differ from
        ``self.cfg`` only in :data:`LOSS_WEIGHT_FIELDS`."""
        same = dataclasses.replace(cfg, **{f: getattr(self.cfg, f) for f in LOSS_WEIGHT_FIELDS})
        if same != self.cfg:
            diff = sorted(k for k, v in same.to_dict().items() if v != self.cfg.to_dict()[k])
            raise ValueError(f"reweighted: config differs beyond the loss weights in {diff}")
        new = copy.copy(self)
        new.cfg, new.weights = cfg, new.place(LossWeights.of(cfg))
        return new

    def init(self, key) -> TrainState:
        return self._fresh_state(self.initial_params(key), key)

    def _fresh_state(self, params, key) -> TrainState:
        return TrainState(params=params, opt_state=self.opt.init(params), iteration=jnp.int32(0),
                          key=jax.random.fold_in(key, 1))

    def warm_start_params(self) -> dict:
        """μ, φ, π and the auxiliary decoder of ``cfg.init_from`` (checked: it exists, holds
        mjxsysid policy weights, and was trained with this environment's θ normalisation)."""
        path = Path(self.cfg.init_from)
        if not path.is_file():
            raise FileNotFoundError(f"init_from: policy weights not found: {path}")
        try:
            warm, meta = load_policy_params(path)
        except (KeyError, ValueError, OSError) as e:
            raise ValueError(f"init_from: {path}: not mjxsysid policy weights ({e})") from None
        norm = meta.get("normalizer")
        if norm is not None and not _same_normalizer(norm, self.env.normalizer.to_dict()):
            raise ValueError(f"init_from: {path} was trained with another θ normalisation (prior) than this config's")
        return warm

    def _reset(self, key, p):
        keys = jax.random.split(key, self.cfg.num_envs)
        st = jax.vmap(lambda k: self.env.reset(k, p))(keys)
        # Desynchronise episodes so resets spread over time.
        offs = jax.random.randint(jax.random.fold_in(key, 7), (self.cfg.num_envs,), 0, self.cfg.env.episode_steps)
        return st.replace(step=offs)

    def _rollout(self, params, env_state: EnvState, key, p, it):
        cfg, env = self.cfg, self.env

        def one(st, k, refresh, fresh):
            s, z, z_theta, obs = env.policy_input(params, st)
            mean, log_std = self.nets.act(params, s, z)
            raw = mean + jnp.exp(log_std) * jax.random.normal(k, mean.shape)
            logp = gaussian_logp(raw, mean, log_std)
            value = self.nets.value(params, s, st.theta_norm, z)
            expert = env.expert_raw(st)
            new, tr = env.step(params, st, raw, obs, p, refresh, fresh)
            b = Batch(state=s, theta_norm=st.theta_norm, zhat=st.zhat, use_zhat=st.use_zhat, raw=raw,
                      logp=logp, value=value, reward=tr.reward, done=tr.done, expert=expert,
                      failed=tr.failed, rate_err=tr.rate_err, thrust_err=tr.thrust_err)
            return new, b

        fresh = None
        if cfg.reset_per_unroll:
            key, k_fresh = jax.random.split(key)
            fresh = distributed.constrain_batch(
                jax.vmap(lambda k: env.reset(k, p))(jax.random.split(k_fresh, cfg.num_envs)), self.mesh)

        def body(st, x):
            k, t = x
            refresh = (it * cfg.unroll + t) % cfg.env.phi_every == 0
            keys = jax.random.split(k, cfg.num_envs)
            return jax.vmap(one, in_axes=(0, 0, None, 0 if fresh is not None else None))(st, keys, refresh, fresh)

        keys = jax.random.split(key, cfg.unroll)
        env_state, batch = jax.lax.scan(body, env_state, (keys, jnp.arange(cfg.unroll)))
        s, z, _, _ = jax.vmap(lambda st: env.policy_input(params, st))(env_state)
        last_value = self.nets.value(params, s, env_state.theta_norm, z)
        return env_state, batch, last_value

    def _iteration(self, ts: TrainState, env_state: EnvState, weights: LossWeights):
        cfg = self.cfg
        p, beta = schedules(cfg, ts.iteration)
        key, k_roll, k_perm = jax.random.split(ts.key, 3)
        env_state, batch, last_value = self._rollout(ts.params, env_state, k_roll, p, ts.iteration)
        flat = self._advantages(batch, last_value)
        snap_theta, snap_hist = env_state.theta_norm, env_state.history  # (N, 19), (N, 100, 14)
        params, opt_state, aux = self._update(ts.params, ts.opt_state, flat, snap_theta, snap_hist,
                                              k_perm, beta, weights)
        # Latent health on the snapshots: alignment error relative to the spread of z^θ.
        z_theta = self.nets.encode(params, snap_theta)
        zhat = self.nets.adapt(params, snap_hist)
        spread = jnp.sqrt(jnp.sum(jnp.var(z_theta, 0)))
        stats = {k: v.mean() for k, v in aux.items()}
        stats.update(reward=batch.reward.mean(), fail_rate=batch.failed.mean(),
                     rate_err=batch.rate_err.mean(), thrust_err=batch.thrust_err.mean(),
                     p_zhat=p, bc_weight=beta,
                     latent_err_rel=jnp.sqrt(jnp.mean(jnp.sum((z_theta - zhat) ** 2, -1))) / spread,
                     latent_min_std=jnp.sqrt(jnp.var(z_theta, 0)).min())
        ts = TrainState(params=params, opt_state=opt_state, iteration=ts.iteration + 1, key=key)
        return ts, env_state, stats

    def _advantages(self, batch: Batch, last_value):
        """GAE over the rollout (T, N) and flattening to samples: -> (batch, adv, ret) with
        leaves (T·N, ...), or on a mesh of D devices (D, T·N/D, ...), device by device."""
        cfg = self.cfg
        adv, ret = gae(batch.reward, batch.value, batch.done, last_value, cfg.gamma, cfg.gae_lambda)
        if self.mesh is None:
            return jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), (batch, adv, ret))
        # On a mesh of D devices, each device's samples together: leaves (D, T·N/D, ...), so that
        # flattening moves nothing between the devices (a time-major flatten of the sharded N would).
        d, t, n = self.mesh.size, cfg.unroll, cfg.num_envs
        return jax.tree.map(lambda a: jax.lax.with_sharding_constraint(
            a.reshape((t, d, n // d) + a.shape[2:]).swapaxes(0, 1).reshape((d, t * (n // d)) + a.shape[2:]),
            self._batch_sharding), (batch, adv, ret))

    def _update(self, params, opt_state, flat, snap_theta, snap_hist, key, beta, weights: LossWeights):
        """``epochs`` × ``minibatches`` gradient steps of :func:`loss_fn` on the flattened
        rollout ``flat`` (leaves (T·N, ...)) and the history snapshots (N, ...). Returns
        (params, opt_state, aux) with aux leaves (epochs, minibatches)."""
        cfg = self.cfg
        n = cfg.num_envs * cfg.unroll
        m = cfg.minibatches

        def epoch(carry, k):
            if self.mesh is None:
                perm = jax.random.permutation(k, n).reshape(m, -1)
                sperm = jax.random.permutation(jax.random.fold_in(k, 1), cfg.num_envs).reshape(m, -1)
                # One gather per leaf and epoch (minibatches × rows), sliced by the scan: the same
                # minibatches as gathering each one inside it, in fewer, larger kernels.
                mb, adv, ret = jax.tree.map(lambda x: x[perm], flat)
                snaps = (snap_theta[sperm], snap_hist[sperm])
            else:
                (mb, adv, ret), snaps = self._local_minibatches(k, flat, (snap_theta, snap_hist))
            shuffled = (mb, normalize_advantages(adv), ret, *snaps)

            def minibatch(carry, batch):
                params, opt_state = carry
                # Data parallel: each device takes a slice of the minibatch (no-op on one device).
                mb, a, r, st, sh = distributed.constrain_batch(batch, self.mesh)
                (loss, aux), grads = jax.value_and_grad(loss_fn, has_aux=True)(
                    params, self.nets, cfg, weights, self.ident_proj, mb, a, r, st, sh, beta)
                updates, opt_state = self.opt.update(grads, opt_state, params)
                return (optax.apply_updates(params, updates), opt_state), dict(aux, loss=loss)

            return jax.lax.scan(minibatch, carry, shuffled)

        (params, opt_state), aux = jax.lax.scan(epoch, (params, opt_state), jax.random.split(key, cfg.epochs))
        return params, opt_state, aux

    def _local_minibatches(self, key, flat, snaps):
        """An epoch's minibatches on a mesh of D devices, each device shuffling its own samples:
        flat leaves (D, T·N/D, ...) (:meth:`_advantages` on a mesh), snapshot leaves (N, ...), the N
        environments sharded in D blocks. Returns (flat, snaps) with leaves (m, B, ...): minibatch j
        is the j-th slice of every device's shuffled samples, device d's slice on device d. A global
        permutation (the one-device path) would move the whole rollout and every history between the
        devices each iteration (an all-gather of both); this moves nothing. The minibatches are as
        random (each a uniform draw within each device's share), not the same as one device's."""
        cfg, d, m = self.cfg, self.mesh.size, self.cfg.minibatches

        def local(x, k):   # (D, L, ...) -> shuffled per device with keys from k -> (m, D·L/m, ...) minibatches
            x = jax.lax.with_sharding_constraint(x, self._batch_sharding)
            length = x.shape[1]
            perm = jax.vmap(lambda kd: jax.random.permutation(kd, length))(jax.random.split(k, d))
            x = jax.vmap(lambda a, p: a[p])(x, perm)
            x = x.reshape((d, m, length // m) + x.shape[2:]).swapaxes(0, 1)
            return x.reshape((m, d * (length // m)) + x.shape[3:])

        n = cfg.num_envs
        # Every leaf shuffled by the same permutations (one key per group): a sample's rows stay together.
        rollout = jax.tree.map(lambda x: local(x, key), flat)
        k_snap = jax.random.fold_in(key, 1)
        snapshots = jax.tree.map(lambda x: local(x.reshape((d, n // d) + x.shape[1:]), k_snap), snaps)
        return rollout, snapshots


POLICY_MODULES = ("mu", "phi", "pi", "aux")


def _same_config(saved, cfg: TrainConfig) -> bool:
    """Whether a checkpoint's saved config is ``cfg`` (keys added since it was written read as
    their defaults)."""
    if not isinstance(saved, dict):
        return False
    try:
        return json.loads(json.dumps(TrainConfig.from_dict(saved).to_dict())) == json.loads(json.dumps(cfg.to_dict()))
    except (TypeError, ValueError):
        return False


def export_policy(params, path, meta: dict) -> Path:
    """Ship the deployable part (μ, φ, π, aux decoder) of ``params`` with its metadata."""
    return save_tree(path, {k: params[k] for k in POLICY_MODULES}, meta)


def load_policy_params(path):
    """Read shipped policy weights -> (params dict {'mu','phi','pi','aux'}, meta)."""
    template = jax.eval_shape(lambda: N.Networks().init(jax.random.PRNGKey(0)))   # shapes only
    params = load_tree(path, {k: template[k] for k in POLICY_MODULES}, finite=True)
    return params, load_meta(path)


def training_mesh(cfg: TrainConfig):
    """The data-parallel mesh for ``cfg``: the most devices (of those JAX sees) that divide
    ``num_envs / minibatches``, since each device shuffles its own environments' samples into every
    minibatch (:meth:`Trainer._local_minibatches`)."""
    whole = cfg.num_envs % cfg.minibatches == 0
    return distributed.batch_mesh(divides=cfg.num_envs // cfg.minibatches if whole else cfg.num_envs)


def train(cfg: TrainConfig, out_dir, *, resume: bool = True, log=print, trainer: Trainer | None = None,
          background_compile: bool | None = None) -> dict:
    """Train with checkpoints in ``out_dir`` (``checkpoint.npz``: training state and the
    environments' state, so an interrupted run resumed from it continues exactly as an
    uninterrupted one; resumed if present and ``resume``). Writes ``policy.npz`` (shipped
    format) and ``train_log.jsonl``. Returns the last stats and wall time. A progress bar
    (:mod:`mjxsysid.progress`) advances per iteration with the key metrics. ``trainer``: a
    prebuilt :class:`Trainer` for ``cfg`` (e.g. from :meth:`Trainer.reweighted`, to share its
    compile). ``background_compile`` (default on; the environment variable
    ``MJXSYSID_BACKGROUND_COMPILE=0`` turns it off, for timing the difference): the iteration
    compiles in a background thread while the states are made (:meth:`Trainer.start_compile`)."""

    t_enter = time.time()
    if background_compile is None:
        background_compile = os.environ.get("MJXSYSID_BACKGROUND_COMPILE", "1") != "0"
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if trainer is not None and trainer.cfg != cfg:
        raise ValueError("train: the trainer was built for a different config")
    mesh = training_mesh(cfg)
    if trainer is not None and (trainer.mesh.size if trainer.mesh is not None else 1) != mesh.size:
        raise ValueError(f"train: the trainer was built for another device mesh than the {mesh.size} device(s)")
    ckpt = out / "checkpoint.npz"
    meta = load_meta(ckpt) if (resume and ckpt.exists()) else None   # the run to resume
    # A checkpoint of another config is an error before anything compiles (a compile started in the
    # background would run on after the error, holding the CPU).
    if meta is not None and not _same_config(meta.get("config"), cfg):
        raise ValueError(f"{ckpt} was written with a different config; use a new --out or --no-resume")
    t_built = None
    if trainer is None:
        trainer = Trainer(cfg, mesh)
        t_built = time.time()
        if background_compile:
            trainer.start_compile()   # the iteration compiles while the states below are made
    ts, env_state = trainer.start(jax.random.PRNGKey(cfg.seed))   # a fresh run: state and environments
    if meta is not None:
        if meta.get("with_env"):
            ts, env_state = load_tree(ckpt, (ts, env_state))
            # resumed environments: shard their batch axis like a fresh reset's
            env_state = distributed.shard_batch(env_state, cfg.num_envs, mesh=mesh)
        else:  # older checkpoints hold the training state only: environments restart
            ts = load_tree(ckpt, ts)
            p0, _ = schedules(cfg, ts.iteration)
            env_state = trainer.reset(*trainer.place((jax.random.fold_in(ts.key, 123), p0)))
        log(f"resumed from {ckpt} at iteration {int(ts.iteration)}")
    if mesh.size > 1:
        log(f"{cfg.num_envs} environments sharded over {mesh.size} devices ({jax.process_count()} process(es))")
    ts = trainer.place(ts)
    steps_per_it = cfg.num_envs * cfg.unroll
    t_start = time.time()
    # Where this call's wall time goes (BENCHMARKS.md, issue 30): building the trainer, initialising and
    # resetting (compiles), the first iteration (its compile), the loop, checkpoints, the export.
    timing = {"setup_s": t_start - t_enter, "first_iteration_s": 0.0, "checkpoint_s": 0.0}
    if t_built is not None:
        timing["construct_s"] = t_built - t_enter   # of setup: building the Trainer (before any compile starts)
    wall_prev = meta.get("wall_s", 0.0) if meta is not None else 0.0
    logf = open(out / "train_log.jsonl", "a")
    stats = {}
    t_log, it_log = time.time(), int(ts.iteration)
    bar = progress(total=cfg.iterations, initial=int(ts.iteration), desc="train-policy", unit="it")
    # The iteration count is kept on the host: iterations are dispatched back to back and the
    # host waits on the device only where it logs or checkpoints (docs/runs/measurements/benchmarks/train_profile.json).
    it = int(ts.iteration)
    while it < cfg.iterations:
        ts, env_state, stats = trainer.iteration(ts, env_state)
        it += 1
        if not timing["first_iteration_s"]:
            jax.block_until_ready(stats)
            timing["first_iteration_s"] = time.time() - t_start
        bar.update(1)
        if it % cfg.log_every == 0 or it == cfg.iterations or it == 1:
            stats = {k: float(v) for k, v in stats.items()}
            if not bar.disable:
                bar.set_postfix(reward=f"{stats['reward']:+.3f}", rate_err=f"{stats['rate_err']:.3f}",
                                thrust_err=f"{stats['thrust_err']:.2f}", z_err=f"{stats['latent_err_rel']:.3f}",
                                refresh=False)
            now = time.time()
            sps = (it - it_log) * steps_per_it / max(now - t_log, 1e-9)
            t_log, it_log = now, it
            rec = dict(iteration=it, env_steps=it * steps_per_it, steps_per_s=sps,
                       wall_s=wall_prev + now - t_start, **stats)
            logf.write(json.dumps(rec) + "\n")
            logf.flush()
            log(f"it {it:5d}/{cfg.iterations} | {sps / 1e6:6.2f} M steps/s | reward {stats['reward']:+.3f} "
                f"| rate err {stats['rate_err']:.3f} rad/s | thrust err {stats['thrust_err']:.2f} | "
                f"fail {stats['fail_rate'] * 1e3:.2f}‰ | bc {stats['bc']:.4f} | "
                f"‖z−ẑ‖/spread {stats['latent_err_rel']:.3f} | min std z {stats['latent_min_std']:.2f} "
                f"| p {stats['p_zhat']:.2f}")
        if (it % cfg.checkpoint_every == 0 or it == cfg.iterations) and jax.process_index() == 0:
            t_ck = time.time()
            save_tree(ckpt, (ts, env_state), {"config": cfg.to_dict(), "iteration": it, "with_env": True,
                                              "wall_s": wall_prev + time.time() - t_start})
            timing["checkpoint_s"] += time.time() - t_ck
    bar.close()
    logf.close()
    wall = wall_prev + time.time() - t_start
    timing["loop_s"] = time.time() - t_start
    for name, sec in getattr(trainer, "compile_seconds", {}).items():   # compiled in the background
        timing[f"{name}_compile_s"] = sec
    if jax.process_index() == 0:
        export_policy(ts.params, out / "policy.npz", {
            "config": cfg.to_dict(), "normalizer": trainer.env.normalizer.to_dict(),
            "iterations": int(ts.iteration), "env_steps": int(ts.iteration) * steps_per_it,
            "wall_s": wall, "final_stats": {k: float(v) for k, v in stats.items()},
            "device": str(jax.devices()[0]), "device_kind": getattr(jax.devices()[0], "device_kind", ""),
            "devices": mesh.size, "jax": jax.__version__, "timing": timing})
    log("time: " + ", ".join(f"{k[:-2].replace('_', ' ')} {v:.1f} s" for k, v in timing.items()))
    return {"stats": {k: float(v) for k, v in stats.items()}, "wall_s": wall, "timing": timing}
