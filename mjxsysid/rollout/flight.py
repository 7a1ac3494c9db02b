"""Scripted flights: build controllers and references from names, fly, save, evaluate.

Used by ``mjxsysid fly`` and ``mjxsysid demo``; the same functions serve notebooks.
"""
from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.low_level import KTheta, KThetaLag
from mjxsysid.control.references import Hover, Lemniscate, MinSnap, stack
from mjxsysid.rollout.harness import Disturbance, Flight, batch_metrics, fly_batch, metrics_to_host, summarize
from mjxsysid.sim import Quadrotor, SimConfig
from mjxsysid.sim.quadrotor import quat_to_mat

CONTROLLERS = ("oracle", "k_theta", "nominal", "policy")
REFERENCES = ("hover", "lemniscate", "minsnap")


def minsnap_segments(duration: float) -> int:
    """Segments of a random min-snap reference of ``duration`` s: one per second, 1 to 5 (five
    2 m segments in 2 s ask for accelerations no vehicle of the prior has)."""
    return int(min(5, max(1, round(float(duration)))))


GROUND_CLEARANCE = 0.2
"""Random min-snap references of flights stay this high (m) or higher along their whole path
(without it about 1 in 10 dipped below the ground and crashed every controller)."""


def make_reference(name: str, *, period: float = 10.0, duration: float | None = None,
                   seed: int = 0, size=(1.0, 1.0, 0.3), start=(0.0, 0.0, 1.0)):
    """A reference by name. Returns (reference, default duration in s)."""
    if name == "hover":
        return Hover.make(pos=start), 5.0
    if name == "lemniscate":
        return Lemniscate.make(period=period, size=size, center=start), period
    if name == "minsnap":
        d = 5.0 if duration is None else duration
        return MinSnap.random(seed=seed, n_segments=minsnap_segments(d), duration=d, start=start,
                              min_height=GROUND_CLEARANCE), d
    raise ValueError(f"unknown reference {name!r}; choose from {REFERENCES}")


def make_low_level(name: str, theta, policy=None, dt: float = 0.002):
    """'oracle': the lag-aware K_θ (:class:`~mjxsysid.control.low_level.KThetaLag`) with each
    vehicle's true θ, the yardstick wherever an oracle is one; 'k_theta': the
    paper's K_θ with each vehicle's true θ (ignores τ_m; the action-replay probe); 'nominal': K_θ with the paper vehicle's θ whatever is flown
    (non-adaptive); 'policy': the frozen latent policy ``policy``, already resolved (anything
    with ``batched(B)``: a :class:`~mjxsysid.policy.interface.PolicyRef` from
    :func:`~mjxsysid.policy.interface.resolve_policy`, or a controller). θ (B, 19) -> batched
    controller; ``dt``: the control period (s) the lag-aware oracle compensates over."""
    theta = np.asarray(theta, np.float32)
    if name in ("oracle", "k_theta", "nominal") and policy is not None:
        raise ValueError(f"--policy / --weights do not apply to the {name} K_θ controller")
    if name == "oracle":
        return KThetaLag.make(theta, dt=dt)
    if name == "k_theta":
        return KTheta.make(theta)
    if name == "nominal":
        return KTheta.make(np.broadcast_to(P.PAPER_HARDWARE, theta.shape))
    if name == "policy":
        if not hasattr(policy, "batched"):
            raise ValueError(f"controller 'policy' needs a resolved latent policy, got {policy!r}: pass "
                             f"policy=mjxsysid.policy.interface.resolve_policy(NAME_OR_PATH)")
        return policy.batched(theta.shape[0])
    raise ValueError(f"unknown controller {name!r}; choose from {CONTROLLERS}")


def broadcast(tree, b: int):
    """Give every leaf of an unbatched pytree a leading axis of size b."""
    return jax.tree.map(lambda a: jnp.broadcast_to(a, (b,) + jnp.shape(a)), tree)


def fly_vehicles(theta, *, controller="oracle", reference="lemniscate", period=10.0,
                 duration=None, gains="baseline", force_step=(0.0, 0.0, 0.0), force_step_time=1.0,
                 force_sigma=0.0, seed=0, sim: Quadrotor | None = None, refs=None, policy=None):
    """Fly a batch θ (B, 19) (or one vehicle (19,)) under one controller and reference.

    Returns (Flight with (B, T, ...) leaves, metrics dict of (B,) arrays, duration s).
    ``refs`` may pass a pre-built batched reference (e.g. one min-snap per vehicle); ``policy``:
    the resolved latent policy of ``controller='policy'`` (see :func:`make_low_level`).
    ``force_step``: (3,) N for every vehicle, or (B, 3) one per vehicle (e.g. scaled by its mass).
    """
    theta = P.as_batch(theta)
    b = theta.shape[0]
    if duration is not None and not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    if refs is None:
        ref, d0 = make_reference(reference, period=period, duration=duration, seed=seed)
        refs = broadcast(ref, b)
    else:
        d0 = float(np.max(np.asarray(refs.duration)))
    duration = d0 if duration is None else duration
    sim = sim or Quadrotor(SimConfig())
    steps = int(round(duration / sim.config.dt))
    low = make_low_level(controller, theta, policy, dt=sim.config.dt)
    high = broadcast(Cascade.make(gains), b)
    f = np.asarray(force_step, np.float32)
    if f.shape not in ((3,), (b, 3)) or not np.isfinite(f).all():
        raise ValueError(f"force_step must be finite, of shape (3,) or ({b}, 3) (one per vehicle); got {f.shape}")
    dist = broadcast(Disturbance.make(step_time=force_step_time, sigma=force_sigma), b)
    dist = dist.replace(step_force=jnp.broadcast_to(jnp.asarray(f), (b, 3)))
    flight = fly_batch(sim, theta, low, high, refs, dist, jax.random.PRNGKey(seed), steps)
    return flight, batch_metrics(flight), duration


