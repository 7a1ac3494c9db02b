"""The trained adaptive policy as a low-level controller (the interface of
:mod:`mjxsysid.control.low_level`): ``init(key)``, ``step(carry, imu, command)``, plus
``latent(carry)`` -> the current ẑ, so downstream tools (decoding, experiments) can read it.

Deployment mirrors training exactly (:mod:`mjxsysid.policy.adaptive.env`): observation from the IMU and
the command, policy state [obs, r_{t−1}], the deterministic action (the mean), history push, and
ẑ = φ(history) refreshed every ``phi_every`` steps (0 until the first refresh).
"""
from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import struct

from mjxsysid.control.low_level import Command
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.policy.adaptive.weights import PRETRAINED_DIR, load_policy_params

PRETRAINED = PRETRAINED_DIR / "policy.npz"


class PolicyCarry(NamedTuple):
    history: jax.Array   # (100, 14)
    last_raw: jax.Array  # (4,)
    zhat: jax.Array      # (8,)
    count: jax.Array     # () int32 steps taken
    started: jax.Array   # () bool: history initialised from the first observation


@struct.dataclass
class PolicyController:
    """params: {'mu', 'phi', 'pi', ...}. z_override: (8,) latent to use instead of ẑ when
    ``use_override`` (e.g. z^θ = μ(θ) for the privileged policy)."""
    params: dict
    z_override: jax.Array
    use_override: jax.Array
    phi_every: int = struct.field(pytree_node=False, default=10)

    @classmethod
    def load(cls, path=None, *, phi_every: int | None = None) -> "PolicyController":
        path = Path(path) if path else PRETRAINED
        if path.is_dir():
            path = path / "policy.npz"
        params, meta = load_policy_params(path)
        pe = phi_every or meta.get("config", {}).get("env", {}).get("phi_every", 10)
        return cls(params=params, z_override=jnp.zeros(N.LATENT), use_override=jnp.array(False),
                   phi_every=int(pe))

    def with_privileged(self, theta_norm) -> "PolicyController":
        """The same policy conditioned on z^θ = μ(θ_norm) instead of ẑ; θ_norm (19,) or
        (n, 19) (then a batch for ``fly_batch``)."""
        z = N.Networks().encode(self.params, jnp.asarray(theta_norm, jnp.float32))
        return self.replace(z_override=z, use_override=jnp.ones(z.shape[:-1], bool))

    def batch_axes(self):
        """vmap axes for a batch built by :meth:`batched`: weights shared, latents per vehicle."""
        return PolicyController(params=None, z_override=0, use_override=0, phi_every=self.phi_every)

    def batched(self, n: int) -> "PolicyController":
        """n vehicles sharing these weights (for ``fly_batch``)."""
        return self.replace(z_override=jnp.broadcast_to(self.z_override, (n, N.LATENT)),
                            use_override=jnp.broadcast_to(self.use_override, (n,)))

    @property
    def rate_hz(self) -> float:
        """The policy acts at every simulator step (500 Hz); ẑ refreshes every ``phi_every``."""
        return 500.0

    def init(self, key=None) -> PolicyCarry:
        return PolicyCarry(history=jnp.zeros((N.HISTORY, N.STATE)), last_raw=jnp.zeros(N.ACT),
                           zhat=jnp.zeros(N.LATENT), count=jnp.int32(0), started=jnp.array(False))

    def latent(self, carry: PolicyCarry) -> jax.Array:
        return carry.zhat

    def step(self, carry: PolicyCarry, imu, command: Command):
        return self.step_at(carry, imu, command, carry.count)

    def step_at(self, carry: PolicyCarry, imu, command: Command, index, raw=None):
        """:meth:`step` with the step index given by the caller (the harness passes its scan
        index, unbatched, so the every-``phi_every`` refresh of ẑ is a real branch under vmap
        instead of φ evaluated every step). ``raw`` (4,): a recorded action in [−1, 1] that
        stands in for π's (replay)."""
        nets = N.Networks()
        obs = N.observation(imu, command.a_cmd, command.omega_cmd)
        history = jnp.where(carry.started, carry.history, N.initial_history(obs))
        if raw is None:
            s = jnp.concatenate([obs, carry.last_raw])
            z = jnp.where(self.use_override, self.z_override, carry.zhat)
            raw, _ = nets.act(self.params, s, z)
        history = N.push_history(history, obs, raw)
        count = carry.count + 1
        zhat = jax.lax.cond((index + 1) % self.phi_every == 0, lambda h: nets.adapt(self.params, h),
                            lambda h: carry.zhat, history)
        return PolicyCarry(history, raw, zhat, count, jnp.array(True)), N.to_motor(raw)

    def replay(self, imu, a_cmd, omega_cmd, motor):
        """ẑ after every step of a recorded flight (T, 8), the history rebuilt from the logged
        IMU (T, 6), a_cmd (T,), omega_cmd (T, 3) and motor commands (T, 4) in [0, 1] (which
        stand in for the policy's own actions)."""
        import numpy as np
        xs = tuple(jnp.asarray(a, jnp.float32) for a in (imu, a_cmd, omega_cmd, motor))
        return np.asarray(_replay(self, xs))

    def replay_actions(self, imu, a_cmd, omega_cmd, motor, zhat, rows):
        """The policy's own motor commands (R, 4) at ``rows`` (R,) (indices ≥ 1) of a recorded
        flight, given the logged inputs and ẑ (T, 8) of :meth:`replay`: at step t the policy
        sees the observation of row t, the previous logged action and ẑ after step t − 1. For a
        flight this policy flew, they equal the logged motor commands."""
        import numpy as np
        rows = np.asarray(rows, int)
        at = lambda a, r: jnp.asarray(np.asarray(a)[r], jnp.float32)   # noqa: E731 (rows first: logs are long)
        obs = N.observation(at(imu, rows), at(a_cmd, rows), at(omega_cmd, rows))
        last = 2.0 * at(motor, rows - 1) - 1.0
        raw = _act(self.params, jnp.concatenate([obs, last], -1), at(zhat, rows - 1))
        return np.asarray(N.to_motor(raw))


@jax.jit
def _act(params, state, z):
    return N.Networks().act(params, state, z)[0]


@jax.jit
def _replay(ctrl: PolicyController, xs):
    def body(carry, x):
        imu, a, w, u = x
        new, _ = ctrl.step_at(carry, imu, Command(a, w), carry.count, raw=2.0 * u - 1.0)
        return new, new.zhat

    return jax.lax.scan(body, ctrl.init(), xs)[1]
