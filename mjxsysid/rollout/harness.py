"""Closed-loop harness: (high-level controller, low-level controller, vehicle, reference,
disturbance) -> time series and metrics.

``fly`` is unbatched and pure; ``fly_batch`` is the one vmap boundary (over vehicles,
controllers, references and disturbance realisations), jitted once per structure and length.
"""
from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from mjxsysid.runtime import distributed
from mjxsysid import theta as P
from mjxsysid.control.high_level import Cascade, Estimate
from mjxsysid.sim.quadrotor import Frame, Quadrotor, hover_rotor_speed, quat_to_mat


@struct.dataclass
class Disturbance:
    """External disturbances of one flight (batch with a leading axis).

    step_force: (3,) N world, applied from ``step_time`` (s) on. sigma: (3,) N, std of an i.i.d.
    Gaussian world force drawn per control step. torque: (3,) N·m extra constant body torque
    (added to the vehicle's τ_ext).

    Payload (off by default): a point mass ``payload_mass`` () kg attached at ``payload_pos`` (3,)
    m, body frame, from ``payload_time`` () s on (``inf``: never). From then on the vehicle flies
    with :func:`payload_theta` (mass + m_p, inertia + the point mass's parallel-axis terms about
    the body origin) plus the torque of the offset weight, :func:`payload_torque`, recomputed
    every step from the attitude. Approximation: the body origin stays the reference point of
    the dynamics (the centre of mass does not move), so the payload's weight acts through its
    torque alone; exact in steady hover, it leaves out the coupling terms m_p r × a_body and
    m_p ω̇ × r, which scale with the vehicle's own accelerations.
    """
    step_force: jax.Array
    step_time: jax.Array
    sigma: jax.Array
    torque: jax.Array
    payload_mass: jax.Array = struct.field(default_factory=lambda: jnp.float32(0.0))
    payload_pos: jax.Array = struct.field(default_factory=lambda: jnp.zeros(3, jnp.float32))
    payload_time: jax.Array = struct.field(default_factory=lambda: jnp.float32(jnp.inf))

    @classmethod
    def make(cls, step_force=(0.0, 0.0, 0.0), step_time=0.0, sigma=0.0, torque=(0.0, 0.0, 0.0),
             payload_mass=0.0, payload_pos=(0.0, 0.0, 0.0), payload_time=float("inf")):
        f = np.broadcast_to(np.asarray(step_force, np.float32), (3,))
        s = np.broadcast_to(np.asarray(sigma, np.float32), (3,))
        tq = np.broadcast_to(np.asarray(torque, np.float32), (3,))
        if not (np.all(np.isfinite(f)) and np.all(np.isfinite(tq)) and np.isfinite(step_time)):
            raise ValueError("disturbance values must be finite")
        if np.any(s < 0) or not np.all(np.isfinite(s)):
            raise ValueError(f"disturbance sigma must be finite and >= 0, got {sigma}")
        r = np.asarray(payload_pos, np.float32)
        if r.shape != (3,) or not np.all(np.isfinite(r)):
            raise ValueError(f"payload_pos must be 3 finite numbers (m, body frame), got {payload_pos}")
        if not (np.isfinite(payload_mass) and payload_mass >= 0):
            raise ValueError(f"payload_mass must be finite and >= 0 kg, got {payload_mass}")
        if np.isnan(payload_time):
            raise ValueError("payload_time must be a number of seconds (inf: never)")
        return cls(jnp.asarray(f), jnp.float32(step_time), jnp.asarray(s), jnp.asarray(tq),
                   jnp.float32(payload_mass), jnp.asarray(r), jnp.float32(payload_time))

    def forces(self, key, steps: int, dt: float) -> jax.Array:
        """World force sequence (steps, 3) N."""
        t = dt * jnp.arange(steps)
        step = jnp.where((t >= self.step_time)[:, None], self.step_force, 0.0)
        return step + self.sigma * jax.random.normal(key, (steps, 3))


def payload_theta(theta, mass, pos):
    """θ (..., 19) with a point mass ``mass`` (...) kg rigidly attached at ``pos`` (..., 3) m
    (body frame): mass + m_p, J_aa + m_p (|r|² − r_a²) (parallel-axis terms about the body
    origin; the products of inertia −m_p r_a r_b, zero for an offset along one axis, are
    dropped since θ holds a diagonal J). τ_ext is left alone: see :func:`payload_torque`."""
    theta = jnp.asarray(theta, jnp.float32)
    mass = jnp.asarray(mass, jnp.float32)
    pos = jnp.asarray(pos, jnp.float32)
    j_add = mass[..., None] * (jnp.sum(pos**2, -1, keepdims=True) - pos**2)
    theta = theta.at[..., P.MASS].add(mass)
    return theta.at[..., P.INERTIA].add(j_add)


