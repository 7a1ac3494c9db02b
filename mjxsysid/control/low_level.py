"""Low-level controllers: (IMU, command) -> normalised motor speeds.

The parametric controller K_θ (paper appendix) and the interface every low-level controller
(K_θ here, the neural policies elsewhere) implements, so that any low-level controller sits under any
high-level controller:

    carry = ctrl.init(key)                                   # per-episode memory
    carry, motor_cmd = ctrl.step(carry, imu, command)        # imu (6,), motor_cmd (4,)

A controller is a pytree (``flax.struct.dataclass``): its numeric parameters are leaves, so a
batch of controllers (one per vehicle, e.g. K_θ with each vehicle's own θ) is vmapped like any
other argument and never re-traces.
"""
from __future__ import annotations

from typing import NamedTuple, Protocol

import jax
import jax.numpy as jnp
from flax import struct

from mjxsysid import theta as P
from mjxsysid.sim.quadrotor import hover_rotor_speed


class Command(NamedTuple):
    """High-level command to a low-level controller.

    a_cmd: () mass-normalised collective thrust, m/s² (≈ g at hover).
    omega_cmd: (3,) body rates, rad/s (body frame FLU).
    """
    a_cmd: jax.Array
    omega_cmd: jax.Array


class LowLevel(Protocol):
    def init(self, key: jax.Array): ...

    def step(self, carry, imu: jax.Array, command: Command) -> tuple[object, jax.Array]: ...


def allocation_matrix(theta) -> jax.Array:
    """B_alloc(θ) (4, 4): [T; τ_x; τ_y; τ_z] = B f, f the per-rotor thrusts (N).

    Columns are rotors 1..4 (front-right, front-left, back-left, back-right) at (x_i, y_i):
    rows 1, y_i, −x_i, s_i κ with s_i the yaw reaction sign and κ = k_τ / k_t.
    θ (..., 19) -> (..., 4, 4).
    """
    theta = jnp.asarray(theta)
    r = P.rotor_positions(theta)  # (..., 4, 3)
    kappa = P.torque_ratio(theta)[..., None]
    ones = jnp.ones_like(r[..., 0])
    return jnp.stack([ones, r[..., 1], -r[..., 0], jnp.asarray(P.YAW_SIGNS) * kappa], -2)


def allocate(theta, collective_thrust, torque) -> jax.Array:
    """Squared rotor speeds Ω²_cmd (4,) = (1/k_t) diag(1/η) B⁻¹ [T; τ] (paper eq. app-alloc).

    theta (19,); collective_thrust () N; torque (3,) N·m."""
    wrench = jnp.concatenate([jnp.reshape(collective_thrust, (1,)), torque])
    f = jnp.linalg.solve(allocation_matrix(theta), wrench)
    return f / (theta[P.KT] * theta[P.ETA])


DEFAULT_RATE_GAINS = (40.0, 40.0, 16.0)
"""K_ω (1/s), shared across platforms: rate-loop bandwidth below the motor bandwidth 1/τ_m."""


@struct.dataclass
class KTheta:
    """The parametric controller K_θ (paper appendix).

    τ_cmd = J K_ω (ω_cmd − ω);  Ω²_cmd = (1/k_t) diag(1/η) B_alloc(θ)⁻¹ [m a_cmd; τ_cmd];
    Ω_norm = clip(√Ω²_cmd / Ω_max, 0, 1).  ω is the measured (gyro) body rate.

    theta: (19,) the vehicle the controller *believes* it flies. rate_gains: (3,) K_ω diagonal.
    """
    theta: jax.Array
    rate_gains: jax.Array

    @classmethod
    def make(cls, theta, rate_gains=DEFAULT_RATE_GAINS) -> "KTheta":
        """θ (..., 19) -> a controller (batched if θ is); K_ω broadcast to (..., 3)."""
        theta = jnp.asarray(theta, jnp.float32)
        gains = jnp.broadcast_to(jnp.asarray(rate_gains, jnp.float32), theta.shape[:-1] + (3,))
        return cls(theta, gains)

    def init(self, key=None):
        return ()

    def motor_command(self, command: Command, omega: jax.Array) -> jax.Array:
        """(command, measured body rate (3,)) -> Ω_norm (4,) in [0, 1]."""
        th = self.theta
        tau = th[P.INERTIA] * self.rate_gains * (command.omega_cmd - omega)
        sq = allocate(th, th[P.MASS] * command.a_cmd, tau)
        return jnp.clip(jnp.sqrt(jnp.maximum(sq, 0.0)) / th[P.OMEGA_MAX], 0.0, 1.0)

    def step(self, carry, imu, command: Command):
        return carry, self.motor_command(command, imu[0:3])


THRUST_CUT_MAX = 0.2
"""The most of the collective thrust :func:`_yaw_last` gives up for roll/pitch torque."""


