"""Batched MJX quadrotor whose physics is rewritten per vehicle from θ.

Everything here is *unbatched* and pure: one vehicle θ (19,), one state. Batching is one
``jax.vmap`` at the caller (see :mod:`mjxsysid.sim.rollout`). θ is an argument of every function,
never captured, so a new batch of vehicles re-uses the compiled code.

What MuJoCo integrates: the free rigid body (mass, inertia, gravity, gyroscopic terms), the four
thrust actuators at the rotor sites (their gear carries the yaw-torque ratio κ = k_τ / k_t),
and the external wrench in ``xfrc_applied``. What is computed in JAX around ``mjx.step``: rotor
first-order speed dynamics towards the commanded speed (integrated exactly), quadratic thrust η_i k_t Ω_i², body-frame linear
drag −D v_body, the constant body-frame torque τ_ext, the world-frame disturbance force, the IMU
(noise, bias, latency) and divergence detection.
"""
from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from flax import struct

from mjxsysid import theta as P
from mjxsysid.runtime.quiet import import_mjx
from mjxsysid.sim.motors import commanded_speed, mean_square_speed

mjx = import_mjx()  # without MJX's "Failed to import warp" probe message

ASSET = Path(__file__).resolve().parent.parent / "assets" / "quadrotor.xml"
AERO_PARASITIC = (0.01, 0.01, 0.02)
"""1/m: parasitic drag per mass along body x, y, z with ``SimConfig.aero`` (RotorPy's Hummingbird:
c_D 0.005, 0.005, 0.01 N/(m/s)² on 0.5 kg)."""
AERO_LIFT = 0.0028
"""Per (m/s)²: translational lift as a share of the weight with ``SimConfig.aero`` (the Hummingbird's
k_h 3.39e-3 N/(m/s)² on each of four rotors, over its 4.9 N)."""
BODY = 1  # body id of the quadrotor in assets/quadrotor.xml (0 is the world)


