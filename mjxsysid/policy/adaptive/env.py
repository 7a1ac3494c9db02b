"""Training environment of the adaptive policy: the simulator with θ resampled every episode.

Commands (a_cmd, ω_cmd) come from the cascaded high-level controller tracking a random 3-D
lemniscate (period, size, yaw weave and gains drawn per episode, gains between `naive` and
`baseline`), plus a random piecewise-constant excitation of per-episode amplitude — so the
policy sees both realistic tracking commands and random command sequences. A random
Gaussian world force (per-episode σ) disturbs the vehicle; the IMU is noisy.

Reward per step (tracking the *commanded* collective thrust and body rates)::

    r = 1 − w_rate ‖ω − ω_cmd‖ − w_thrust |f_z − a_cmd| − w_smooth ‖r_t − r_{t−1}‖² − w_sat sat_t

and ``fail_penalty`` with termination when the vehicle diverges, flips over or leaves a 3 m
tube around its reference. Everything is unbatched and pure; training vmaps it. :meth:`TrainEnv.step`
steps the simulator only; the wrappers :class:`LatentRefresh` (ẑ = φ(history) every
``phi_every`` steps) and :class:`AutoReset` (finished episodes restarted in place) make the
step that training and evaluation roll (:func:`training_env`).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from mjxsysid import theta as P
from mjxsysid.control.high_level import PRESETS, Cascade, Estimate
from mjxsysid.control.low_level import Command, KTheta
from mjxsysid.control.references import Lemniscate
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.policy.adaptive.config import IMU_FIELDS, EnvConfig
from mjxsysid.sim.quadrotor import (
    Quadrotor,
    SimConfig,
    SimState,
    hover_rotor_speed,
    quat_to_mat,
)


@struct.dataclass
class EnvState:
    sim: SimState
    theta: jax.Array          # (19,)
    theta_norm: jax.Array     # (19,)
    cascade: Cascade
    integral: jax.Array       # (3,)
    ref: Lemniscate
    t0: jax.Array             # () reference time offset
    excite_scale: jax.Array   # (4,)
    excite: jax.Array         # (4,) current excitation [a, ω]
    force_sigma: jax.Array    # () N
    command: Command          # command for the current step
    history: jax.Array        # (100, 14)
    last_raw: jax.Array       # (4,)
    zhat: jax.Array           # (8,)
    use_zhat: jax.Array       # () bool: policy sees ẑ instead of z^θ this episode
    step: jax.Array           # () int32
    key: jax.Array


class Transition(struct.PyTreeNode):
    """What one env step returns besides the state (all unbatched)."""
    reward: jax.Array
    done: jax.Array
    failed: jax.Array
    rate_err: jax.Array
    thrust_err: jax.Array
    reset_key: jax.Array      # (2,) the key an episode that ends here restarts from (AutoReset)


class TrainEnv:
    """``focus_theta`` (n, 19): weak systems (e.g. ``mjxsysid probe``'s); a fraction
    ``config.focus_weight`` of episodes flies one of them (uniformly), the rest the prior."""

    def __init__(self, config: EnvConfig = EnvConfig(), normalizer: P.Normalizer | None = None,
                 focus_theta=None):
        if not 0.0 <= config.focus_weight <= 1.0:
            raise ValueError(f"focus_weight must be in [0, 1], got {config.focus_weight}")
        self.config = config
        self.focus_theta = None if focus_theta is None else jnp.asarray(focus_theta, jnp.float32)
        if self.focus_theta is not None and (self.focus_theta.ndim != 2 or self.focus_theta.shape[1] != P.N_PARAMS
                                             or self.focus_theta.shape[0] == 0):
            raise ValueError(f"focus systems must have shape (n, {P.N_PARAMS}), n >= 1; got {self.focus_theta.shape}")
        self.prior = P.get_prior(config.prior)
        self.sim = Quadrotor(SimConfig(**{k: getattr(config, k) for k in IMU_FIELDS}))
        self.normalizer = normalizer or P.prior_normalizer(config.prior)
        self.nets = N.Networks()

    # -------------------------------------------------------------------------------- reset
    def reset(self, key, p_zhat) -> EnvState:
        """A new episode: θ from the prior, a random reference, gains, excitation and force σ.
        ẑ starts at 0 and is refreshed with the others (every ``phi_every`` steps)."""
        c = self.config
        ks = jax.random.split(key, 12)
        theta = self.prior.sample(ks[0], 1)[0]
        if self.focus_theta is not None:   # a fraction of episodes flies one of the weak systems
            kf, kw = jax.random.split(jax.random.fold_in(ks[0], 1))
            pick = self.focus_theta[jax.random.randint(kf, (), 0, self.focus_theta.shape[0])]
            theta = jnp.where(jax.random.uniform(kw) < c.focus_weight, pick, theta)
        u = lambda k, lo, hi, shape=(): jax.random.uniform(k, shape, jnp.float32, lo, hi)
        ref = Lemniscate(center=jnp.array([0.0, 0.0, 1.0]),
                         size=u(ks[1], 0.0, 1.0, (3,)) * jnp.asarray(c.size_max),
                         period=u(ks[2], *c.period_range),
                         yaw=u(ks[3], -jnp.pi, jnp.pi),
                         yaw_amplitude=u(ks[4], -c.yaw_amplitude_max, c.yaw_amplitude_max),
                         duration=jnp.float32(jnp.inf))
        t0 = u(ks[5], 0.0, 1.0) * ref.period
        mix = u(ks[6], 0.0, 1.0)
        gains = jnp.asarray(PRESETS["naive"]) + mix * (jnp.asarray(PRESETS["baseline"]) - jnp.asarray(PRESETS["naive"]))
        cascade = Cascade(gains, jnp.float32(12.0))
        r0 = ref.at(t0)
        half = 0.5 * r0.yaw
        sim_state = self.sim.init(theta, ks[7], pos=r0.pos, quat=jnp.array([jnp.cos(half), 0, 0, jnp.sin(half)]),
                                  rotor_speed=hover_rotor_speed(theta))
        scale = u(ks[8], 0.0, 1.0) * jnp.array([c.excite_thrust, *c.excite_rate])
        integral, cmd = cascade.step(jnp.zeros(3), self._estimate(sim_state), r0, self.sim.config.dt)
        obs = N.observation(sim_state.imu, cmd.a_cmd, cmd.omega_cmd)
        history = N.initial_history(obs)
        state = EnvState(
            sim=sim_state, theta=theta, theta_norm=self.normalizer.normalize(theta), cascade=cascade,
            integral=integral, ref=ref, t0=t0, excite_scale=scale, excite=jnp.zeros(4),
            force_sigma=u(ks[9], 0.0, c.force_sigma_max) * theta[P.MASS] * P.GRAVITY,
            command=cmd, history=history, last_raw=jnp.zeros(4),
            zhat=jnp.zeros(N.LATENT), use_zhat=jax.random.uniform(ks[10]) < p_zhat,
            step=jnp.int32(0), key=ks[11])
        return state

    @staticmethod
    def _estimate(s: SimState) -> Estimate:
        return Estimate(s.pos, s.vel, s.quat, s.omega)

    # --------------------------------------------------------------------------- policy I/O
    def policy_input(self, params, state: EnvState):
        """(s_t (14), z used by the policy (8), z^θ (8), obs_t (10))."""
        obs = N.observation(state.sim.imu, state.command.a_cmd, state.command.omega_cmd)
        s = jnp.concatenate([obs, state.last_raw])
        z_theta = self.nets.encode(params, state.theta_norm)
        z = jnp.where(state.use_zhat, jax.lax.stop_gradient(state.zhat), z_theta)
        return s, z, z_theta, obs

    def expert_raw(self, state: EnvState):
        """K_θ(true θ) on the current command, as a raw action in [−1, 1] (4,)."""
        u = KTheta.make(state.theta).motor_command(state.command, state.sim.imu[0:3])
        return 2.0 * u - 1.0

    # --------------------------------------------------------------------------------- step
    def step(self, state: EnvState, raw, obs):
        """One simulator step of raw action r (4,) (obs (10,): this step's observation, pushed to
        the history with r) -> (state, Transition). Pure: ẑ is left as it is and an episode that
        ends here is not restarted (the wrappers :class:`LatentRefresh` and :class:`AutoReset`
        do both)."""
        c = self.config
        dt = self.sim.config.dt
        key, k_force, k_ex, k_hold, k_reset = jax.random.split(state.key, 5)
        raw = jnp.clip(raw, -1.0, 1.0)
        history = N.push_history(state.history, obs, raw)
        force = state.force_sigma * jax.random.normal(k_force, (3,))
        sim = self.sim.step(state.theta, state.sim, N.to_motor(raw), force)
        # Reward on the command this action answered.
        true_imu = sim.imu_buffer[-1]
        rate_err = jnp.linalg.norm(sim.omega - state.command.omega_cmd)
        thrust_err = jnp.abs(true_imu[5] - state.command.a_cmd)
        u = N.to_motor(raw)
        sat = jnp.mean((u <= 1e-3) | (u >= 1 - 1e-3))
        reward = (1.0 - c.w_rate * rate_err - c.w_thrust * thrust_err
                  - c.w_smooth * jnp.sum((raw - state.last_raw) ** 2) - c.w_sat * sat)
        # Next command.
        t = state.t0 + (state.step + 1).astype(jnp.float32) * dt
        r = state.ref.at(t)
        integral, cmd = state.cascade.step(state.integral, self._estimate(sim), r, dt)
        hold = jax.random.uniform(k_hold) < dt / c.excite_hold
        excite = jnp.where(hold, jax.random.uniform(k_ex, (4,), minval=-1.0, maxval=1.0) * state.excite_scale,
                           state.excite)
        cmd = Command(a_cmd=jnp.maximum(cmd.a_cmd + excite[0], 0.0), omega_cmd=cmd.omega_cmd + excite[1:])
        step = state.step + 1
        upright = quat_to_mat(sim.quat)[2, 2] > 0.0
        failed = sim.diverged | ~upright | (jnp.linalg.norm(sim.pos - r.pos) > c.tube)
        done = failed | (step >= c.episode_steps)
        reward = jnp.where(failed, c.fail_penalty, reward)
        new = state.replace(sim=sim, integral=integral, excite=excite, command=cmd, history=history,
                            last_raw=raw, step=step, key=key)
        return new, Transition(reward=reward, done=done, failed=failed, rate_err=rate_err,
                               thrust_err=thrust_err, reset_key=k_reset)


class Wrapper:
    """An environment around another one (MuJoCo Playground's ``Wrapper``): every attribute
    it does not define (``reset``, ``policy_input``, ``nets``, ``config`` ...) is the wrapped
    environment's."""

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        if name == "env" or name.startswith("__"):     # not yet set (copy, pickle)
            raise AttributeError(name)
        return getattr(self.env, name)


class LatentRefresh(Wrapper):
    """The wrapped step, then ẑ = φ(history) recomputed where ``refresh``."""

    def step(self, params, state: EnvState, raw, obs, refresh):
        """``refresh``: a scalar shared by the whole batch, so vmap keeps a real branch (φ runs
        only on refresh steps). Returns (state, Transition)."""
        new, tr = self.env.step(state, raw, obs)
        zhat = jax.lax.cond(refresh, lambda h: self.nets.adapt(params, h), lambda h: state.zhat, new.history)
        return new.replace(zhat=zhat), tr


class AutoReset(Wrapper):
    """The wrapped step (:class:`LatentRefresh`'s), then every finished episode restarted in
    place."""

    def step(self, params, state: EnvState, raw, obs, p_zhat, refresh, fresh: EnvState | None = None):
        """Returns (state, Transition). Where ``Transition.done``, the state is a new
        :meth:`TrainEnv.reset` on ``Transition.reset_key`` (computed every step, for every
        environment, and selected where done; ``p_zhat``: its probability of flying on ẑ) or,
        given ``fresh``, that precomputed episode start (its random stream re-keyed per step, so
        an environment that ends twice before ``fresh`` is redrawn flies the same vehicle and
        reference with new noise)."""
        new, tr = self.env.step(params, state, raw, obs, refresh)
        start = self.reset(tr.reset_key, p_zhat) if fresh is None else fresh.replace(key=tr.reset_key)
        return jax.tree.map(lambda a, b: jnp.where(tr.done, a, b), start, new), tr


def training_env(env: TrainEnv) -> AutoReset:
    """``env`` as training and evaluation roll it: ẑ refreshed on schedule, episodes restarted
    where they end (``step(params, state, raw, obs, p_zhat, refresh, fresh=None)``)."""
    return AutoReset(LatentRefresh(env))
