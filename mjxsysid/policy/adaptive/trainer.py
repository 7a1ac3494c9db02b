"""The trainer of the adaptive policy: one jitted training iteration (rollout scan, GAE,
epochs × minibatches scans of :func:`~mjxsysid.policy.adaptive.losses.loss_fn`), its optimiser,
and its compile (in background threads, overlapping the setup of a run). The loss weights are a
traced argument, so configs that differ only in them share one compile (:meth:`Trainer.reweighted`).
The host loop that runs it is :func:`mjxsysid.policy.adaptive.train.train`.
"""
from __future__ import annotations

import copy
import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp
import optax
from flax import struct
from jax.sharding import NamedSharding, PartitionSpec

from mjxsysid.runtime import distributed
from mjxsysid.runtime.ahead import Ahead
from mjxsysid.policy.adaptive.config import TrainConfig
from mjxsysid.policy.adaptive.env import EnvState, TrainEnv, training_env
from mjxsysid.policy.adaptive.focus import load_weak
from mjxsysid.policy.adaptive.losses import (
    LOSS_WEIGHT_FIELDS,
    Batch,
    LossWeights,
    gae,
    gaussian_logp,
    identifiable_projection,
    loss_fn,
    normalize_advantages,
    schedules,
)
from mjxsysid.policy.adaptive.weights import load_policy_params, same_normalizer


@struct.dataclass
class TrainState:
    params: dict
    opt_state: optax.OptState
    iteration: jax.Array
    key: jax.Array


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


def _host_device():
    """JAX's CPU device, or None (the default device) where JAX runs without a CPU backend."""
    try:
        return jax.devices("cpu")[0]
    except RuntimeError:
        return None


class Trainer:
    """Builds the jitted iteration for a config. ``init(key)``, ``iteration(ts, env_state)``;
    ``reweighted(cfg)``: the same compiled iteration under another config's loss weights.

    ``mesh`` (a 1-D ``'batch'`` mesh, :func:`mjxsysid.runtime.distributed.batch_mesh`): data-parallel
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
            self.rolled = training_env(self.env)   # the env as the rollout steps it (ẑ refresh, auto-reset)
            self.ident_proj = identifiable_projection(self.env.normalizer, self.env.prior,
                                                      yaw_authority=cfg.ident_yaw_authority)
        self.nets = self.env.nets
        self.opt = optimizer(cfg)
        self._compiling = None   # background compiles (start_compile): an Ahead
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
        if self._compiling is not None and name in self._compiling:
            self._compiled[name] = self._compiling.result(name)
            if not any(n in self._compiling for n in ("start", "iteration")):
                self._compiling.close()          # both taken: end the threads
        return self._compiled.get(name)

    @property
    def compile_seconds(self) -> dict:
        """Each background compile's wall time once done (:meth:`start_compile`)."""
        return {} if self._compiling is None else dict(self._compiling.seconds)

    def start_compile(self) -> None:
        """Compile the iteration and :meth:`start` on two background threads (:class:`~mjxsysid.runtime.ahead.Ahead`:
        XLA compiles without holding the GIL), so that they compile side by side and the iteration's compile
        overlaps the setup that follows (starting, loading a checkpoint): the cold start of ``train`` costs the
        longest of them instead of their sum. :meth:`start` and :meth:`iteration` wait for their executable (and
        raise what its compile raised)."""
        if self._compiling is not None or self._compiled:
            return
        params, key = self._abstract_start_inputs()
        ts, env = jax.eval_shape(self._start, params, key)
        self._compiling = Ahead(on=True, threads=2)
        self._compiling.submit("start", lambda: self._start_jit.lower(params, key).compile())
        self._compiling.submit("iteration", lambda: self._iteration_jit.lower(ts, env, self.weights).compile())

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
        if norm is not None and not same_normalizer(norm, self.env.normalizer.to_dict()):
            raise ValueError(f"init_from: {path} was trained with another θ normalisation (prior) than this config's")
        return warm

    def _reset(self, key, p):
        keys = jax.random.split(key, self.cfg.num_envs)
        st = jax.vmap(lambda k: self.env.reset(k, p))(keys)
        # Desynchronise episodes so resets spread over time.
        offs = jax.random.randint(jax.random.fold_in(key, 7), (self.cfg.num_envs,), 0, self.cfg.env.episode_steps)
        return st.replace(step=offs)

    def _rollout(self, params, env_state: EnvState, key, p, it):
        cfg, env, rolled = self.cfg, self.env, self.rolled

        def one(st, k, refresh, fresh):
            s, z, z_theta, obs = env.policy_input(params, st)
            mean, log_std = self.nets.act(params, s, z)
            raw = mean + jnp.exp(log_std) * jax.random.normal(k, mean.shape)
            logp = gaussian_logp(raw, mean, log_std)
            value = self.nets.value(params, s, st.theta_norm, z)
            expert = env.expert_raw(st)
            new, tr = rolled.step(params, st, raw, obs, p, refresh, fresh)
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

