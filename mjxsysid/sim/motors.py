"""The rotors of :mod:`.quadrotor`: first-order speed dynamics, integrated exactly over a step, and the static
motor map from a normalised command to the speed it settles at. Pure and unbatched; ``config`` is the
simulator's :class:`~mjxsysid.sim.quadrotor.SimConfig` (its motor map, substeps and physics step)."""
from __future__ import annotations

import jax
import jax.numpy as jnp

from mjxsysid import theta as P


def mean_square_speed(omega0, omega_cmd, tau_m, h, exp=jnp.exp):
    """Exact mean of Ω(t)² over [0, h] for Ω̇ = (Ω_cmd − Ω)/τ_m, and Ω(h).

    omega0, omega_cmd: (4,) rad/s; tau_m, h: scalars (s). Returns (mean Ω² (4,), Ω(h) (4,)).
    ``exp``: ``np.exp`` evaluates it in NumPy float64 (the dm_control twin, mjxsysid.envs).
    """
    a = exp(-h / tau_m)
    d = omega0 - omega_cmd
    r1 = tau_m / h * (1.0 - a)  # mean of e^{-t/τ}
    r2 = tau_m / (2.0 * h) * (1.0 - a * a)  # mean of e^{-2t/τ}
    return omega_cmd**2 + 2.0 * omega_cmd * d * r1 + d * d * r2, omega_cmd + d * a


def commanded_speed(cmd, omega_max, config):
    """The steady-state rotor speed (rad/s) of the normalised command ``cmd`` (..., 4), clipped to [0, 1],
    at ``omega_max`` (rad/s, broadcast): Ω_max u by default; with ``config.motor_map``,
    Ω_max max(0, idle + (1 − idle) s(u)) (idle ``motor_idle``, κ ``motor_kappa``; s: Indiflight's
    √(κ u² + (1 − κ) u) for κ ≤ 1, u √(2 − κ + (κ − 1) u²) beyond): it is Ω_max at u = 1 and idle Ω_max at u = 0."""
    u = jnp.clip(jnp.asarray(cmd, jnp.float32), 0.0, 1.0)
    if not config.motor_map:  # a Python branch: off, the default map to the bit
        return u * omega_max
    idle, kappa = config.motor_idle, config.motor_kappa
    shape = (u if kappa == 1.0 else jnp.sqrt(kappa * u * u + (1.0 - kappa) * u) if kappa < 1.0
             else u * jnp.sqrt(2.0 - kappa + (kappa - 1.0) * u * u))
    return jnp.maximum(idle + (1.0 - idle) * shape, 0.0) * omega_max


def rotor_speed_after(theta, speed0, motor_cmds, config, mask=None) -> jax.Array:
    """The rotor speeds (4,) rad/s after the motor commands ``motor_cmds`` (W, 4) (normalised, one
    per control step, oldest first) starting from ``speed0`` (4,) rad/s, by θ's (19,) motor lag
    (τ_m, Ω_max) and ``config``'s motor map (:func:`commanded_speed`): the simulator's own
    integration, substep by substep, so with the true θ and the true start it reproduces the
    simulator's rotor speeds to float round-off. ``mask`` (W,) bool: steps to apply (others are
    skipped; None: all)."""
    theta = jnp.asarray(theta, jnp.float32)
    cmds = jnp.asarray(motor_cmds, jnp.float32)
    mask = jnp.ones(cmds.shape[0], bool) if mask is None else jnp.asarray(mask, bool)
    h = config.physics_dt

    def body(speed, inp):
        cmd, on = inp
        omega_cmd = commanded_speed(cmd, theta[P.OMEGA_MAX], config)
        new = speed
        for _ in range(config.substeps):
            _, new = mean_square_speed(new, omega_cmd, theta[P.TAU_M], h)
        return jnp.where(on, new, speed), None

    # unrolled: a few hundred tiny sequential steps would otherwise cost a kernel launch each
    speed, _ = jax.lax.scan(body, jnp.asarray(speed0, jnp.float32), (cmds, mask),
                            unroll=max(1, min(cmds.shape[0], 20)))
    return speed
