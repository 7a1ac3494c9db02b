"""(θ, ẑ) datasets for the decoder: θ from a prior, ẑ from a frozen policy's adaptation
module in closed-loop flight under excitation (paper §IV-A: 20,000 training pairs).

Each vehicle flies ``steps`` control steps (default 1.5 s, so the 0.2 s history has long
filled) under the baseline cascade tracking a random 3-D lemniscate (period 5–15 s, size up to
1.5 × 1.5 × 0.3 m, yaw weave) with a random Gaussian world force (σ up to 0.1 m g per axis);
ẑ is read at the last step. Failed flights are kept but flagged (``failed``) and left out of
training by the decoder. Works with any low-level controller that has ``latent(carry)``.

Latent trajectories (``collect(seconds=S)``, the CLI default S = 10): each vehicle flies S s
of one manoeuvre drawn at random (``MANOEUVRES``): a random lemniscate as above (period 5–15 s)
with a random Gaussian world force; a random 5-segment minimum-snap trajectory through
waypoints in a 2 × 2 × 1 m box (a seeded pool of 512) with a random Gaussian force; or hover
with a world force step (0.05–0.3 m g, random direction, at 0.5 s to 0.6 S) and a small
Gaussian force (σ up to 0.03 m g). ẑ is recorded at 10 Hz from 0.2 s on (the decode times of
``mjxsysid decode``), and the single-latent pair uses the last one.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid.runtime import distributed
from mjxsysid import theta as P
from mjxsysid.runtime.checkpoint import open_npz
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.references import MinSnap, Switch, stack
from mjxsysid.policy.adaptive import networks as N
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.runtime.progress import progress, tee
from mjxsysid.rollout.flight import broadcast, random_lemniscates
from mjxsysid.rollout.harness import Disturbance, failure_mask, fly_batch
from mjxsysid.sim import Quadrotor, SimConfig


def latents_in_flight(policy, theta, key, *, weights=None, steps: int = 750, sim=None):
    """Fly θ (n, 19) with a latent policy (a name, path or PolicyRef; see
    :func:`~mjxsysid.policy.interface.resolve_policy`) under excitation.
    Returns (ẑ at the last step (n, 8), failed (n,))."""
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    sim = sim or Quadrotor()
    low = resolve_policy(policy, weights).batched(n)
    ref, dist, k_fly = lemniscate_excitation(key, theta)
    z, failed = fly_batch(sim, theta, low, broadcast(Cascade.make("baseline"), n), ref, dist, k_fly, steps,
                          reduce=last_latent_and_failure)
    return np.asarray(z), np.asarray(failed)


def lemniscate_excitation(key, theta):
    """The single-latent pairs' excitation of θ (n, 19): (random lemniscates (leaves (n, ...)),
    Disturbance batch with a Gaussian world force of σ up to 0.1 m g per axis, the flight's key)."""
    n = len(theta)
    k_ref, k_force, k_fly = jax.random.split(key, 3)
    sigma = jax.random.uniform(k_force, (n, 1), minval=0.0, maxval=0.1) * theta[:, P.MASS, None] * P.GRAVITY
    dist = broadcast(Disturbance.make(), n).replace(sigma=jnp.broadcast_to(sigma, (n, 3)))
    return random_lemniscates(k_ref, n), dist, k_fly


@dataclasses.dataclass(frozen=True)
class LatentsAt:
    """A flight reducer (hashable, so the compiled flight is cached per step set): one flight
    (leaves (T, ...)) -> (ẑ at the control steps ``idx`` (L, 8), failed by the last step ())."""
    idx: tuple

    def __call__(self, flight):
        return flight.latent[jnp.asarray(self.idx)], failure_mask(flight)[-1]


def last_latent_and_failure(flight):
    """One flight (leaves (T, ...)) -> (ẑ at the last step (8,), failed by then ()): what
    :func:`latents_in_flight` keeps, reduced inside the compiled flight so that only (n, 9)
    numbers per batch leave the devices, not the (n, T, ...) trajectories."""
    return flight.latent[-1], failure_mask(flight)[-1]


MANOEUVRES = ("lemniscate", "minsnap", "hover_step")
TRAJ_RATE_HZ = 10.0
_MINSNAP_POOL = 512