@dataclasses.dataclass(frozen=True)
class SimConfig:
    """Simulator settings (static: changing them re-traces).

    dt: control period (s); 500 Hz by default. substeps: physics steps per control step.
    contacts: keep MuJoCo contacts (off for flight). gyro_noise / accel_noise: white-noise std
    per control step (rad/s, m/s²). gyro_bias / accel_bias: std of a constant bias drawn at reset.
    imu_latency: IMU delay in control steps. gyro_vibration / accel_vibration: std (rad/s, m/s²)
    of narrow-band noise at the rotor frequency, as rotor vibration adds to a real IMU
    (:func:`vibration_step`); its centre ``vibration_hz`` (0: the mean rotor speed / 2π, aliased
    into the 0 – 1/(2 dt) band the IMU samples) and ``vibration_bandwidth_hz``. Off (0) by
    default; the other settings' noise is the same with it off. pos_limit (m), vel_limit (m/s),
    rate_limit (rad/s): a vehicle beyond any of these, or with a non-finite state, is flagged
    ``diverged`` and frozen. aero: rotor aerodynamics beyond the linear body drag, in RotorPy's form
    with its Hummingbird's coefficients scaled to the vehicle (:meth:`Quadrotor.aero_force`): the drag
    grows with the rotor speed (rotor drag and induced inflow), a parasitic drag quadratic in the
    airspeed, and translational lift; off by default (the physics θ describes). motor_idle, motor_kappa:
    another static motor map, the steady-state rotor speed of a command u being
    Ω_max (idle + (1 − idle) s(u)) (:func:`~mjxsysid.sim.motors.commanded_speed`): an idle offset (a share of Ω_max; negative: a
    dead band) and a curvature κ ∈ [0, 2]: s = √(κ u² + (1 − κ) u) up to κ 1 (0: √u, 1: linear), beyond it
    s = u √(2 − κ + (κ − 1) u²) (2: u², the speed of an ESC linear in its command read through a thrust model
    linear in it, PX4's THR_MDL_FAC 0); off (0 and 1) by default (the map θ describes, Ω_max u). randomize_imu: the noise, bias and vibration settings are maxima, each
    flight drawing its levels uniform in [0, 1] × them; imu_clean_fraction: with it, that share of
    flights has a clean IMU (both levels 0).
    """
    dt: float = 0.002
    substeps: int = 1
    contacts: bool = False
    gyro_noise: float = 0.0
    accel_noise: float = 0.0
    gyro_bias: float = 0.0
    accel_bias: float = 0.0
    imu_latency: int = 0
    gyro_vibration: float = 0.0
    accel_vibration: float = 0.0
    vibration_hz: float = 0.0
    vibration_bandwidth_hz: float = 20.0
    randomize_imu: bool = False
    imu_clean_fraction: float = 0.0
    pos_limit: float = 1.0e3
    vel_limit: float = 100.0
    rate_limit: float = 200.0
    aero: bool = False
    motor_idle: float = 0.0
    motor_kappa: float = 1.0

    def __post_init__(self):
        if not self.dt > 0:
            raise ValueError(f"SimConfig.dt must be > 0, got {self.dt}")
        if int(self.substeps) != self.substeps or self.substeps < 1:
            raise ValueError(f"SimConfig.substeps must be an integer >= 1, got {self.substeps}")
        if int(self.imu_latency) != self.imu_latency or self.imu_latency < 0:
            raise ValueError(f"SimConfig.imu_latency must be an integer >= 0, got {self.imu_latency}")
        for f in ("gyro_noise", "accel_noise", "gyro_bias", "accel_bias", "gyro_vibration",
                  "accel_vibration", "vibration_hz"):
            if not getattr(self, f) >= 0:
                raise ValueError(f"SimConfig.{f} must be >= 0, got {getattr(self, f)}")
        if not 0.0 <= self.imu_clean_fraction <= 1.0:
            raise ValueError(f"SimConfig.imu_clean_fraction must be in [0, 1], got {self.imu_clean_fraction}")
        if self.imu_clean_fraction > 0 and not self.randomize_imu:
            raise ValueError("SimConfig.imu_clean_fraction needs randomize_imu (it is a share of the per-flight draws)")
        if not -1.0 < self.motor_idle < 1.0:
            raise ValueError(f"SimConfig.motor_idle must be in (-1, 1) (a share of Ω_max), got {self.motor_idle}")
        if not 0.0 <= self.motor_kappa <= 2.0:
            raise ValueError(f"SimConfig.motor_kappa must be in [0, 2], got {self.motor_kappa}")
        if not 0 < self.vibration_bandwidth_hz < 0.5 / self.dt:
            raise ValueError(f"SimConfig.vibration_bandwidth_hz must be in (0, {0.5 / self.dt:g}) Hz "
                             f"(the IMU's Nyquist band), got {self.vibration_bandwidth_hz}")

    @property
    def vibration(self) -> bool:
        """Whether the IMU carries rotor vibration (decided at trace time)."""
        return self.gyro_vibration > 0 or self.accel_vibration > 0

    @property
    def motor_map(self) -> bool:
        """Whether the static motor map differs from Ω_max u (decided at trace time)."""
        return self.motor_idle != 0.0 or self.motor_kappa != 1.0

    @property
    def physics_dt(self) -> float:
        return self.dt / self.substeps