def payload_torque(quat, mass, pos):
    """Body-frame torque (..., 3) N·m of the weight of a point mass ``mass`` (...) kg at ``pos``
    (..., 3) m (body frame) about the body origin, at attitude ``quat`` (..., 4) wxyz:
    r × (Rᵀ [0, 0, −m_p g])."""
    rot = quat_to_mat(jnp.asarray(quat, jnp.float32))
    w_world = jnp.stack([jnp.zeros_like(mass), jnp.zeros_like(mass), -mass * P.GRAVITY], -1)
    w_body = jnp.einsum("...ji,...j->...i", rot, w_world)
    return jnp.cross(jnp.asarray(pos, jnp.float32), w_body)


class Flight(NamedTuple):
    """Time series of one flight (leaves (T, ...); (B, T, ...) batched).

    frame: the simulator record after each step; ref_pos (3), ref_vel (3), ref_yaw ();
    a_cmd (), omega_cmd (3): the high-level command of that step; time (): s after the step;
    latent (8): the low-level controller's latent ẑ after the step, if it has one (else None).
    """
    frame: Frame
    ref_pos: jax.Array
    ref_vel: jax.Array
    ref_yaw: jax.Array
    a_cmd: jax.Array
    omega_cmd: jax.Array
    time: jax.Array
    latent: jax.Array | None = None


class LoopCarry(NamedTuple):
    """Everything a closed loop carries between control steps: the simulator state, the
    high-level controller's carry and the low-level controller's carry (unbatched)."""
    sim: object
    high: object
    low: object


def start_loop(sim: Quadrotor, theta, low, high: Cascade, ref, key, imu_std=None) -> LoopCarry:
    """Initial closed-loop carry: the vehicle θ (19,) at rest at the reference start (yaw
    aligned, hover rotor speeds). key: the ``k_sim`` / ``k_low`` keys of :func:`fly`; imu_std: the
    IMU's magnitudes (3, 6) given as data (None: the simulator's config, :meth:`Quadrotor.init`)."""
    k_sim, k_low = key
    theta = jnp.asarray(theta, jnp.float32)
    r0 = ref.at(jnp.float32(0.0))
    half = 0.5 * r0.yaw
    quat0 = jnp.array([jnp.cos(half), 0.0, 0.0, jnp.sin(half)])
    state = sim.init(theta, k_sim, pos=r0.pos, quat=quat0, rotor_speed=hover_rotor_speed(theta), imu_std=imu_std)
    return LoopCarry(state, high.init(), low.init(k_low))


def run_loop(sim: Quadrotor, theta, low, high: Cascade, ref, carry: LoopCarry, forces, start,
             steps: int, payload: Disturbance | None = None, unroll: int = 1) -> tuple[LoopCarry, Flight]:
    """Advance a closed loop ``steps`` control steps from ``carry``, the first step having the
    global index ``start`` (an unbatched int: time t = index · dt). θ (19,) the flown vehicle
    (τ_ext disturbance already added); forces (steps, 3) N world. ``payload``: a
    :class:`Disturbance` whose payload fields apply from its ``payload_time`` on (None: no
    payload). ``unroll``: control steps per iteration of the compiled loop (``lax.scan``'s
    unroll: fewer, larger kernels; the same result). Returns the new carry and the Flight of
    these steps (leaves (steps, ...))."""
    dt = sim.config.dt
    if payload is not None:
        theta_payload = payload_theta(theta, payload.payload_mass, payload.payload_pos)

    def body(c, inp):
        s, hc, lc = c
        i, f = inp
        t = i.astype(jnp.float32) * dt
        r = ref.at(t)
        est = Estimate(s.pos, s.vel, s.quat, s.omega)
        hc, cmd = high.step(hc, est, r, dt)
        # Controllers that run something periodically take the (unbatched) step index.
        lc, u = low.step_at(lc, s.imu, cmd, i) if hasattr(low, "step_at") else low.step(lc, s.imu, cmd)
        th = theta
        if payload is not None:  # after the event: the point mass and its offset weight
            th_p = theta_payload.at[P.TAU_EXT].add(
                payload_torque(s.quat, payload.payload_mass, payload.payload_pos))
            th = jnp.where(t >= payload.payload_time, th_p, theta)
        s = sim.step(th, s, u, f)
        lat = low.latent(lc) if hasattr(low, "latent") else None
        out = (sim.frame(s, u, f), r.pos, r.vel, r.yaw, cmd.a_cmd, cmd.omega_cmd, t + dt, lat)
        return LoopCarry(s, hc, lc), out

    idx = start + jnp.arange(steps)
    carry, out = jax.lax.scan(body, carry, (idx, forces), unroll=unroll)
    return carry, Flight(*out)