def _yaw_last(theta, collective_thrust, torque, sq_max, thrust_cut: bool = True) -> jax.Array:
    """Squared rotor speeds (4,) like :func:`allocate`, but with the yaw torque scaled down by the
    least factor s ∈ [0, 1] that keeps every rotor inside [0, ``sq_max``] (where the thrust and
    roll/pitch torque alone fit; the allocation is linear in τ_z, so s is exact), then, where a
    rotor is still above ``sq_max``, the collective thrust lowered until it is not: roll and pitch
    first, then thrust, then heading."""
    # Ω² is linear in the wrench: one solve gives the columns (per unit thrust, τ_x, τ_y, τ_z)
    cols = jnp.linalg.solve(allocation_matrix(theta), jnp.eye(4, dtype=jnp.float32)) / (theta[P.KT] * theta[P.ETA])[:, None]
    base = cols[:, :3] @ jnp.concatenate([jnp.reshape(collective_thrust, (1,)), torque[:2]])
    d = cols[:, 3] * torque[2]
    big = jnp.float32(1e30)
    up = jnp.where(d > 0, (sq_max - base) / jnp.where(d > 0, d, 1.0), big)
    down = jnp.where(d < 0, -base / jnp.where(d < 0, d, -1.0), big)
    s = jnp.clip(jnp.min(jnp.minimum(up, down)), 0.0, 1.0)
    sq = base + s * d
    if not thrust_cut:
        return sq
    # still above Ω_max²: lower the collective thrust (every rotor by its share) until the roll /
    # pitch torque fits — attitude before altitude, as flight controllers' mixers do
    per_unit = cols[:, 0]                                                        # (4,) > 0
    over = jnp.max((sq - sq_max) / per_unit)
    cut = jnp.clip(over, 0.0, THRUST_CUT_MAX * jnp.maximum(collective_thrust, 0.0))
    return sq - cut * per_unit


LAG_TARGET_TAU = 0.02
"""Motor time constant (s) :class:`KThetaLag` makes every motor look like (the fast end of the
default prior, τ_m ∈ [0.02, 0.04] s, where K_ω's rate gains were chosen); motors already faster
are left alone."""


@struct.dataclass
class KThetaLag:
    """K_θ that also uses θ's motor lag (τ_m): the lag-aware oracle.

    K_θ asks for rotor speeds Ω_d (paper appendix) as if the motors followed at once; with a
    first-order lag τ_m ≫ 1/K_ω its rate loop goes unstable. This controller keeps the rotor
    speeds it expects, Ω̂ (its carry: θ's own lag run over the commands it sent, exact for the
    simulator's motors, starting in hover), and commands the speed that moves them in one
    control step as a motor of time constant τ_d = min(τ_m, ``target_tau``) would:

        a = e^{−dt/τ_m}, a_d = e^{−dt/τ_d};  Ω_cmd = Ω̂ + (Ω_d − Ω̂)(1 − a_d)/(1 − a),
        clipped to [0, Ω_max];  Ω̂ ← Ω_cmd + (Ω̂ − Ω_cmd) a.

    Unsaturated, the motors then follow Ω_d with lag τ_d; with τ_m ≤ τ_d and τ_ext = 0 it is K_θ
    exactly. It also uses the rest of θ K_θ leaves out: the known external torque τ_ext is
    cancelled in the torque asked of the rotors.
    K_θ itself stays the action-replay probe (the paper's definition); this one is the oracle
    wherever an oracle is the yardstick. theta (19,), rate_gains (3,), dt () s (the control
    period), target_tau () s.
    """
    theta: jax.Array
    rate_gains: jax.Array
    dt: jax.Array
    target_tau: jax.Array
    yaw_last: bool = struct.field(pytree_node=False, default=True)
    cancel_torque: bool = struct.field(pytree_node=False, default=True)
    thrust_cut: bool = struct.field(pytree_node=False, default=True)

    @classmethod
    def make(cls, theta, rate_gains=DEFAULT_RATE_GAINS, dt=0.002, target_tau=LAG_TARGET_TAU,
             yaw_last=True, cancel_torque=True, thrust_cut=True) -> "KThetaLag":
        """θ (..., 19) -> a controller (batched if θ is). ``yaw_last``: where the allocation
        asks a rotor for more than Ω_max (or less than 0), give up yaw torque first
        (:func:`_yaw_last`). ``cancel_torque``: subtract θ's constant external torque τ_ext
        from the torque asked of the rotors (K_θ leaves it to the rate loop's error).
        ``thrust_cut`` (with ``yaw_last``): where a rotor still saturates, lower the collective
        thrust before losing roll/pitch torque."""
        theta = jnp.asarray(theta, jnp.float32)
        shape = theta.shape[:-1]
        gains = jnp.broadcast_to(jnp.asarray(rate_gains, jnp.float32), shape + (3,))
        return cls(theta, gains, jnp.broadcast_to(jnp.float32(dt), shape),
                   jnp.broadcast_to(jnp.float32(target_tau), shape), yaw_last, cancel_torque, thrust_cut)

    def init(self, key=None):
        """Carry: the expected rotor speeds Ω̂ (4,) rad/s, the hover speeds of θ."""
        return hover_rotor_speed(self.theta)

    def step(self, carry, imu, command: Command):
        th = self.theta
        tau = th[P.INERTIA] * self.rate_gains * (command.omega_cmd - imu[0:3])
        if self.cancel_torque:   # θ knows the external torque: the rotors supply the rest
            tau = tau - th[P.TAU_EXT]
        w_max = th[P.OMEGA_MAX]
        sq = _yaw_last(th, th[P.MASS] * command.a_cmd, tau, w_max**2, self.thrust_cut) if self.yaw_last else \
            allocate(th, th[P.MASS] * command.a_cmd, tau)
        desired = jnp.clip(jnp.sqrt(jnp.maximum(sq, 0.0)), 0.0, w_max)
        a = jnp.exp(-self.dt / th[P.TAU_M])
        a_d = jnp.exp(-self.dt / jnp.minimum(th[P.TAU_M], self.target_tau))
        cmd = jnp.clip(carry + (desired - carry) * (1.0 - a_d) / (1.0 - a), 0.0, w_max)
        return cmd + (carry - cmd) * a, cmd / w_max