@struct.dataclass
class SimState:
    """State of one vehicle (add a leading batch axis under vmap).

    data: MJX data (qpos (7) = world position + quaternion wxyz, qvel (6) = world linear velocity
      + body angular velocity). rotor_speed: (4,) rad/s. imu: (6,) latest IMU output
      [gyro (3) rad/s, specific force (3) m/s²], body frame, with noise / bias / latency.
    imu_buffer: (imu_latency + 1, 6) true readings, oldest first. imu_bias: (6,).
    imu_vibration: (2, 6) the vibration filter's last two outputs (unit std; zeros when off).
    imu_std: (3, 6) this episode's IMU magnitudes per channel: the white noise's std, the bias's std
    and the vibration's amplitude (the config's, times ``randomize_imu``'s draw; :meth:`Quadrotor.imu_std`).
    key: PRNG key for IMU noise. diverged: () bool. step: () int32 control steps taken.
    """
    data: mjx.Data
    rotor_speed: jax.Array
    imu: jax.Array
    imu_buffer: jax.Array
    imu_bias: jax.Array
    imu_vibration: jax.Array
    imu_std: jax.Array
    key: jax.Array
    diverged: jax.Array
    step: jax.Array

    @property
    def pos(self):
        return self.data.qpos[..., 0:3]

    @property
    def quat(self):
        return self.data.qpos[..., 3:7]

    @property
    def vel(self):
        return self.data.qvel[..., 0:3]

    @property
    def omega(self):
        return self.data.qvel[..., 3:6]

    @property
    def time(self):
        return self.data.time


class Frame(NamedTuple):
    """One recorded control step (stacked over time by rollouts: leaves (T, ...)).

    pos (3) m world; quat (4) wxyz; vel (3) m/s world; omega (3) rad/s body; rotor_speed (4);
    imu (6) [gyro, specific force] as output; motor_cmd (4) normalised command applied;
    force (3) N world disturbance applied; diverged () bool.
    """
    pos: jax.Array
    quat: jax.Array
    vel: jax.Array
    omega: jax.Array
    rotor_speed: jax.Array
    imu: jax.Array
    motor_cmd: jax.Array
    force: jax.Array
    diverged: jax.Array


