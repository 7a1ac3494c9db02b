"""Rollouts: open loop (given motor commands) and closed loop (a controller in the scan).

The per-vehicle functions are unbatched; :func:`rollout_batch` is the one vmap boundary
(over θ, initial states, command sequences and disturbances) and is compiled once per
shape: a new θ batch re-uses it.
"""
from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp

from mjxsysid.sim.quadrotor import Quadrotor, SimState


def rollout(sim: Quadrotor, theta, state: SimState, motor_cmds, forces=None):
    """Open-loop rollout of one vehicle.

    theta (19,); state: SimState; motor_cmds (T, 4) normalised; forces (T, 3) N world or None.
    Returns (final SimState, Frame with (T, ...) leaves: the state *after* each step).
    """
    motor_cmds = jnp.asarray(motor_cmds, jnp.float32)
    if forces is None:
        forces = jnp.zeros(motor_cmds.shape[:-1] + (3,), jnp.float32)

    def body(s, inp):
        u, f = inp
        s = sim.step(theta, s, u, f)
        return s, sim.frame(s, u, f)

    return jax.lax.scan(body, state, (motor_cmds, jnp.asarray(forces, jnp.float32)))


@functools.lru_cache(maxsize=None)
def _batched_rollout(sim: Quadrotor):
    return jax.jit(jax.vmap(functools.partial(rollout, sim)))


def rollout_batch(sim: Quadrotor, theta, state: SimState, motor_cmds, forces=None):
    """Batched open-loop rollout: theta (B, 19), state with (B, ...) leaves, motor_cmds
    (B, T, 4), forces (B, T, 3) or None. Returns (final states, Frame with (B, T, ...) leaves).
    Compiled once per (sim, shapes)."""
    motor_cmds = jnp.asarray(motor_cmds, jnp.float32)
    if forces is None:
        forces = jnp.zeros(motor_cmds.shape[:-1] + (3,), jnp.float32)
    return _batched_rollout(sim)(jnp.asarray(theta, jnp.float32), state, motor_cmds, forces)


def init_batch(sim: Quadrotor, theta, key, **kw) -> SimState:
    """Initial states for a batch θ (B, 19); keyword arrays (pos, quat, vel, omega, rotor_speed)
    may be (B, k) or unbatched (k,)."""
    theta = jnp.asarray(theta, jnp.float32)
    b = theta.shape[0]
    keys = jax.random.split(key, b)
    names = list(kw)
    vals = [jnp.broadcast_to(jnp.asarray(kw[n], jnp.float32), (b,) + jnp.shape(kw[n])[-1:])
            for n in names]

    def one(t, k, *v):
        return sim.init(t, k, **dict(zip(names, v)))

    return jax.vmap(one)(theta, keys, *vals)


def closed_loop(sim: Quadrotor, theta, state: SimState, carry0, controller: Callable, forces):
    """Closed-loop rollout of one vehicle.

    controller(carry, state, t_index) -> (carry, motor_cmd (4,), record) is called before each
    step; forces (T, 3) N world. Returns (final state, final carry, (Frame, records) stacked (T, ...)).
    """
    def body(c, inp):
        s, cc = c
        i, f = inp
        cc, u, rec = controller(cc, s, i)
        s = sim.step(theta, s, u, f)
        return (s, cc), (sim.frame(s, u, f), rec)

    forces = jnp.asarray(forces, jnp.float32)
    idx = jnp.arange(forces.shape[0], dtype=jnp.int32)
    (s, cc), out = jax.lax.scan(body, (state, carry0), (idx, forces))
    return s, cc, out
