"""High-level controller: reference -> (a_cmd, ω_cmd), a cascaded position / velocity /
attitude controller with yaw, parameterised by a small gain vector (what CEM tunes).

Gain vector (8,), in this order (:data:`GAIN_NAMES`, bounds :data:`GAIN_BOUNDS`):

    kp_xy, kp_z   position gains (1/s²)          a += kp (p_ref − p)
    kv_xy, kv_z   velocity gains (1/s)           a += kv (v_ref − v)
    ki_xy, ki_z   integral gains (1/s³)          a += ki ∫(p_ref − p) dt   (|∫| ≤ 1 m·s)
    katt_xy, katt_z  attitude gains (1/s)        ω_cmd = −katt ∘ e_R + ω_ff

with a_des = kp e_p + kv e_v + ki ∫e_p + a_ref + g ẑ (horizontal part limited to a 60° tilt),
collective thrust a_cmd = a_des · z_body (clipped to [0, 4g]), desired attitude from a_des and the
reference yaw, e_R = ½ vee(R_dᵀR − RᵀR_d) (Lee et al. 2010), and the feed-forward body rates
ω_ff from the reference jerk and yaw rate (differential flatness, Mellinger & Kumar 2011).
Commanded rates are clipped to ±``max_rate``.
"""
from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxsysid.control.low_level import Command
from mjxsysid.control.references import RefPoint
from mjxsysid.sim.quadrotor import quat_to_mat
from mjxsysid.theta import GRAVITY

GAIN_NAMES = ("kp_xy", "kp_z", "kv_xy", "kv_z", "ki_xy", "ki_z", "katt_xy", "katt_z")
GAIN_BOUNDS = np.array([[0.5, 20.0], [0.5, 20.0], [0.5, 12.0], [0.5, 12.0],
                        [0.0, 5.0], [0.0, 5.0], [2.0, 20.0], [0.5, 8.0]], np.float32)
"""(8, 2) lower / upper bound of each gain; CEM searches inside this box."""

PRESETS = {
    # Uninformed defaults: a soft, critically-damped-ish loop anyone would start from.
    "naive": np.array([2.0, 2.0, 2.0, 2.0, 0.0, 0.0, 4.0, 1.0], np.float32),
    # Hand-tuned on the paper vehicle with K_θ(true θ): coordinate search over the lemniscate
    # (10 s) and random min-snap (5 s) references (benchmarks/tune_baseline.py, BENCHMARKS.md).
    "baseline": np.array([20.0, 20.0, 12.0, 12.0, 0.53, 0.94, 8.43, 2.83], np.float32),
}
INTEGRAL_LIMIT = 1.0  # m·s
MAX_TILT = np.deg2rad(60.0)


class Estimate(NamedTuple):
    """Vehicle state the high-level controller sees: pos (3) m, vel (3) m/s (world),
    quat (4) wxyz, omega (3) rad/s body."""
    pos: jax.Array
    vel: jax.Array
    quat: jax.Array
    omega: jax.Array


def gains(name_or_vector) -> jax.Array:
    """A preset name ('naive', 'baseline') or a gain vector (8,) -> validated (8,) array."""
    if isinstance(name_or_vector, str):
        if name_or_vector not in PRESETS:
            raise ValueError(f"unknown gain preset {name_or_vector!r}; choose from {sorted(PRESETS)}")
        return jnp.asarray(PRESETS[name_or_vector])
    g = np.asarray(name_or_vector, np.float32)
    if g.shape[-1:] != (len(GAIN_NAMES),):
        raise ValueError(f"gain vector must have shape (..., {len(GAIN_NAMES)}) ordered {GAIN_NAMES}; got {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ValueError("gain vector has non-finite entries")
    lo, hi = GAIN_BOUNDS[:, 0], GAIN_BOUNDS[:, 1]
    bad = np.argwhere((g < lo - 1e-6) | (g > hi + 1e-6))
    if bad.size:
        j = int(bad[0][-1])
        raise ValueError(f"gain {GAIN_NAMES[j]} = {g.reshape(-1, 8)[int(bad[0][0]) if g.ndim > 1 else 0, j]:.3g} "
                         f"outside its bounds [{lo[j]}, {hi[j]}]")
    return jnp.asarray(g)


def _vee(m):
    return jnp.stack([m[2, 1], m[0, 2], m[1, 0]])


def _unit(v, eps=1e-9):
    return v / jnp.maximum(jnp.linalg.norm(v), eps)


@struct.dataclass
class Cascade:
    """The cascaded controller. gains: (8,) (see module doc). max_rate: () rad/s."""
    gains: jax.Array
    max_rate: jax.Array = struct.field(default_factory=lambda: jnp.float32(12.0))

    @classmethod
    def make(cls, g="baseline", max_rate=12.0) -> "Cascade":
        return cls(gains(g), jnp.float32(max_rate))

    def init(self):
        """Carry: the position-error integral (3,)."""
        return jnp.zeros(3, jnp.float32)

    def step(self, integral, est: Estimate, ref: RefPoint, dt) -> tuple[jax.Array, Command]:
        g = self.gains
        kp = jnp.array([g[0], g[0], g[1]])
        kv = jnp.array([g[2], g[2], g[3]])
        ki = jnp.array([g[4], g[4], g[5]])
        katt = jnp.array([g[6], g[6], g[7]])
        e_p = ref.pos - est.pos
        integral = jnp.clip(integral + e_p * dt, -INTEGRAL_LIMIT, INTEGRAL_LIMIT)
        a_des = kp * e_p + kv * (ref.vel - est.vel) + ki * integral + ref.acc
        a_des = a_des + jnp.array([0.0, 0.0, GRAVITY])
        # Keep some upward thrust and limit the tilt to MAX_TILT.
        az = jnp.maximum(a_des[2], 0.2 * GRAVITY)
        h = a_des[:2]
        h_max = az * jnp.tan(MAX_TILT)
        h = h * jnp.minimum(1.0, h_max / jnp.maximum(jnp.linalg.norm(h), 1e-9))
        a_des = jnp.concatenate([h, az[None]])

        rot = quat_to_mat(est.quat)
        a_cmd = jnp.clip(jnp.dot(a_des, rot[:, 2]), 0.0, 4.0 * GRAVITY)
        z_d = _unit(a_des)
        x_c = jnp.array([jnp.cos(ref.yaw), jnp.sin(ref.yaw), 0.0])
        y_d = _unit(jnp.cross(z_d, x_c))
        x_d = jnp.cross(y_d, z_d)
        rot_d = jnp.stack([x_d, y_d, z_d], -1)
        e_r = 0.5 * _vee(rot_d.T @ rot - rot.T @ rot_d)
        # Feed-forward rates of the desired frame (differential flatness).
        hw = (ref.jerk - jnp.dot(z_d, ref.jerk) * z_d) / jnp.linalg.norm(a_des)
        w_ff_d = jnp.stack([-jnp.dot(hw, y_d), jnp.dot(hw, x_d), ref.yaw_rate * z_d[2]])
        omega_cmd = -katt * e_r + rot.T @ rot_d @ w_ff_d
        omega_cmd = jnp.clip(omega_cmd, -self.max_rate, self.max_rate)
        return integral, Command(a_cmd=a_cmd, omega_cmd=omega_cmd)
