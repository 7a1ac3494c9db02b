"""One quadrotor of any θ as a dm_control environment (``dm_env`` interface).

The MuJoCo model is ``assets/quadrotor.xml``, the file the MJX simulator loads, rewritten for θ
the way :meth:`mjxsysid.sim.quadrotor.Quadrotor.model` rewrites it (body mass and inertia, rotor
sites, actuator gear), here on the CPU ``MjModel`` that dm_control's ``Physics`` wraps: both
simulators share one model file and one set of field edits, so there is no second description
of the vehicle to drift (``dm_control.mjcf`` would rebuild the XML; nothing here needs that).
What MuJoCo does not integrate is computed around ``mj_step`` exactly as the MJX simulator does
(rotor first-order speed dynamics integrated exactly, thrust η k_t Ω², body-frame drag, τ_ext,
a world disturbance force), in float64. The IMU is ideal (no noise, bias or latency).

Agent interface: action (4,) = normalised rotor-speed commands Ω_cmd / Ω_max in [0, 1], in
mjxsysid's rotor order; observations: what the policy sees — ``imu`` (6,) [gyro rad/s, specific
force m/s²] body frame, ``command`` (4,) [a_cmd m/s², ω_cmd rad/s (3)] of the baseline cascade
tracking the task's reference — plus the privileged state (``position``, ``velocity``,
``quaternion`` wxyz, ``angular_velocity``, ``rotor_speed``, ``reference_position``).
Reward: position tracking, 1 within 5 cm of the reference, falling off smoothly to 0.1 at 0.5 m
(``dm_control.utils.rewards.tolerance``). An episode ends (discount 0) when the vehicle
diverges (the MJX simulator's limits) or touches the ground.
"""
from __future__ import annotations

import collections
import warnings

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

# dm_control probes GLFW for its renderer when imported; without a display GLFW warns. Nothing
# here renders (videos: mjxsysid.render), so that one message is not news.
warnings.filterwarnings("ignore", message=r".*DISPLAY environment variable is missing")
from dm_control import mujoco as dm_mujoco  # noqa: E402
from dm_control.rl import control  # noqa: E402
from dm_control.suite import base  # noqa: E402
from dm_control.utils import rewards  # noqa: E402

from mjxsysid import theta as P
from mjxsysid.control.high_level import Cascade, Estimate
from mjxsysid.rollout.flight import make_reference
from mjxsysid.sim.motors import mean_square_speed
from mjxsysid.sim.quadrotor import ASSET, BODY, SimConfig, hover_rotor_speed


TASKS = ("hover", "lemniscate", "minsnap", "force_step")
"""Tasks: hover at (0, 0, 1) m; a lemniscate (``period``); a random min-snap path (``seed``);
hover with a world force step of [1, 1, 0] N × m / m_paper from ``step_time`` s (the same
acceleration for every vehicle, as in the closed-loop fidelity benchmark)."""

DT = SimConfig().dt
_TRACK_MARGIN = 0.5  # m: the tracking reward falls to 0.1 here


def _rot(quat) -> np.ndarray:
    m = np.zeros(9)
    mujoco.mju_quat2Mat(m, np.asarray(quat, np.float64))
    return m.reshape(3, 3)