def quat_to_mat(q: jax.Array) -> jax.Array:
    """Unit quaternion wxyz (..., 4) -> rotation matrix body→world (..., 3, 3)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return jnp.stack([
        jnp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        jnp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        jnp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def initial_imu(omega, latency: int) -> tuple[jax.Array, jax.Array]:
    """A vehicle's first true IMU reading (6,) — the given body rates (3,) and the hover specific
    force, +g along body z — and the latency buffer (latency + 1, 6) filled with it."""
    true0 = jnp.concatenate([jnp.asarray(omega, jnp.float32), jnp.array([0.0, 0.0, P.GRAVITY], jnp.float32)])
    return true0, jnp.tile(true0, (latency + 1, 1))


def hover_rotor_speed(theta) -> jax.Array:
    """Rotor speeds that hold the vehicle at rest, η_i k_t Ω_i² = m g / 4. θ (..., 19) -> (..., 4)."""
    theta = jnp.asarray(theta)
    w = theta[..., P.MASS] * P.GRAVITY / 4.0
    return jnp.sqrt(w[..., None] / (theta[..., P.ETA] * theta[..., P.KT, None]))


def aliased_hz(freq_hz, dt: float):
    """The frequency (Hz) at which a tone of ``freq_hz`` appears when sampled every ``dt`` s:
    folded into [0, 1/(2 dt)] (a 400 Hz rotor sampled at 500 Hz reads as 100 Hz)."""
    fs = 1.0 / dt
    return jnp.abs(jnp.mod(jnp.asarray(freq_hz, jnp.float32) + fs / 2, fs) - fs / 2)


def vibration_step(prev, noise, freq_hz, bandwidth_hz: float, dt: float):
    """One sample of unit-variance narrow-band noise: a two-pole resonator driven by white noise.

    x_k = φ₁ x_{k−1} + φ₂ x_{k−2} + g e_k with φ₁ = 2 r cos(2π f dt), φ₂ = −r², r = exp(−π B dt)
    (poles at the centre f, half-power bandwidth ≈ B), and g the gain that makes the stationary
    variance 1: var(x) / g² = (1 − φ₂) / ((1 + φ₂)((1 − φ₂)² − φ₁²)). prev (2, ...) the last two
    outputs (oldest first), noise (...) standard normal, freq_hz scalar or (...) in [0, 1/(2 dt)].
    Returns the new (2, ...) with the new output last."""
    r = jnp.exp(-jnp.pi * bandwidth_hz * dt)
    phi1 = 2.0 * r * jnp.cos(2.0 * jnp.pi * jnp.asarray(freq_hz, jnp.float32) * dt)
    phi2 = -r * r
    var = (1.0 - phi2) / ((1.0 + phi2) * ((1.0 - phi2) ** 2 - phi1 ** 2))
    x = phi1 * prev[1] + phi2 * prev[0] + noise / jnp.sqrt(var)
    return jnp.stack([prev[1], x])


def _physics_only(mj: mujoco.MjModel, xml_path) -> mujoco.MjModel:
    """``mj`` without its geoms, cameras and lights: what MJX steps when nothing collides. The body's
    inertia is explicit (``<inertial>``), so the dynamics are the same to the bit; MJX does not
    place nine geoms, three cameras and a light at every step (one step's program is 14 % smaller
    and compiles in 15 % less time than with them: BENCHMARKS.md, "CPU compile settings"). :attr:`Quadrotor.mj_model` keeps them for rendering."""
    spec = mujoco.MjSpec.from_file(str(xml_path))
    for kind in ("geoms", "cameras", "lights"):
        for element in list(getattr(spec, kind)):
            spec.delete(element)
    out = spec.compile()
    out.opt.timestep, out.opt.disableflags = mj.opt.timestep, mj.opt.disableflags
    if (out.nbody, out.njnt, out.nsite, out.nu) != (mj.nbody, mj.njnt, mj.nsite, mj.nu):
        raise ValueError(f"{xml_path}: stripping geoms, cameras and lights changed the bodies, joints, sites or actuators")
    return out


class Quadrotor:
    """The MJX quadrotor simulator.

    >>> sim = Quadrotor()
    >>> theta = mjxsysid.theta.paper_hardware()
    >>> s = sim.init(theta, jax.random.PRNGKey(0))
    >>> s = sim.step(theta, s, jnp.full(4, 0.5))

    ``init``, ``step`` and ``model`` are pure and unbatched; vmap them (or use
    :func:`mjxsysid.sim.rollout.rollout_batch`).
    """

    def __init__(self, config: SimConfig = SimConfig(), xml_path: str | Path = ASSET):
        self.config = config
        self.xml_path = Path(xml_path).resolve()
        self._key = (config, str(self.xml_path))
        mj = mujoco.MjModel.from_xml_path(str(xml_path))
        mj.opt.timestep = config.physics_dt
        if config.contacts:
            mj.opt.disableflags &= ~int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        else:
            mj.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
        # The IMU is computed in JAX (below); skip MuJoCo's sensor stage in MJX.
        mj.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        self.mj_model = mj
        # This process's first device (MJX's default, jax.devices()[0], belongs to process 0 in a
        # multi-process run, and the model is a constant of every jitted step).
        self.base = mjx.put_model(_physics_only(mj, xml_path) if not config.contacts else mj, impl="jax",
                                  device=jax.local_devices()[0])
        self._site_ids = np.array([mujoco.mj_name2id(mj, mujoco.mjtObj.mjOBJ_SITE, f"rotor{i}")
                                   for i in range(1, 5)])
        self._gravity = jnp.asarray(mj.opt.gravity, jnp.float32)
        if abs(float(mj.opt.gravity[2]) + P.GRAVITY) > 1e-6:
            raise ValueError(f"{xml_path}: gravity must be (0, 0, -{P.GRAVITY})")

    # Two simulators of the same config and model file are the same simulator: the compiled
    # flights cached per simulator (rollout_batch, harness.fly_batch) are shared between them.
    def __eq__(self, other):
        return type(other) is type(self) and other._key == self._key

    def __hash__(self):
        return hash(self._key)

    # ------------------------------------------------------------------ model
    def model(self, theta: jax.Array) -> mjx.Model:
        """θ (19,) -> MJX model with this vehicle's mass, inertia, rotor sites and gear. Pure."""
        theta = jnp.asarray(theta, jnp.float32)
        m = self.base
        mass = m.body_mass.at[BODY].set(theta[P.MASS])
        inertia = m.body_inertia.at[BODY].set(theta[P.INERTIA])
        site_pos = m.site_pos.at[self._site_ids].set(P.rotor_positions(theta))
        kappa = theta[P.KTAU] / theta[P.KT]
        gear = m.actuator_gear.at[:, 5].set(jnp.asarray(P.YAW_SIGNS) * kappa)
        subtree = m.body_subtreemass.at[:].set(theta[P.MASS])
        return m.replace(body_mass=mass, body_inertia=inertia, site_pos=site_pos,
                         actuator_gear=gear, body_subtreemass=subtree)

    # ------------------------------------------------------------------- IMU
    def imu_std(self) -> np.ndarray:
        """The config's IMU magnitudes (3, 6) float32, per channel [gyro (3) rad/s, accelerometer (3) m/s²]:
        the white noise's std, the bias's std and the vibration's amplitude (randomize_imu's maxima)."""
        c = self.config
        return np.array([[c.gyro_noise] * 3 + [c.accel_noise] * 3, [c.gyro_bias] * 3 + [c.accel_bias] * 3,
                         [c.gyro_vibration] * 3 + [c.accel_vibration] * 3], np.float32)

    def imu_as_data(self) -> tuple[Quadrotor, np.ndarray]:
        """(this simulator with the IMU's magnitudes left to :meth:`init`'s ``imu_std``, those magnitudes (3, 6)).
        Flights of every noise level of one structure (rotor vibration on or off) then share one compiled
        program, and fly as this simulator flies: the same noise to the bit (:func:`~mjxsysid.rollout.harness.fly_batch`)."""
        return _imu_free(self), self.imu_std()

    # ------------------------------------------------------------------- init
    def init(self, theta, key, *, pos=(0.0, 0.0, 1.0), quat=(1.0, 0.0, 0.0, 0.0),
             vel=(0.0, 0.0, 0.0), omega=(0.0, 0.0, 0.0), rotor_speed=None, imu_std=None) -> SimState:
        """Initial state of one vehicle: θ (19,), key; pos (3) m, quat (4) wxyz, vel (3) m/s world,
        omega (3) rad/s body, rotor_speed (4) rad/s (default: the hover speeds); imu_std (3, 6) the IMU's
        magnitudes (default the config's, :meth:`imu_std`; data, so that one program serves every level)."""
        theta = jnp.asarray(theta, jnp.float32)
        c = self.config
        k_bias, k_noise = jax.random.split(key)
        quat = jnp.asarray(quat, jnp.float32)
        quat = quat / jnp.linalg.norm(quat)
        data = mjx.make_data(self.base)
        data = data.replace(qpos=jnp.concatenate([jnp.asarray(pos, jnp.float32), quat]),
                            qvel=jnp.concatenate([jnp.asarray(vel, jnp.float32),
                                                  jnp.asarray(omega, jnp.float32)]))
        speed = hover_rotor_speed(theta) if rotor_speed is None else jnp.asarray(rotor_speed, jnp.float32)
        level = jnp.ones(2, jnp.float32)
        if c.randomize_imu:  # a Python branch: without it the key stream is unchanged
            k_bias, k_level = jax.random.split(k_bias)
            level = jax.random.uniform(k_level, (2,), jnp.float32)
            if c.imu_clean_fraction > 0:   # that share of flights has a clean IMU (levels 0)
                k_level, k_clean = jax.random.split(k_level)
                level = jnp.where(jax.random.uniform(k_clean) < c.imu_clean_fraction, 0.0, level)
        std = jnp.asarray(self.imu_std() if imu_std is None else imu_std, jnp.float32)
        std = jnp.stack([level[0] * std[0], level[1] * std[1], level[0] * std[2]])
        bias = std[1] * jax.random.normal(k_bias, (6,))
        true0, buf = initial_imu(omega, c.imu_latency)
        return SimState(data=data, rotor_speed=speed, imu=true0 + bias, imu_buffer=buf,
                        imu_bias=bias, imu_vibration=jnp.zeros((2, 6), jnp.float32), imu_std=std,
                        key=k_noise, diverged=jnp.array(False),
                        step=jnp.array(0, jnp.int32))

    # ------------------------------------------------------------------- step
    def aero_force(self, theta, v_body, rotor_speed) -> jax.Array:
        """The body-frame force (3,) N of the air on the vehicle at body velocity ``v_body`` (3,) m/s:
        the linear drag −D v; with ``config.aero``, RotorPy's aerodynamics instead, scaled to the vehicle:
        −D v · Ω̄ / Ω_hover (rotor drag and induced inflow grow with the mean rotor speed Ω̄; D is their
        value at hover), − m c |v| v with c = :data:`AERO_PARASITIC` (parasitic drag), and the
        translational lift + m g · :data:`AERO_LIFT` · (v_x² + v_y²) along body z."""
        drag = -theta[P.DRAG] * v_body
        if not self.config.aero:
            return drag
        m = theta[P.MASS]
        hover = jnp.sqrt(m * P.GRAVITY / (4.0 * jnp.mean(theta[P.ETA]) * theta[P.KT]))
        speed = jnp.sqrt(jnp.sum(v_body * v_body) + 1e-12)
        lift = m * P.GRAVITY * AERO_LIFT * (v_body[0] ** 2 + v_body[1] ** 2)
        return (drag * jnp.mean(rotor_speed) / hover - m * jnp.asarray(AERO_PARASITIC) * speed * v_body
                + jnp.array([0.0, 0.0, 1.0]) * lift)

    def external_wrench(self, theta, data: mjx.Data, force_world, rotor_speed=None) -> jax.Array:
        """xfrc_applied row (6,) of the quadrotor body: the air's force R :meth:`aero_force` + force_world,
        and torque R τ_ext (world frame, applied at the centre of mass)."""
        rot = quat_to_mat(data.qpos[3:7])
        v_body = rot.T @ data.qvel[0:3]
        speed = jnp.zeros(4) if rotor_speed is None else rotor_speed
        return jnp.concatenate([rot @ self.aero_force(theta, v_body, speed) + force_world, rot @ theta[P.TAU_EXT]])

    def specific_force(self, theta, data: mjx.Data, rotor_speed, force_world) -> jax.Array:
        """What an ideal accelerometer at the centre of mass reads, body frame (3,) m/s²:
        (thrust + the air's force + disturbance) / m, at the state in ``data`` (no contacts)."""
        rot = quat_to_mat(data.qpos[3:7])
        thrust = jnp.sum(theta[P.ETA] * theta[P.KT] * rotor_speed**2)
        air = self.aero_force(theta, rot.T @ data.qvel[0:3], rotor_speed)
        return (air + rot.T @ force_world + jnp.array([0.0, 0.0, 1.0]) * thrust) / theta[P.MASS]

    def step(self, theta, state: SimState, motor_cmd, force_world=None) -> SimState:
        """Advance one control step (dt). θ (19,); motor_cmd (4,) normalised rotor-speed commands
        Ω_cmd/Ω_max (clipped to [0, 1]); force_world (3,) N disturbance held over the step.

        A jitted function of its own: every program that flies this simulator (flights, training,
        tuning, each under vmap and scan) reuses one trace of MJX's step per signature instead of
        tracing it again (tracing MJX's Python is a large share of a first flight's compile)."""
        return _step_jit(self, theta, state, motor_cmd, force_world)

    def _step(self, theta, state: SimState, motor_cmd, force_world=None) -> SimState:
        theta = jnp.asarray(theta, jnp.float32)
        c = self.config
        h = c.physics_dt
        model = self.model(theta)
        force_world = jnp.zeros(3, jnp.float32) if force_world is None else jnp.asarray(force_world, jnp.float32)
        omega_cmd = commanded_speed(motor_cmd, theta[P.OMEGA_MAX], c)
        gain = theta[P.ETA] * theta[P.KT]

        def substep(carry, _):
            data, speed = carry
            msq, speed = mean_square_speed(speed, omega_cmd, theta[P.TAU_M], h)
            xfrc = data.xfrc_applied.at[BODY].set(self.external_wrench(theta, data, force_world, speed))
            data = data.replace(ctrl=gain * msq, xfrc_applied=xfrc)
            data = mjx.step(model, data)
            return (data, speed), None

        if c.substeps == 1:
            (data, speed), _ = substep((state.data, state.rotor_speed), None)
        else:
            (data, speed), _ = jax.lax.scan(substep, (state.data, state.rotor_speed), None,
                                            length=c.substeps)

        true = jnp.concatenate([data.qvel[3:6], self.specific_force(theta, data, speed, force_world)])
        buf = jnp.concatenate([state.imu_buffer[1:], true[None]], 0)
        key, k = jax.random.split(state.key)
        imu = buf[0] + state.imu_bias + state.imu_std[0] * jax.random.normal(k, (6,))
        vib = state.imu_vibration
        if c.vibration:  # a Python branch: with vibration off the key stream is unchanged
            key, kv = jax.random.split(key)
            f = c.vibration_hz if c.vibration_hz > 0 else jnp.mean(speed) / (2 * jnp.pi)
            vib = vibration_step(vib, jax.random.normal(kv, (6,)), aliased_hz(f, c.dt),
                                 c.vibration_bandwidth_hz, c.dt)
            imu = imu + state.imu_std[2] * vib[-1]

        new = state.replace(data=data, rotor_speed=speed, imu=imu, imu_buffer=buf, imu_vibration=vib,
                            key=key, step=state.step + 1)
        bad = state.diverged | self._diverged(new)
        # A diverged vehicle is frozen at its last good state: no NaN leaves the step.
        out = jax.tree.map(lambda a, b: jnp.where(bad, a, b), state, new)
        return out.replace(diverged=bad, step=state.step + 1)

    def _diverged(self, s: SimState) -> jax.Array:
        c = self.config
        finite = (jnp.all(jnp.isfinite(s.data.qpos)) & jnp.all(jnp.isfinite(s.data.qvel))
                  & jnp.all(jnp.isfinite(s.rotor_speed)) & jnp.all(jnp.isfinite(s.imu)))
        inside = ((jnp.max(jnp.abs(s.pos)) < c.pos_limit) & (jnp.linalg.norm(s.vel) < c.vel_limit)
                  & (jnp.linalg.norm(s.omega) < c.rate_limit))
        return ~(finite & inside)

    def frame(self, state: SimState, motor_cmd, force_world) -> Frame:
        """Record of one step (unbatched)."""
        return Frame(pos=state.pos, quat=state.quat, vel=state.vel, omega=state.omega,
                     rotor_speed=state.rotor_speed, imu=state.imu,
                     motor_cmd=jnp.clip(motor_cmd, 0.0, 1.0), force=force_world,
                     diverged=state.diverged)


_step_jit = jax.jit(Quadrotor._step, static_argnums=0)


@functools.lru_cache(maxsize=16)
def _imu_free(sim: Quadrotor) -> Quadrotor:
    """``sim`` with the IMU's magnitudes zeroed in its config and the vibration's structure kept (on: a unit
    gyro amplitude): what its flights compile when :meth:`Quadrotor.init` is given the magnitudes."""
    c = sim.config
    free = dataclasses.replace(c, gyro_noise=0.0, accel_noise=0.0, gyro_bias=0.0, accel_bias=0.0,
                               gyro_vibration=float(c.vibration), accel_vibration=0.0)
    return sim if free == c else type(sim)(free, sim.xml_path)