def random_minsnaps(n: int, seed: int, duration: float = 5.0):
    """n seeded random min-snap references stacked into one batch, :func:`minsnap_segments`
    segments each, at least :data:`GROUND_CLEARANCE` above the ground along the whole path."""
    return stack([MinSnap.random(seed=seed * 100_003 + i, n_segments=minsnap_segments(duration), duration=duration,
                                 start=(0.0, 0.0, 1.0), min_height=GROUND_CLEARANCE) for i in range(n)])


def save_flight(flight: Flight, theta, path, index: int = 0) -> Path:
    """Write one flight of a batch to an .npz (plain arrays, no pickle)."""
    f = jax.tree.map(lambda a: np.asarray(a[index]), flight)
    fr = f.frame
    path = Path(path)
    np.savez_compressed(path, time=f.time, pos=fr.pos, quat=fr.quat, vel=fr.vel, omega=fr.omega,
                        rotor_speed=fr.rotor_speed, imu=fr.imu, motor_cmd=fr.motor_cmd,
                        force=fr.force, diverged=fr.diverged, ref_pos=f.ref_pos, ref_vel=f.ref_vel,
                        ref_yaw=f.ref_yaw, a_cmd=f.a_cmd, omega_cmd=f.omega_cmd,
                        theta=np.asarray(P.as_batch(theta)[index]))
    return path


def seen_imu(imu) -> np.ndarray:
    """The IMU reading the controller acted on at each step (T, 6): a Flight's ``frame.imu`` is
    the reading *after* each step, so the controller saw the previous row; the first row is the
    at-rest hover reading [0, 0, 0, 0, 0, g]."""
    imu = np.asarray(imu, np.float32)
    imu0 = np.zeros_like(imu[..., :1, :])
    imu0[..., 5] = P.GRAVITY
    return np.concatenate([imu0, imu[..., :-1, :]], -2)


def flight_log(frame, index: int | None = None) -> dict:
    """A flight's IMU and motor log as :func:`mjxsysid.logs.csvlog.read_log` gives a log's (what the
    log-grounded posterior reads), from its ``frame`` (a Flight's, or any Frame): 'imu' (T, 6) the
    readings the controller acted on (:func:`seen_imu`), 'motor' (T, 4) the motor commands,
    'velocity_body' (T, 3) m/s the true velocity in the body frame (what a state estimate gives); of
    vehicle ``index`` of a batched flight."""
    imu, motor, quat, vel = frame.imu, frame.motor_cmd, frame.quat, frame.vel
    if index is not None:
        imu, motor, quat, vel = imu[index], motor[index], quat[index], vel[index]
    R = np.asarray(quat_to_mat(np.asarray(quat, np.float32)), np.float64)
    return {"imu": seen_imu(imu), "motor": np.asarray(motor),
            "velocity_body": np.einsum("tji,tj->ti", R, np.asarray(vel, np.float64))}


def one_flight(flight: Flight, index: int = 0) -> Flight:
    return jax.tree.map(lambda a: np.asarray(a[index]), flight)


def metrics_dict(m: dict, index: int | None = 0) -> dict:
    """metrics of flight ``index`` (or the batch summary if index is None), JSON-ready."""
    if index is None:
        return summarize(m)
    d = metrics_to_host({k: np.asarray(v)[index] for k, v in m.items()})
    d["failed"] = bool(d["failed"])
    return d


def write_metrics(m: dict, path, index: int | None = 0, extra: dict | None = None) -> dict:
    """metrics of flight ``index`` (or the batch summary if index is None) -> JSON file."""
    d = metrics_dict(m, index)
    if extra:
        d.update(extra)
    Path(path).write_text(jsonout.dumps(d, indent=2) + "\n")
    return d


def random_lemniscates(key, n: int):
    """n random excitation references, stacked (leaves (n, ...))."""
    ks = jax.random.split(key, 4)
    u = lambda k, lo, hi, shape=(n,): jax.random.uniform(k, shape, jnp.float32, lo, hi)
    return Lemniscate(center=jnp.tile(jnp.array([0.0, 0.0, 1.0]), (n, 1)),
                      size=u(ks[0], 0.0, 1.0, (n, 3)) * jnp.array([1.5, 1.5, 0.3]),
                      period=u(ks[1], 5.0, 15.0), yaw=jnp.zeros(n),
                      yaw_amplitude=u(ks[2], -0.5, 0.5), duration=jnp.full((n,), jnp.inf))