class QuadrotorPhysics(dm_mujoco.Physics):
    """dm_control Physics of one vehicle θ (19,). Beside MuJoCo's state it carries the rotor
    speeds (4,) rad/s and the world disturbance force (3,) N, which ``before_step`` uses."""

    @classmethod
    def from_theta(cls, theta) -> "QuadrotorPhysics":
        """θ (19,), validated -> physics with this vehicle's mass, inertia, rotor sites and gear."""
        theta = np.asarray(P.validate_theta(theta, what="vehicle"), np.float64)
        if theta.shape != (P.N_PARAMS,):
            raise ValueError(f"vehicle: one θ of shape ({P.N_PARAMS},) expected, got {theta.shape}")
        physics = cls.from_xml_path(str(ASSET))
        m = physics.model.ptr
        m.opt.timestep = DT
        m.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
        sites = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, f"rotor{i}") for i in range(1, 5)]
        m.body_mass[BODY] = theta[P.MASS]
        m.body_inertia[BODY] = theta[P.INERTIA]
        m.site_pos[sites] = np.asarray(P.rotor_positions(theta), np.float64)
        m.actuator_gear[:, 5] = np.asarray(P.YAW_SIGNS, np.float64) * theta[P.KTAU] / theta[P.KT]
        m.body_subtreemass[:] = theta[P.MASS]
        physics.theta = theta
        physics.rotor_speed = np.zeros(4)
        physics.force_world = np.zeros(3)
        return physics

    # state views ------------------------------------------------------------------------------
    def position(self):
        return self.data.qpos[0:3].copy()

    def quaternion(self):
        return self.data.qpos[3:7].copy()

    def velocity(self):
        return self.data.qvel[0:3].copy()

    def angular_velocity(self):
        """Body-frame rates (a free joint's angular qvel is in the body frame)."""
        return self.data.qvel[3:6].copy()

    def specific_force(self) -> np.ndarray:
        """An ideal accelerometer at the centre of mass, body frame (3,) m/s²."""
        th = self.theta
        rot = _rot(self.data.qpos[3:7])
        thrust = np.sum(th[P.ETA] * th[P.KT] * self.rotor_speed**2)
        drag = -th[P.DRAG] * (rot.T @ self.data.qvel[0:3])
        return (drag + rot.T @ self.force_world + np.array([0.0, 0.0, thrust])) / th[P.MASS]

    def imu(self) -> np.ndarray:
        return np.concatenate([self.angular_velocity(), self.specific_force()])

    def apply_motor_command(self, motor_cmd) -> None:
        """Set ctrl and xfrc_applied for the next ``mj_step`` from motor commands (4,) in [0, 1]
        (clipped), advancing the rotor speeds over the step: the MJX simulator's ``substep``."""
        th = self.theta
        omega_cmd = np.clip(np.asarray(motor_cmd, np.float64), 0.0, 1.0) * th[P.OMEGA_MAX]
        msq, self.rotor_speed = mean_square_speed(self.rotor_speed, omega_cmd, th[P.TAU_M], DT, exp=np.exp)
        rot = _rot(self.data.qpos[3:7])
        drag = rot @ (-th[P.DRAG] * (rot.T @ self.data.qvel[0:3]))
        self.data.xfrc_applied[BODY] = np.concatenate([drag + self.force_world, rot @ th[P.TAU_EXT]])
        self.data.ctrl[:] = th[P.ETA] * th[P.KT] * msq

    def diverged(self) -> bool:
        c = SimConfig()
        state = np.concatenate([self.data.qpos, self.data.qvel, self.rotor_speed])
        return bool(not np.all(np.isfinite(state)) or np.max(np.abs(self.data.qpos[0:3])) >= c.pos_limit
                    or np.linalg.norm(self.data.qvel[0:3]) >= c.vel_limit
                    or np.linalg.norm(self.data.qvel[3:6]) >= c.rate_limit)


@jax.jit
def _cascade_step(cascade: Cascade, integral, est: Estimate, ref, t):
    """One evaluation of the reference at t: the cascade's (integral, command) and its position."""
    r = ref.at(t)
    integral, cmd = cascade.step(integral, est, r, DT)
    return integral, cmd, r.pos