def start_flight(sim: Quadrotor, theta, low, high: Cascade, ref, disturbance: Disturbance, key,
                 steps: int, imu_std=None) -> tuple[jax.Array, LoopCarry, jax.Array]:
    """What :func:`fly` starts from: the flown θ (19,) (the disturbance's torque added to τ_ext),
    the closed loop's carry at rest at the reference start, and the world forces (steps, 3) N.
    imu_std: as :func:`start_loop`'s."""
    k_sim, k_dist, k_low = jax.random.split(key, 3)
    theta = jnp.asarray(theta, jnp.float32)
    theta = theta.at[P.TAU_EXT].add(disturbance.torque)
    carry0 = start_loop(sim, theta, low, high, ref, (k_sim, k_low), imu_std)
    return theta, carry0, disturbance.forces(k_dist, steps, sim.config.dt)


def fly(sim: Quadrotor, theta, low, high: Cascade, ref, disturbance: Disturbance, key,
        steps: int) -> Flight:
    """Fly one vehicle θ (19,) for ``steps`` control steps from rest at the reference start.

    low: a low-level controller (``init(key)``, ``step(carry, imu, Command)``); high: a
    :class:`Cascade`; ref: a reference pytree with ``at(t)``; key: PRNG key (IMU noise and
    disturbance realisation). The high-level controller sees the true state.
    """
    theta, carry0, forces = start_flight(sim, theta, low, high, ref, disturbance, key, steps)
    return run_loop(sim, theta, low, high, ref, carry0, forces, 0, steps, payload=disturbance)[1]


@functools.lru_cache(maxsize=64)
def _fly_batch(sim, steps, low_axes_def, low_axes_leaves, reduce=None):
    """The jitted batch of :func:`fly`: two vmaps, the start and the loop, so that the loop's
    carry enters its ``lax.scan`` batched in every leaf (a vmap's outputs are). Under one vmap
    of the whole flight, the leaves the start leaves unbatched (the high-level controller's zeros,
    most of MJX's data) become batched inside the loop, and JAX traces and batches the loop's
    body twice to find that fixed point: about a second more of tracing per flight program."""
    low_axes = jax.tree_util.tree_unflatten(low_axes_def, low_axes_leaves)

    def loop(theta, low, high, ref, disturbance, carry0, forces):
        flight = run_loop(sim, theta, low, high, ref, carry0, forces, 0, steps, payload=disturbance)[1]
        return flight if reduce is None else reduce(flight)

    def batch(theta, low, high, ref, disturbance, keys, imu_std):
        th, carry0, forces = jax.vmap(lambda *a: start_flight(sim, *a, steps, imu_std),
                                      in_axes=(0, low_axes, 0, 0, 0, 0))(theta, low, high, ref, disturbance, keys)
        return jax.vmap(loop, in_axes=(0, low_axes, 0, 0, 0, 0, 0))(th, low, high, ref, disturbance, carry0, forces)

    return jax.jit(batch)


def low_level_axes(low):
    """vmap axes of a low-level controller: ``low.batch_axes()`` if it defines one (e.g. network
    weights shared by the whole batch: None), else 0 for every leaf."""
    return low.batch_axes() if hasattr(low, "batch_axes") else 0


def fly_batch(sim: Quadrotor, theta, low, high, ref, disturbance, key, steps: int, *,
              same_key: bool = False, reduce=None) -> Flight:
    """Batched :func:`fly`: θ (B, 19) and every pytree argument with leading axis B (the
    low-level controller's shared leaves, per its ``batch_axes()``, unbatched). ``same_key``:
    every vehicle gets ``key`` itself, i.e. the same disturbance and noise realisation; a key
    batch (B, 2) gives vehicle b the key ``key[b]``. ``reduce``: a module-level function
    Flight -> pytree applied to each vehicle's flight inside the compiled function (so only
    what it returns is kept, e.g. error traces of large ensembles; any hashable callable, e.g. a
    frozen dataclass, as the compiled function is cached on it); returns its batched result.

    The batch is sharded over every device (:mod:`mjxsysid.runtime.distributed`: padded to a multiple
    of the device count, the padding dropped from the result); per-vehicle keys are drawn
    before padding, so the flights do not depend on the device count."""
    theta = jnp.asarray(theta, jnp.float32)
    n = theta.shape[0]
    key = jnp.asarray(key)
    if key.ndim == 2:
        if same_key or key.shape[0] != n:
            raise ValueError(f"a key batch must have one key per vehicle ({n}, 2) and no same_key; "
                             f"got shape {key.shape}")
        keys = key
    else:
        keys = jnp.broadcast_to(key, (n,) + key.shape) if same_key else jax.random.split(key, n)
    axes = low_level_axes(low)
    leaves, treedef = jax.tree_util.tree_flatten(axes, is_leaf=lambda x: x is None)
    sim, imu_std = sim.imu_as_data()     # every noise level of one structure: one program
    fn = _fly_batch(sim, int(steps), treedef, tuple(leaves), reduce)
    args = distributed.shard_batch((theta, low, high, ref, disturbance, keys, imu_std), n,
                                   axes=(0, axes, 0, 0, 0, 0, None))
    return distributed.unpad(fn(*args), n)


