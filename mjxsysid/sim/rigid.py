"""A light twin of :class:`~mjxsysid.sim.quadrotor.Quadrotor` for predictive rollouts.

The same equations (DESIGN §3) and the same integrator as the MJX simulator — MuJoCo's
semi-implicit Euler for a free body whose centre of mass is the body origin: accelerations from
the state at the start of the step, ``v ← v + h a``, ``p ← p + h v``, ``q ← q ⊗ exp(h ω / 2)``
(ω in the body frame), rotor speeds integrated exactly with the thrust of a step the exact mean
of η k_t Ω² over it — written directly in JAX without MuJoCo's generic machinery. It has no
IMU noise or bias (predictions are deterministic) and no contacts; the IMU latency is the
simulator's (a buffer of the true readings, carried over from the simulator's state). The tuner flies K × N
short rollouts per update with it; ``tests/sim/test_sim.py`` checks it against the MJX simulator.

``RigidSim`` implements what :func:`~mjxsysid.rollout.harness.fly_batch` needs of a simulator:
``config.dt``, ``init(θ, key, ...)``, ``step(θ, state, motor_cmd, force_world)`` and
``frame(state, motor_cmd, force)``, so it flies wherever the simulator does (``fly_vehicles(...,
sim=RigidSim())``: a noiseless flight that compiles in a fraction of the MJX program's time).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from mjxsysid import theta as P
from mjxsysid.sim.motors import commanded_speed, mean_square_speed
from mjxsysid.sim.quadrotor import (
    Frame,
    SimConfig,
    hover_rotor_speed,
    initial_imu,
    quat_to_mat,
)


@struct.dataclass
class RigidState:
    """pos (3) m world, quat (4) wxyz, vel (3) m/s world, omega (3) rad/s body, rotor_speed (4)
    rad/s, imu (6) [gyro, specific force] the controller sees (``imu_buffer[0]``; after
    :func:`from_sim_state`, the simulator's last output), imu_buffer (latency + 1, 6) true
    readings, oldest first, diverged () bool, step () int32."""
    pos: jax.Array
    quat: jax.Array
    vel: jax.Array
    omega: jax.Array
    rotor_speed: jax.Array
    imu: jax.Array
    imu_buffer: jax.Array
    diverged: jax.Array
    step: jax.Array


def from_sim_state(s, rotor_speed=None) -> RigidState:
    """The rigid-body state of an MJX :class:`~mjxsysid.sim.quadrotor.SimState` (optionally with
    other rotor speeds); the IMU reading carries over as the controller last saw it, and the
    latency buffer of true readings with it (the next outputs of a delayed IMU are already in it)."""
    return RigidState(s.pos, s.quat, s.vel, s.omega, s.rotor_speed if rotor_speed is None else rotor_speed,
                      s.imu, s.imu_buffer, jnp.array(False), s.step)


def _quat_mul(a, b):
    aw, ax, ay, az = a[0], a[1], a[2], a[3]
    bw, bx, by, bz = b[0], b[1], b[2], b[3]
    return jnp.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                      aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def _quat_integrate(q, omega, h):
    """MuJoCo's mju_quatIntegrate: q ⊗ [cos(|ω| h / 2), sin(|ω| h / 2) ω / |ω|], normalised."""
    n = jnp.linalg.norm(omega)
    half = 0.5 * n * h
    axis = omega / jnp.where(n > 0, n, 1.0)
    dq = jnp.concatenate([jnp.cos(half)[None], jnp.sin(half) * axis])
    q = _quat_mul(q, dq)
    return q / jnp.linalg.norm(q)


class RigidSim:
    """Deterministic rigid-body quadrotor for predictions (see the module doc). ``config``: a
    :class:`SimConfig` (dt, substeps, the motor map and the divergence limits are used; noise and
    ``aero`` are not)."""

    def __init__(self, config: SimConfig = SimConfig()):
        self.config = config

    def __hash__(self):
        return hash(("RigidSim", self.config))

    def __eq__(self, other):
        return isinstance(other, RigidSim) and other.config == self.config

    def imu_as_data(self) -> tuple[RigidSim, None]:
        """(this simulator, no IMU magnitudes): the twin draws no noise (:meth:`Quadrotor.imu_as_data
        <mjxsysid.sim.quadrotor.Quadrotor.imu_as_data>`)."""
        return self, None

    def init(self, theta, key=None, *, pos=(0.0, 0.0, 1.0), quat=(1.0, 0.0, 0.0, 0.0),
             vel=(0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0), rotor_speed=None, imu_std=None) -> RigidState:
        """Initial state of one vehicle, as :meth:`Quadrotor.init <mjxsysid.sim.quadrotor.Quadrotor.init>`
        makes it without IMU bias (``key`` and ``imu_std`` are accepted and unused: the twin draws no noise)."""
        theta = jnp.asarray(theta, jnp.float32)
        quat = jnp.asarray(quat, jnp.float32)
        omega = jnp.asarray(omega, jnp.float32)
        speed = hover_rotor_speed(theta) if rotor_speed is None else jnp.asarray(rotor_speed, jnp.float32)
        true0, buf = initial_imu(omega, self.config.imu_latency)
        return RigidState(jnp.asarray(pos, jnp.float32), quat / jnp.linalg.norm(quat), jnp.asarray(vel, jnp.float32),
                          omega, speed, true0, buf, jnp.array(False), jnp.array(0, jnp.int32))

    def step(self, theta, state: RigidState, motor_cmd, force_world=None) -> RigidState:
        """One control step; θ (19,), motor_cmd (4,) normalised, force_world (3,) N."""
        theta = jnp.asarray(theta, jnp.float32)
        c = self.config
        h = c.physics_dt
        f_world = jnp.zeros(3, jnp.float32) if force_world is None else jnp.asarray(force_world, jnp.float32)
        omega_cmd = commanded_speed(motor_cmd, theta[P.OMEGA_MAX], c)
        gain = theta[P.ETA] * theta[P.KT]
        rotors = P.rotor_positions(theta)                               # (4, 3) body
        kappa = theta[P.KTAU] / theta[P.KT]
        mass, inertia = theta[P.MASS], theta[P.INERTIA]

        def substep(carry, _):
            pos, quat, vel, omega, speed = carry
            msq, speed = mean_square_speed(speed, omega_cmd, theta[P.TAU_M], h)
            thrust = gain * msq                                         # (4,) N along body z
            rot = quat_to_mat(quat)
            v_body = rot.T @ vel
            f_body = jnp.array([0.0, 0.0, 1.0]) * thrust.sum() - theta[P.DRAG] * v_body
            acc = (rot @ f_body + f_world) / mass + jnp.array([0.0, 0.0, -P.GRAVITY])
            tau = (jnp.sum(jnp.cross(rotors, jnp.stack([jnp.zeros(4), jnp.zeros(4), thrust], -1)), 0)
                   + jnp.array([0.0, 0.0, 1.0]) * jnp.sum(jnp.asarray(P.YAW_SIGNS) * kappa * thrust)
                   + theta[P.TAU_EXT])
            wdot = (tau - jnp.cross(omega, inertia * omega)) / inertia
            vel = vel + h * acc
            omega = omega + h * wdot
            return (pos + h * vel, _quat_integrate(quat, omega, h), vel, omega, speed), None

        carry = (state.pos, state.quat, state.vel, state.omega, state.rotor_speed)
        if c.substeps == 1:
            carry, _ = substep(carry, None)
        else:
            carry, _ = jax.lax.scan(substep, carry, None, length=c.substeps)
        pos, quat, vel, omega, speed = carry
        rot = quat_to_mat(quat)
        thrust = jnp.sum(gain * speed**2)
        sf = (jnp.array([0.0, 0.0, 1.0]) * thrust - theta[P.DRAG] * (rot.T @ vel) + rot.T @ f_world) / mass
        buf = jnp.concatenate([state.imu_buffer[1:], jnp.concatenate([omega, sf])[None]], 0)
        new = RigidState(pos, quat, vel, omega, speed, buf[0], buf, state.diverged, state.step + 1)
        finite = jnp.all(jnp.isfinite(jnp.concatenate([pos, quat, vel, omega, speed])))
        inside = ((jnp.max(jnp.abs(pos)) < c.pos_limit) & (jnp.linalg.norm(vel) < c.vel_limit)
                  & (jnp.linalg.norm(omega) < c.rate_limit))
        bad = state.diverged | ~(finite & inside)
        out = jax.tree.map(lambda a, b: jnp.where(bad, a, b), state, new)
        return out.replace(diverged=bad, step=state.step + 1)

    def frame(self, state: RigidState, motor_cmd, force_world) -> Frame:
        return Frame(pos=state.pos, quat=state.quat, vel=state.vel, omega=state.omega,
                     rotor_speed=state.rotor_speed, imu=state.imu,
                     motor_cmd=jnp.clip(motor_cmd, 0.0, 1.0), force=force_world, diverged=state.diverged)