def trajectory_times(seconds: float, rate: float = TRAJ_RATE_HZ, dt: float = 0.002):
    """(times (L,) s, step indices (L,), number of control steps) at which a ``seconds``-long
    flight's latent is recorded at ``rate`` Hz (the decode times of
    :func:`decode_indices`: from 0.2 s on, every 1/rate s). Raises ValueError for a flight shorter than
    the policy history (0.2 s)."""
    steps = int(round(seconds / dt))
    if not seconds > 0 or steps * dt < 0.2 - 1e-9:
        raise ValueError(f"seconds must be >= 0.2 (the policy's history), got {seconds}")
    times = dt * (np.arange(steps) + 1)
    idx = decode_indices(times, rate)
    return times[idx], idx, steps


@functools.lru_cache(maxsize=4)
def _minsnap_pool(seed: int, seconds: float):
    """The seeded pool of random min-snap paths the minsnap manoeuvre draws from (stacked,
    leaves (_MINSNAP_POOL, ...)): solved once per process, not once per batch (~2 s each)."""
    return stack([MinSnap.random(seed=seed * 7919 + i, duration=seconds, start=(0.0, 0.0, 1.0),
                                 box=((-1.0, -1.0, 0.5), (1.0, 1.0, 1.5))) for i in range(_MINSNAP_POOL)])


def random_manoeuvres(key, theta, seconds: float, manoeuvres=MANOEUVRES, seed: int = 0):
    """Per-vehicle excitation of a trajectory flight: (reference batch (Switch of Lemniscate and
    MinSnap, leaves (n, ...)), Disturbance batch, manoeuvre index (n,) into ``manoeuvres``)."""
    bad = [m for m in manoeuvres if m not in MANOEUVRES]
    if bad or not manoeuvres:
        raise ValueError(f"unknown manoeuvre(s) {bad}; choose from {MANOEUVRES}")
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    ks = jax.random.split(key, 8)
    kind = np.asarray(jnp.asarray([MANOEUVRES.index(m) for m in manoeuvres])[
        jax.random.randint(ks[0], (n,), 0, len(manoeuvres))])
    lem = random_lemniscates(ks[1], n)
    hover = kind == MANOEUVRES.index("hover_step")
    lem = lem.replace(size=jnp.where(hover[:, None], 0.0, lem.size),
                      yaw_amplitude=jnp.where(hover, 0.0, lem.yaw_amplitude))
    pick = np.asarray(jax.random.randint(ks[2], (n,), 0, _MINSNAP_POOL))
    ms = jax.tree.map(lambda a: jnp.asarray(a)[pick], _minsnap_pool(seed, float(seconds)))
    ref = Switch(lem, ms, jnp.asarray(kind == MANOEUVRES.index("minsnap")))
    mg = theta[:, P.MASS] * P.GRAVITY
    u = lambda k, lo, hi, shape=(n,): np.asarray(jax.random.uniform(k, shape, jnp.float32, lo, hi))
    sigma = np.where(hover, u(ks[3], 0.0, 0.03), u(ks[3], 0.0, 0.1)) * mg
    direction = np.array(jax.random.normal(ks[4], (n, 3)))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True) + 1e-9
    step = direction * (u(ks[5], 0.05, 0.3) * mg)[:, None] * hover[:, None]
    step_time = u(ks[6], 0.5, max(0.6 * seconds, 0.5 + 1e-3))
    dist = broadcast(Disturbance.make(), n).replace(
        step_force=jnp.asarray(step, jnp.float32), step_time=jnp.asarray(step_time),
        sigma=jnp.asarray(np.repeat(sigma[:, None], 3, 1), jnp.float32))
    return ref, dist, kind


def latent_trajectories_in_flight(policy, theta, key, *, seconds: float = 10.0, weights=None,
                                  manoeuvres=MANOEUVRES, rate: float = TRAJ_RATE_HZ, sim=None,
                                  seed: int = 0):
    """Fly θ (n, 19) ``seconds`` s with a latent policy under random manoeuvres
    (:func:`random_manoeuvres`). Returns (ẑ at ``rate`` Hz (n, L, 8), times (L,) s,
    failed (n,), manoeuvre index (n,))."""
    theta = np.asarray(theta, np.float32)
    n = len(theta)
    times, idx, steps = trajectory_times(seconds, rate)
    sim = sim or Quadrotor()
    k_man, k_fly = jax.random.split(key)
    ref, dist, kind = random_manoeuvres(k_man, theta, seconds, manoeuvres, seed)
    low = resolve_policy(policy, weights).batched(n)
    zt, failed = fly_batch(sim, theta, low, broadcast(Cascade.make("baseline"), n), ref, dist, k_fly, steps,
                           reduce=LatentsAt(tuple(int(i) for i in idx)))
    return np.asarray(zt), times, np.asarray(failed), kind


