"""A frozen latent policy as a dm_env agent: ``agent(timestep) -> action``.

It sees what it sees in mjxsysid's closed loop — the IMU of the last step and the cascade's
command — and keeps its own carry (history, ẑ) across steps, reset at every first timestep; it
works with ``dm_control.viewer.launch(env, policy=agent)`` and any loop over ``env.step``.
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.control.low_level import Command
from mjxsysid.policy.interface import resolve_policy


@jax.jit
def _act(controller, carry, imu, a_cmd, omega_cmd, index):
    return controller.step_at(carry, imu, Command(a_cmd=a_cmd, omega_cmd=omega_cmd), index)


class PolicyAgent:
    """``policy``/``weights`` as for :func:`~mjxsysid.policy.interface.resolve_policy` (default
    the shipped policy). ``latent``: the current ẑ (8,)."""

    def __init__(self, policy="mjxsysid", weights=None, seed: int = 0):
        self.policy = resolve_policy(policy, weights)
        self.controller = self.policy.load()
        self._key = jax.random.PRNGKey(seed)
        self.reset()

    def reset(self) -> None:
        self._carry = self.controller.init(self._key)
        self._index = 0

    @property
    def latent(self) -> np.ndarray:
        return np.asarray(self.controller.latent(self._carry))

    def __call__(self, timestep) -> np.ndarray:
        """Motor commands (4,) in [0, 1] for a timestep of :func:`mjxsysid.envs.make_env`."""
        if timestep.first():
            self.reset()
        obs = timestep.observation
        for k in ("imu", "command"):
            if k not in obs:
                raise ValueError(f"PolicyAgent: the observation has no {k!r} (an mjxsysid.envs environment?)")
        cmd = np.asarray(obs["command"], np.float32)
        self._carry, u = _act(self.controller, self._carry, jnp.asarray(obs["imu"], jnp.float32),
                              jnp.float32(cmd[0]), jnp.asarray(cmd[1:4]), jnp.int32(self._index))
        self._index += 1
        return np.asarray(u, np.float64)
