"""The rotor state a predictive rollout starts from: the commands the controller sent (a window
of them, :class:`CommandHistory`) run through each model's own motor lag, so that a model with slow
motors starts its rollouts with its rotors where that lag puts them (``TunerConfig.rotor_state``)."""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from mjxsysid import theta as P
from mjxsysid.rollout.harness import LoopCarry
from mjxsysid.sim.motors import rotor_speed_after
from mjxsysid.sim.quadrotor import SimConfig, hover_rotor_speed

ROTOR_STATES = ("estimate", "steady", "true")
"""Where the predictive rollouts start the rotors (``TunerConfig.rotor_state``)."""

class CommandHistory(NamedTuple):
    """The last W motor commands (normalised) the controller sent, oldest first: cmds (W, 4);
    count () int32: how many of the W were sent in this flight (the ``W − count`` at the front
    predate it). Batched: (B, W, 4) and (B,)."""
    cmds: jax.Array
    count: jax.Array


def empty_history(window: int, batch: int) -> CommandHistory:
    """No command sent yet, for ``batch`` vehicles and a ``window`` of control steps."""
    return CommandHistory(jnp.zeros((batch, window, 4), jnp.float32), jnp.zeros(batch, jnp.int32))


def push_history(hist: CommandHistory, cmds) -> CommandHistory:
    """Append the commands sent since (B, n, 4), oldest first; keep the last W."""
    w = hist.cmds.shape[-2]
    cmds = jnp.asarray(cmds, jnp.float32)
    both = jnp.concatenate([hist.cmds, cmds], -2)[..., -w:, :]
    return CommandHistory(both, jnp.minimum(hist.count + cmds.shape[-2], w).astype(jnp.int32))


def estimate_rotor_speed(theta, hist: CommandHistory, config: SimConfig) -> jax.Array:
    """The rotor speeds (4,) rad/s that model θ (19,) implies now: its own motor lag (τ_m, Ω_max)
    run over the command history ``hist`` (unbatched), from the hover speeds of θ where the
    history reaches the flight's start (flights start in hover), else from θ's steady state for
    the oldest command in the window (an error that decays as e^{−W/τ_m}). Reads no hidden
    state: with the true θ it equals the simulator's rotor speeds to float round-off once the
    start is forgotten (at once while the window covers the flight)."""
    w = hist.cmds.shape[0]
    full = hist.count >= w
    speed0 = jnp.where(full, jnp.clip(hist.cmds[0], 0.0, 1.0) * theta[P.OMEGA_MAX], hover_rotor_speed(theta))
    return rotor_speed_after(theta, speed0, hist.cmds, config, mask=jnp.arange(w) >= w - hist.count)


def start_rotor_speed(mode: str, theta, hist: CommandHistory, carry: LoopCarry, config: SimConfig) -> jax.Array:
    """Rotor speeds (4,) a predictive rollout of model θ starts from (``TunerConfig.rotor_state``):
    'estimate' (:func:`estimate_rotor_speed`), 'steady' (θ's steady state for the last command,
    θ's hover before any) or 'true' (the simulator's, a diagnostic)."""
    if mode == "estimate":
        return estimate_rotor_speed(theta, hist, config)
    if mode == "steady":
        last = jnp.clip(hist.cmds[-1], 0.0, 1.0) * theta[P.OMEGA_MAX]
        return jnp.where(hist.count > 0, last, hover_rotor_speed(theta))
    if mode == "true":
        return carry.sim.rotor_speed
    raise ValueError(f"unknown rotor_state {mode!r}; choose from {ROTOR_STATES}")