def collect(out, *, policy="mjxsysid", weights=None, n_train: int = 20_000,
            n_test: int = 2_000, prior: str | None = None, seed: int = 0, batch: int = 2_000,
            steps: int = 750, seconds: float | None = None, manoeuvres=MANOEUVRES,
            sim_config: SimConfig | None = None, log=print) -> Path:
    """Write ``out/pairs.npz``: theta_train (n_train, 19), zhat_train (n_train, 8), failed_train,
    and the same for the held-out test split, plus metadata (policy weights hash, prior, seed).
    ``prior`` defaults to the prior the policy's shipped decoders are trained on
    (:attr:`~mjxsysid.policy.interface.PolicyRef.decoder_prior`: 'wide_actuators' for
    mjxsysid's policy, 'xadap' for the released one).

    ``seconds`` None: the single-latent pairs (a ``steps``-step lemniscate, ẑ at its end).
    ``seconds`` S: S-second flights of random ``manoeuvres`` with the latent recorded at 10 Hz:
    also zhat_traj_train (n_train, L, 8), manoeuvre_train (n_train,) (index into
    ``MANOEUVRES``), the same for the test split, and traj_times (L,) s; zhat = the last latent.

    ``sim_config``: the simulator's settings (default: a clean IMU); e.g. IMU noise, bias and
    vibration drawn per flight (``randomize_imu``), so that decoders learn latents of noisy
    flights. Its IMU settings are recorded in the metadata (``imu``)."""
    if n_train < 1 or n_test < 1 or batch < 1:
        raise ValueError("n_train, n_test and batch must be >= 1")
    if seconds is not None:
        trajectory_times(seconds)  # validates
        if any(m not in MANOEUVRES for m in manoeuvres) or not manoeuvres:
            raise ValueError(f"manoeuvres must be a non-empty subset of {MANOEUVRES}, got {manoeuvres}")
    ref = resolve_policy(policy, weights)
    prior = prior or ref.decoder_prior
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    log = tee(log, out / "collect_log.txt")
    total = n_train + n_test
    nb = -(-total // batch)
    theta = np.asarray(P.get_prior(prior).sample(jax.random.PRNGKey(seed), nb * batch))
    sim_config = SimConfig() if sim_config is None else sim_config
    if not isinstance(sim_config, SimConfig):
        raise TypeError(f"sim_config must be a SimConfig, got {type(sim_config).__name__}")
    sim = Quadrotor(sim_config)
    zs, fs, trajs, kinds = [], [], [], []
    times = None
    if seconds is not None:
        steps = trajectory_times(seconds)[2]
    t0 = time.time()
    for i in progress(range(nb), desc="collect", unit="batch"):
        k = jax.random.fold_in(jax.random.PRNGKey(seed + 1), i)
        th = theta[i * batch:(i + 1) * batch]
        if seconds is None:
            z, f = latents_in_flight(ref, th, k, steps=steps, sim=sim)
        else:
            zt, times, f, kind = latent_trajectories_in_flight(ref, th, k, seconds=seconds, sim=sim,
                                                               manoeuvres=tuple(manoeuvres), seed=seed)
            z = zt[:, -1]
            trajs.append(zt)
            kinds.append(kind)
        zs.append(z)
        fs.append(f)
        done = (i + 1) * batch
        log(f"  {min(done, total)}/{total} vehicles, {done * steps / (time.time() - t0) / 1e6:.2f} M steps/s, "
            f"failed so far {int(np.sum(np.concatenate(fs)))}")
    z = np.concatenate(zs)[:total]
    f = np.concatenate(fs)[:total]
    theta = theta[:total]
    excitation = __doc__.split("\n\n")[1 if seconds is None else 2]
    meta = {**ref.to_dict(), "prior": prior, "seed": seed, "steps": steps, "excitation": excitation,
            "n_train": n_train, "n_test": n_test, "wall_s": time.time() - t0, "imu": imu_settings(sim_config),
            "device": str(jax.devices()[0]), "devices": distributed.device_count()}
    extra = {}
    if seconds is not None:
        zt = np.concatenate(trajs)[:total]
        kind = np.concatenate(kinds)[:total]
        meta.update(seconds=float(seconds), traj_rate_hz=TRAJ_RATE_HZ, manoeuvres=list(MANOEUVRES),
                    manoeuvres_used=list(manoeuvres))
        extra = dict(zhat_traj_train=zt[:n_train], zhat_traj_test=zt[n_train:], traj_times=times,
                     manoeuvre_train=kind[:n_train], manoeuvre_test=kind[n_train:])
    path = out / "pairs.npz"
    np.savez_compressed(path, theta_train=theta[:n_train], zhat_train=z[:n_train], failed_train=f[:n_train],
                        theta_test=theta[n_train:], zhat_test=z[n_train:], failed_test=f[n_train:],
                        **extra, meta_json=np.frombuffer(jsonout.dumps(meta).encode(), np.uint8))
    return path


IMU_SETTINGS = ("gyro_noise", "accel_noise", "gyro_bias", "accel_bias", "gyro_vibration", "accel_vibration",
                "imu_latency", "randomize_imu", "imu_clean_fraction")


def imu_settings(cfg: SimConfig) -> dict:
    """The IMU settings of a simulator config (what pairs record of the flights' sensors)."""
    return {k: getattr(cfg, k) for k in IMU_SETTINGS}


def load_pairs(path) -> tuple[dict, dict]:
    """Read a pairs.npz -> (arrays dict, meta dict)."""
    path = Path(path)
    if path.is_dir():
        path = path / "pairs.npz"
    if not path.is_file():
        raise FileNotFoundError(f"dataset not found: {path}")
    with open_npz(path, "pairs file") as f:
        need = {"theta_train", "zhat_train", "theta_test", "zhat_test"}
        missing = need - set(f.files)
        if missing:
            raise ValueError(f"{path}: missing arrays {sorted(missing)} (not a mjxsysid pairs file?)")
        arrays = {k: f[k] for k in f.files if k != "meta_json"}
        meta = json.loads(bytes(f["meta_json"]).decode()) if "meta_json" in f.files else {}
    for split in ("train", "test"):
        th, z = arrays[f"theta_{split}"], arrays[f"zhat_{split}"]
        if th.ndim != 2 or th.shape[1] != P.N_PARAMS or z.ndim != 2 or len(z) != len(th):
            raise ValueError(f"{path}: theta_{split} {th.shape} and zhat_{split} {z.shape} must be "
                             f"(n, {P.N_PARAMS}) and (n, latent)")
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: meta_json is not a JSON object")
    if "zhat_traj_train" in arrays:
        L = len(arrays.get("traj_times", ()))
        for split in ("train", "test"):
            zt = arrays.get(f"zhat_traj_{split}")
            if zt is None or zt.ndim != 3 or zt.shape[0] != len(arrays[f"theta_{split}"]) or zt.shape[1] != L:
                raise ValueError(f"{path}: zhat_traj_{split} must have shape "
                                 f"({len(arrays[f'theta_{split}'])}, {L}, z_dim) to match theta_{split} and "
                                 f"traj_times; got {None if zt is None else zt.shape}")
    return arrays, meta


def decode_indices(times, rate: float, start: float = N.HISTORY * 0.002) -> np.ndarray:
    """Indices (K,) of the steps at which a ``rate`` Hz decoder reads ẑ: every 1/rate s from the
    first step at or after ``start`` s (the last step if the flight is shorter)."""
    times = np.asarray(times)
    dt = float(times[1] - times[0]) if len(times) > 1 else 0.002
    every = max(int(round(1.0 / (rate * dt))), 1)
    after = np.flatnonzero(times >= start - 1e-9)
    if len(after) == 0:
        return np.array([len(times) - 1])
    return after[(after - after[0]) % every == 0]


def paper_vehicle_latents(policy, *, instant: bool = True, flight: bool = True):
    """The paper vehicle's latents that ``evaluate-decoder`` decodes for its posterior figures:
    (ẑ after a 1.5 s excited lemniscate (8,) as the single-latent pairs read it, or None;
    (ẑ at 10 Hz (L, 8), their times (L,) s) of a 10 s lemniscate for the sequence decoder, or None).
    ``policy``: a name, path or PolicyRef."""
    from mjxsysid.rollout.flight import fly_vehicles, one_flight
    ref = resolve_policy(policy)
    zhat = traj = None
    if instant:
        z, _ = latents_in_flight(ref, np.repeat(P.PAPER_HARDWARE[None], 2, 0), jax.random.PRNGKey(0))
        zhat = z[0]
    if flight:
        one = one_flight(fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=ref, reference="lemniscate",
                                      period=10.0)[0])
        idx = decode_indices(one.time, 10.0)
        traj = (np.asarray(one.latent)[idx], np.asarray(one.time)[idx])
    return zhat, traj