# ---------------------------------------------------------------------------------------
# Metrics
# ---------------------------------------------------------------------------------------

METRIC_KEYS = ("pos_rmse_m", "max_pos_err_m", "heading_rmse_deg", "lateral_rmse_m",
               "vertical_rmse_m", "saturation_frac", "failed", "fail_time_s")


def yaw_of(quat):
    """Yaw (rad) of wxyz quaternions (..., 4) -> (...)."""
    w, x, y, z = quat[..., 0], quat[..., 1], quat[..., 2], quat[..., 3]
    return jnp.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def wrap_angle(a):
    return (a + jnp.pi) % (2 * jnp.pi) - jnp.pi


def failure_mask(flight: Flight, *, box: float = 3.0, ground: float = 0.0):
    """Per step (T,): has the flight failed by now? Crash (z below ``ground``), divergence, or
    leaving a ``box``-metre tube around the reference."""
    fr = flight.frame
    err = jnp.linalg.norm(fr.pos - flight.ref_pos, axis=-1)
    bad = fr.diverged | (fr.pos[..., 2] < ground) | (err > box)
    return jnp.cumsum(bad.astype(jnp.int32), axis=-1) > 0


def metrics(flight: Flight, *, box: float = 3.0, ground: float = 0.0, sat_tol: float = 1e-3):
    """Tracking metrics of one flight (leaves (T, ...)); vmap for a batch.

    RMSEs and maxima are over the steps before failure (all steps if none). Saturation is the
    fraction of motor commands within ``sat_tol`` of 0 or 1. Returns a dict of scalars keyed
    by :data:`METRIC_KEYS`.
    """
    fr = flight.frame
    failed_by = failure_mask(flight, box=box, ground=ground)
    ok = (~failed_by).astype(jnp.float32)
    n = jnp.maximum(ok.sum(), 1.0)
    e = fr.pos - flight.ref_pos
    e2 = jnp.sum(e**2, -1)
    lat2 = jnp.sum(e[..., :2] ** 2, -1)
    head = wrap_angle(yaw_of(fr.quat) - flight.ref_yaw)
    sat = ((fr.motor_cmd <= sat_tol) | (fr.motor_cmd >= 1 - sat_tol)).mean(-1)
    fail_step = jnp.argmax(failed_by)
    failed = failed_by[-1]
    return {
        "pos_rmse_m": jnp.sqrt(jnp.sum(ok * e2) / n),
        "max_pos_err_m": jnp.sqrt(jnp.max(ok * e2)),
        "heading_rmse_deg": jnp.rad2deg(jnp.sqrt(jnp.sum(ok * head**2) / n)),
        "lateral_rmse_m": jnp.sqrt(jnp.sum(ok * lat2) / n),
        "vertical_rmse_m": jnp.sqrt(jnp.sum(ok * e[..., 2] ** 2) / n),
        "saturation_frac": jnp.sum(ok * sat) / n,
        "failed": failed,
        "fail_time_s": jnp.where(failed, flight.time[fail_step], jnp.nan),
    }


@jax.jit
def batch_metrics(flight: Flight) -> dict:
    """:func:`metrics` (default arguments) of a batch of flights (leaves (B, T, ...)) -> dict of
    (B,) arrays; compiled once per shape (``jax.vmap(metrics)`` runs op by op)."""
    return jax.vmap(metrics)(flight)


def metrics_to_host(m: dict) -> dict:
    """jnp metric dict (scalars or (B,) arrays) -> plain Python floats / lists (JSON-ready)."""
    out = {}
    for k, v in m.items():
        a = np.asarray(v)
        if a.dtype == bool:
            out[k] = a.tolist()
        else:
            out[k] = None if a.ndim == 0 and not np.isfinite(a) else (
                float(a) if a.ndim == 0 else [None if not np.isfinite(x) else float(x) for x in a])
    return out


def summarize(m: dict) -> dict:
    """Batch metrics (B,) -> success rate and mean ± std over successful flights."""
    failed = np.asarray(m["failed"], bool)
    out = {"n": int(failed.size), "success_rate": float(1 - failed.mean())}
    for k in ("pos_rmse_m", "max_pos_err_m", "heading_rmse_deg", "lateral_rmse_m",
              "vertical_rmse_m", "saturation_frac"):
        v = np.asarray(m[k], np.float64)[~failed]
        out[k] = {"mean": float(v.mean()) if v.size else None, "std": float(v.std()) if v.size else None,
                  "median": float(np.median(v)) if v.size else None}
    return out