class QuadrotorTask(base.Task):
    """Track a reference (``task`` in :data:`TASKS`) with motor commands; the baseline cascade
    turns the reference into the commands the policy observes."""

    def __init__(self, task: str = "lemniscate", *, period: float = 10.0, seed: int = 0,
                 step_time: float = 0.5, gains="baseline", random=None):
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}; choose from {TASKS}")
        if not period > 0:
            raise ValueError(f"period must be > 0 s, got {period}")
        super().__init__(random=random)
        self.task = task
        self.step_time = float(step_time)
        self.reference, self.default_duration = make_reference("hover" if task == "force_step" else task,
                                                               period=period, seed=seed)
        self.cascade = Cascade.make(gains)
        self._integral = self.cascade.init()
        self._command = np.zeros(4)
        self._ref_pos = np.zeros(3)
        self._steps = 0

    # dm_control Task interface -----------------------------------------------------------------
    def initialize_episode(self, physics: QuadrotorPhysics):
        """At rest at the reference start, yaw aligned, rotors at hover speed: the MJX harness's
        ``start_loop``."""
        r0 = self.reference.at(jnp.float32(0.0))
        half = 0.5 * float(r0.yaw)
        with physics.reset_context():
            physics.data.qpos[:] = np.concatenate([np.asarray(r0.pos, np.float64),
                                                   [np.cos(half), 0.0, 0.0, np.sin(half)]])
            physics.data.qvel[:] = 0.0
        physics.rotor_speed = np.asarray(hover_rotor_speed(physics.theta), np.float64)
        physics.force_world = np.zeros(3)
        self._integral = self.cascade.init()
        self._steps = 0
        self._update_command(physics)

    def before_step(self, action, physics: QuadrotorPhysics):
        physics.force_world = self._force(physics, self._steps * DT)
        physics.apply_motor_command(action)

    def after_step(self, physics: QuadrotorPhysics):
        self._steps += 1
        self._update_command(physics)

    def action_spec(self, physics):
        from dm_env import specs
        return specs.BoundedArray((4,), np.float64, 0.0, 1.0, name="motor_command")

    def get_observation(self, physics: QuadrotorPhysics):
        obs = collections.OrderedDict()
        obs["imu"] = physics.imu()
        obs["command"] = self._command.copy()
        obs["position"] = physics.position()
        obs["velocity"] = physics.velocity()
        obs["quaternion"] = physics.quaternion()
        obs["angular_velocity"] = physics.angular_velocity()
        obs["rotor_speed"] = physics.rotor_speed.copy()
        obs["reference_position"] = self._ref_pos.copy()
        return obs

    def get_reward(self, physics: QuadrotorPhysics):
        err = np.linalg.norm(physics.position() - self._ref_pos)
        return float(rewards.tolerance(err, bounds=(0.0, 0.05), margin=_TRACK_MARGIN, sigmoid="gaussian"))

    def get_termination(self, physics: QuadrotorPhysics):
        if physics.diverged() or physics.data.qpos[2] <= 0.0:
            return 0.0
        return None

    # helpers ----------------------------------------------------------------------------------
    def _force(self, physics: QuadrotorPhysics, t: float) -> np.ndarray:
        if self.task != "force_step" or t < self.step_time:
            return np.zeros(3)
        return np.array([1.0, 1.0, 0.0]) * physics.theta[P.MASS] / P.PAPER_HARDWARE[P.MASS]

    def _update_command(self, physics: QuadrotorPhysics):
        """The cascade's command and the reference position for the current state at t = steps · dt
        (the MJX loop's order: state, then command, then policy, then step)."""
        est = Estimate(*(jnp.asarray(a, jnp.float32) for a in (physics.position(), physics.velocity(),
                                                               physics.quaternion(), physics.angular_velocity())))
        self._integral, cmd, pos = _cascade_step(self.cascade, self._integral, est, self.reference,
                                                 jnp.float32(self._steps * DT))
        self._command = np.concatenate([[float(cmd.a_cmd)], np.asarray(cmd.omega_cmd, np.float64)])
        self._ref_pos = np.asarray(pos, np.float64)


def make_env(theta=None, task: str = "lemniscate", *, duration: float | None = None, period: float = 10.0,
             seed: int = 0, step_time: float = 0.5) -> control.Environment:
    """A dm_control environment of one vehicle θ (19,) (default the paper vehicle; a vehicle
    file's θ, a prior draw or a decoded sample) on ``task``; one control step = one 500 Hz
    simulator step; ``duration`` s (default: the reference's, 5 s for hover and force_step)."""
    theta = P.paper_hardware() if theta is None else theta
    physics = QuadrotorPhysics.from_theta(theta)
    t = QuadrotorTask(task, period=period, seed=seed, step_time=step_time)
    d = t.default_duration if duration is None else float(duration)
    if not d > 0:
        raise ValueError(f"duration must be > 0 s, got {d}")
    return control.Environment(physics, t, time_limit=d, n_sub_steps=1)


def ensemble_envs(thetas, task: str = "lemniscate", **kw) -> list[control.Environment]:
    """One environment per vehicle of a decoded ensemble (K, 19) (e.g. ``decode(...)``'s samples):
    samples that are not physically valid are projected first (:func:`mjxsysid.theta.project_valid`)."""
    thetas = np.asarray(thetas, np.float64)
    if thetas.ndim != 2 or thetas.shape[1] != P.N_PARAMS:
        raise ValueError(f"thetas: shape (K, {P.N_PARAMS}) expected, got {thetas.shape}")
    valid, _ = P.project_valid(thetas)
    return [make_env(th, task, **kw) for th in np.asarray(valid, np.float64)]
