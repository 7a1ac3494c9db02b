"""Robustness envelopes of decoded models under force disturbances (paper §V-B, DESIGN §7).

For each true vehicle θ*: an identification flight gives the policy's latent ẑ, the decoder
turns ẑ into models θ̂ ~ p(θ | ẑ) (projected to valid θ), and the true vehicle, the decoded
models and uniform ±p perturbations of θ* are flown by the same frozen policy from hover with
identical initial conditions and identical disturbance realisations:

- **step**: a constant world force (e.g. [1, 1, 0] N) from ``onset``; 1 true rollout, ``n_decoded``
  decoded and ``n_perturbed`` perturbed rollouts, all with the same key;
- **Monte Carlo**: an i.i.d. Gaussian world force of std σ per axis and control step;
  ``mc_rollouts`` true rollouts (noise seeds), and for every seed ``mc_models`` decoded models
  (fresh samples from the same ẑ) and ``mc_models`` perturbed models flown with that seed.

Every rollout is one row of a table (θ, reference, disturbance, key) flown in fixed-size chunks
through :func:`~mjxsysid.rollout.harness.fly_batch` with :func:`error_traces` as the reduction,
so one compiled function serves the identification flights, the steps and the Monte Carlo, and
only the lateral / vertical error traces (every :data:`RECORD_EVERY`-th step) leave the device.
Hover is the :class:`~mjxsysid.control.references.Lemniscate` of size 0, so the identification
flight (a lemniscate, like the decoder's training flights) shares that compiled function too.

The statistics (:func:`step_stats`, :func:`mc_stats`) use
:func:`~mjxsysid.uses.fidelity.envelope_stats` and
:func:`~mjxsysid.uses.fidelity.energy_distance`.
"""
from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import theta as P
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.references import Lemniscate
from mjxsysid.dataset.collect import decode_indices
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.rollout.flight import broadcast, flight_log
from mjxsysid.rollout.harness import Disturbance, Flight, failure_mask, fly_batch
from mjxsysid.sim import Quadrotor
from mjxsysid.sim.quadrotor import Frame
from mjxsysid.uses.fidelity import (POSTERIORS, WINDOWS, check_decoder_window, energy_distance, envelope,
                                       envelope_stats, posterior_draws)

RECORD_EVERY = 5
"""Error traces keep every 5th control step (100 Hz at the default 500 Hz)."""


@dataclasses.dataclass(frozen=True)
class RobustnessConfig:
    """Protocol of the robustness study. Defaults: the full (GPU) run.

    duration: s, every rollout (identification flights too: one compiled function).
    onset: s, when the force step starts; errors are scored from here on (Monte Carlo too).
    forces: the constant world force steps (N) of the step test. sigmas: N, per-axis std of the
    Gaussian forces of the Monte Carlo. n_decoded / n_perturbed: models in the step test.
    mc_rollouts: true rollouts (noise seeds) per σ; mc_models: decoded (and perturbed) models
    per seed. perturbation: half-width of the uniform θ* ⊙ U(1 − p, 1 + p) baseline.
    id_reference: 'lemniscate' (the decoder's training flights are 1.5 s lemniscates) or 'hover';
    id_period, id_size: its period (s) and size (m). scale_forces_by_mass: multiply forces and
    σ by m / m_paper (the same accelerations on every vehicle; the paper vehicle's factor is 1).
    sample_steps: Euler steps of the CFM sampler. chunk: rollouts per compiled batch.
    window: 'flight' (every ẑ of the identification flight at ``id_rate`` Hz, decoded by the
    sequence decoder: the flight-level posterior) or 'instant' (ẑ at its end, single-latent CFM).
    posterior: 'decoded' (the decoded models), 'log_grounded' (draws of the log-grounded posterior of
    the identification flight's IMU and motor commands, the decoded models its proposal:
    :mod:`mjxsysid.identify`) or 'log_grounded_weighed' (those draws with the true mass).
    """
    duration: float = 4.0
    onset: float = 0.5
    forces: tuple = ((1.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    sigmas: tuple = (1.0, 3.0, 5.0)
    n_decoded: int = 100
    n_perturbed: int = 100
    mc_rollouts: int = 100
    mc_models: int = 20
    perturbation: float = 0.2
    id_reference: str = "lemniscate"
    id_period: float = 10.0
    id_size: tuple = (1.0, 1.0, 0.3)
    scale_forces_by_mass: bool = True
    sample_steps: int = 50
    chunk: int = 16384
    window: str = "flight"
    id_rate: float = 10.0
    posterior: str = "decoded"

    def __post_init__(self):
        for f in ("n_decoded", "n_perturbed", "mc_rollouts", "mc_models", "chunk", "sample_steps"):
            if int(getattr(self, f)) < 1:
                raise ValueError(f"RobustnessConfig.{f} must be >= 1, got {getattr(self, f)}")
        if not 0 <= self.onset < self.duration:
            raise ValueError(f"RobustnessConfig.onset must be in [0, duration={self.duration}) s, got {self.onset}")
        if not 0 < self.perturbation < 1:
            raise ValueError(f"RobustnessConfig.perturbation must be in (0, 1), got {self.perturbation}")
        if self.window not in WINDOWS:
            raise ValueError(f"RobustnessConfig.window must be one of {WINDOWS}, got {self.window!r}")
        if self.posterior not in POSTERIORS:
            raise ValueError(f"RobustnessConfig.posterior must be one of {POSTERIORS}, got {self.posterior!r}")
        if not self.id_rate > 0:
            raise ValueError(f"RobustnessConfig.id_rate must be > 0 Hz, got {self.id_rate}")
        if self.id_reference not in ("lemniscate", "hover"):
            raise ValueError(f"RobustnessConfig.id_reference must be 'lemniscate' or 'hover', got {self.id_reference!r}")
        if any(len(f) != 3 for f in self.forces):
            raise ValueError(f"RobustnessConfig.forces must be 3-vectors (N), got {self.forces}")
        if any(not s >= 0 for s in self.sigmas):
            raise ValueError(f"RobustnessConfig.sigmas must be >= 0 N, got {self.sigmas}")


class ErrorTrace(NamedTuple):
    """What a robustness rollout keeps (leaves (...) per rollout, (N, ...) batched).

    lateral: (T',) m, √(Δx² + Δy²); vertical: (T',) m, |Δz| (every :data:`RECORD_EVERY`-th
    step); failed: () bool, crashed / diverged / left the 3 m tube; latent: (8,) ẑ at the last step
    (zeros for controllers without a latent).
    """
    lateral: jax.Array
    vertical: jax.Array
    failed: jax.Array
    latent: jax.Array


def error_traces(flight: Flight) -> ErrorTrace:
    """Reduction of one flight (leaves (T, ...)) -> :class:`ErrorTrace`."""
    e = (flight.frame.pos - flight.ref_pos)[RECORD_EVERY - 1::RECORD_EVERY]
    lat = flight.latent[-1] if flight.latent is not None else jnp.zeros(8, jnp.float32)
    return ErrorTrace(jnp.linalg.norm(e[:, :2], axis=-1), jnp.abs(e[:, 2]), failure_mask(flight)[-1], lat)


def id_traces(flight: Flight) -> tuple[ErrorTrace, jax.Array]:
    """Reduction of an identification flight -> (:func:`error_traces`, its latent ẑ after every
    step (T, 8)), for flight-level decoding."""
    return error_traces(flight), flight.latent


def id_log_traces(flight: Flight) -> tuple[ErrorTrace, jax.Array, Frame]:
    """:func:`id_traces` and the flight's frame (T, ...), whose log the log-grounded posterior reads
    (:func:`mjxsysid.rollout.flight.flight_log`)."""
    return error_traces(flight), flight.latent, flight.frame


def record_times(steps: int, dt: float) -> np.ndarray:
    """Times (T',) s of the recorded error samples (the time after each kept step)."""
    return (np.arange(steps)[RECORD_EVERY - 1::RECORD_EVERY] + 1) * dt


def hover_reference(n: int, *, pos=(0.0, 0.0, 1.0)) -> Lemniscate:
    """n hover references as size-0 lemniscates (leaves (n, ...))."""
    return stack_refs([Lemniscate.make(size=(0.0, 0.0, 0.0), center=pos)], n)


def stack_refs(refs, n: int | None = None):
    """Stack references (leaves (...)) into one batch; with one reference and n, repeat it."""
    if n is not None and len(refs) == 1:
        return jax.tree.map(lambda a: np.broadcast_to(np.asarray(a), (n,) + np.shape(a)).copy(), refs[0])
    return jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *refs)


def fly_traces(policy, theta, refs, dist, keys, steps: int, *, chunk: int = 16384, sim=None,
               gains="baseline", log=None, pad_to: int | None = None, reduce=error_traces) -> ErrorTrace:
    """Fly N rollouts with a frozen latent policy (a :class:`~mjxsysid.policy.interface.PolicyRef`
    or name) under the ``gains`` cascade and keep their error traces.

    theta (N, 19); refs, dist: reference and :class:`Disturbance` pytrees with (N, ...) leaves
    (numpy); keys (N, 2) PRNG keys (rows with equal keys see equal disturbance realisations);
    flown in chunks of ``min(chunk, N)`` (the last one padded), so one compile serves all;
    ``pad_to``: use exactly this chunk size instead (to share a compile with another call).
    Returns :class:`ErrorTrace` of numpy arrays with leading axis N (or what another module-level
    ``reduce`` of a Flight returns, e.g. :func:`id_traces`).
    """
    theta = np.asarray(theta, np.float32)
    keys = np.asarray(keys)
    n = len(theta)
    if n == 0:
        raise ValueError("fly_traces: no rollouts")
    if keys.shape != (n, 2):
        raise ValueError(f"fly_traces: keys must have shape ({n}, 2); got {keys.shape}")
    b = int(pad_to) if pad_to else int(min(chunk, n))
    sim = sim or Quadrotor()
    low = resolve_policy(policy).batched(b)
    high = broadcast(Cascade.make(gains), b)
    outs = []
    t0 = time.time()
    for start in range(0, n, b):
        idx = np.minimum(np.arange(start, start + b), n - 1)
        take = lambda tree: jax.tree.map(lambda a: jnp.asarray(np.asarray(a)[idx]), tree)
        tr = fly_batch(sim, theta[idx], low, high, take(refs), take(dist), jnp.asarray(keys[idx]), steps,
                       reduce=reduce)
        valid = min(b, n - start)
        outs.append(jax.tree.map(lambda a: np.asarray(a)[:valid], tr))
        if log:
            done = start + valid
            log(f"  {done}/{n} rollouts, {done * steps / (time.time() - t0) / 1e3:.0f} k steps/s (compile included)")
    return jax.tree.map(lambda *a: np.concatenate(a), *outs)


def perturbed(theta, key, n: int, spread: float = 0.2) -> np.ndarray:
    """n uniform perturbations θ ⊙ U(1 − spread, 1 + spread) per entry, projected to valid θ.
    θ (V, 19) -> (V, n, 19)."""
    theta = np.asarray(theta, np.float32)
    u = np.asarray(jax.random.uniform(key, (len(theta), n, P.N_PARAMS), minval=1 - spread, maxval=1 + spread))
    return P.project_valid(theta[:, None] * u)[0]


def dist_rows(force, sigma, onset: float, n: int) -> Disturbance:
    """n Disturbance rows: force (n, 3) N from ``onset`` s on, sigma (n, 3) N (numpy leaves)."""
    d = Disturbance.make()
    return d.replace(step_force=np.asarray(force, np.float32).reshape(n, 3),
                     step_time=np.full(n, onset, np.float32),
                     sigma=np.asarray(sigma, np.float32).reshape(n, 3),
                     torque=np.zeros((n, 3), np.float32),
                     payload_mass=np.zeros(n, np.float32), payload_pos=np.zeros((n, 3), np.float32),
                     payload_time=np.full(n, np.inf, np.float32))


def robustness_study(theta_true, decoder, policy, cfg: RobustnessConfig, key, *, sim=None, log=print) -> dict:
    """Run the whole protocol on true vehicles θ* (V, 19).

    decoder: the policy's sequence decoder (:class:`~mjxsysid.cfm.sequence.SequenceDecoder`) for
    ``cfg.window='flight'``, its single-latent CFM (:class:`~mjxsysid.cfm.sample.Decoder`) for
    'instant'. Returns
    a dict: 'times' (T',) s; 'zhat' (V, 8); 'id_failed' (V,); 'scale' (V,); 'step': list over
    vehicles of lists over forces of {'true' (2, T'), 'decoded' (2, S, T'), 'pm20' (2, S, T'),
    'failed': {...}} (axis 0: lateral, vertical); 'mc': list over vehicles of lists over σ of
    {'true' (2, n, T'), 'decoded' (2, n, k, T'), 'pm20' (2, n, k, T'), 'failed': {...}}.
    """
    theta_true = P.validate_theta(np.asarray(theta_true, np.float32).reshape(-1, P.N_PARAMS), what="true vehicles")
    check_decoder_window(decoder, cfg.window, "RobustnessConfig.window")
    v_n = len(theta_true)
    sim = sim or Quadrotor()
    dt = sim.config.dt
    steps = int(round(cfg.duration / dt))
    k_id, k_dec, k_pert, k_step, k_mc = jax.random.split(key, 5)
    scale = (theta_true[:, P.MASS] / P.PAPER_HARDWARE[P.MASS]) if cfg.scale_forces_by_mass else np.ones(v_n)

    n_mc = cfg.mc_rollouts * cfg.mc_models
    n_rows = v_n * (len(cfg.forces) * (1 + cfg.n_decoded + cfg.n_perturbed)
                   + len(cfg.sigmas) * cfg.mc_rollouts * (1 + 2 * cfg.mc_models))
    batch = int(min(cfg.chunk, n_rows))  # every call below uses this batch size: one compile

    # 1. identification flights -> ẑ
    size = cfg.id_size if cfg.id_reference == "lemniscate" else (0.0, 0.0, 0.0)
    id_ref = stack_refs([Lemniscate.make(period=cfg.id_period, size=size)], v_n)
    id_keys = np.asarray(jax.random.split(k_id, v_n))
    log(f"identification flights ({v_n} vehicles, {cfg.id_reference}, {cfg.duration:g} s)")
    id_dist = dist_rows(np.zeros((v_n, 3)), np.zeros((v_n, 3)), cfg.onset, v_n)
    grounded = cfg.posterior != "decoded"      # the log-grounded posterior reads the flights' logs
    if cfg.window == "flight" or grounded:   # every ẑ (and the frames): their own compile, V rollouts
        idt, traj, *frame = fly_traces(policy, theta_true, id_ref, id_dist, id_keys, steps, sim=sim,
                                       reduce=id_log_traces if grounded else id_traces)
        idx = decode_indices((np.arange(steps) + 1) * dt, cfg.id_rate)[-decoder.max_len:]
        cond = traj[:, idx] if cfg.window == "flight" else idt.latent   # (V, K, 8): ẑ at id_rate Hz, or (V, 8)
    else:                         # the last ẑ only: shares the test rollouts' compile
        idt = fly_traces(policy, theta_true, id_ref, id_dist, id_keys, steps, pad_to=batch, sim=sim)
        cond = idt.latent                                           # (V, 8)
    zhat = idt.latent

    # 2. decoded models (fresh samples for every Monte-Carlo seed) and ±p perturbations
    n_s = cfg.n_decoded + n_mc
    n_p = cfg.n_perturbed + n_mc
    log(f"decoding {n_s} models per vehicle" + (f" (flight-level, {cond.shape[1]} latents)" if cond.ndim == 3 else ""))
    dec = P.project_valid(np.asarray(decoder.sample_theta(cond, k_dec, n_s, steps=cfg.sample_steps)))[0]
    dec = dec.reshape(v_n, n_s, P.N_PARAMS)
    if grounded:
        log(f"log-grounded posterior of each identification flight ({n_s} draws, the decoded models its proposal)")
        dec = np.stack([P.project_valid(posterior_draws(cfg.posterior, dec[v], flight_log(frame[0], v),
                                                        mass_kg=float(theta_true[v, P.MASS]), seed=v))[0]
                        for v in range(v_n)])
    pert = perturbed(theta_true, k_pert, n_p, cfg.perturbation)

    # 3. the rollout table
    th_rows, f_rows, s_rows, key_rows, groups = [], [], [], [], {"step": [], "mc": []}
    count = 0

    def add(theta, force, sigma, key):
        nonlocal count
        m = len(theta)
        th_rows.append(theta)
        f_rows.append(np.broadcast_to(force, (m, 3)))
        s_rows.append(np.broadcast_to(sigma, (m, 3)))
        key_rows.append(np.broadcast_to(key, (m,) + np.shape(key)) if np.ndim(key) == 1 else key)
        count += m
        return np.arange(count - m, count)

    for v in range(v_n):
        per_f = []
        for fi, force in enumerate(cfg.forces):
            f = np.asarray(force, np.float32) * scale[v]
            k = np.asarray(jax.random.fold_in(jax.random.fold_in(k_step, v), fi))
            z3 = np.zeros(3, np.float32)
            per_f.append({"true": add(theta_true[v:v + 1], f, z3, k)[0],
                          "decoded": add(dec[v, :cfg.n_decoded], f, z3, k),
                          "pm20": add(pert[v, :cfg.n_perturbed], f, z3, k)})
        groups["step"].append(per_f)
        per_s = []
        for si, sigma in enumerate(cfg.sigmas):
            s3 = np.full(3, sigma * scale[v], np.float32)
            z3 = np.zeros(3, np.float32)
            seeds = np.asarray(jax.random.split(jax.random.fold_in(jax.random.fold_in(k_mc, v), si), cfg.mc_rollouts))
            rep = np.repeat(seeds, cfg.mc_models, 0)  # seed i for its k models
            j = slice(cfg.n_decoded, None)
            per_s.append({"true": add(theta_true[[v] * cfg.mc_rollouts], z3, s3, seeds),
                          "decoded": add(dec[v, j], z3, s3, rep).reshape(cfg.mc_rollouts, cfg.mc_models),
                          "pm20": add(pert[v, cfg.n_perturbed:], z3, s3, rep).reshape(cfg.mc_rollouts, cfg.mc_models)})
        groups["mc"].append(per_s)

    theta = np.concatenate(th_rows)
    dist = dist_rows(np.concatenate(f_rows), np.concatenate(s_rows), cfg.onset, count)
    keys = np.concatenate(key_rows)
    assert len(theta) == count == n_rows
    log(f"flying {count} rollouts of {steps} steps ({count * steps / 1e6:.1f} M steps)")
    tr = fly_traces(policy, theta, hover_reference(count), dist, keys, steps, pad_to=batch, sim=sim, log=log)
    both = np.stack([tr.lateral, tr.vertical])  # (2, N, T')

    def pick(g):
        return {k: both[:, idx] for k, idx in g.items()} | {
            "failed": {k: tr.failed[idx] for k, idx in g.items()}}

    return {"times": record_times(steps, dt), "onset": cfg.onset, "zhat": zhat, "id_failed": idt.failed,
            "scale": scale, "theta_true": theta_true,
            "step": [[pick(g) for g in per_f] for per_f in groups["step"]],
            "mc": [[pick(g) for g in per_s] for per_s in groups["mc"]]}


AXES = ("lateral", "vertical")


def step_stats(g: dict, times, onset: float) -> dict:
    """Statistics of one step test (a :func:`robustness_study` 'step' entry), from ``onset`` on:
    per axis, the fraction of time the true error lies inside the decoded (and ±p) 5–95 %
    envelope, the mean envelope widths (m) and their ratio decoded / ±p, peak errors."""
    w = np.asarray(times) >= onset - 1e-9
    out = {}
    for a, name in enumerate(AXES):
        t, d, p = g["true"][a][w], g["decoded"][a][:, w], g["pm20"][a][:, w]
        fi_d, w_d = envelope_stats(t, d)
        fi_p, w_p = envelope_stats(t, p)
        out[name] = {"inside_decoded": fi_d, "inside_pm20": fi_p, "width_decoded_m": w_d, "width_pm20_m": w_p,
                     "width_ratio": w_d / w_p if w_p > 0 else float("nan"),
                     "true_peak_m": float(t.max()), "decoded_median_peak_m": float(np.median(d.max(1))),
                     "pm20_median_peak_m": float(np.median(p.max(1)))}
    out["failed"] = {"true": bool(g["failed"]["true"]), "decoded": float(np.mean(g["failed"]["decoded"])),
                     "pm20": float(np.mean(g["failed"]["pm20"]))}
    return out


def mc_stats(g: dict, times, onset: float) -> dict:
    """Statistics of one Monte-Carlo level (a :func:`robustness_study` 'mc' entry), from
    ``onset`` on, per axis:

    - ``inside_decoded_per_seed``: mean over seeds of the fraction of time the true trace lies
      in the 5–95 % envelope of the models flown with its own noise seed (and ``_pm20``);
    - ``coverage_decoded``: fraction of all true (seed, time) points inside the decoded
      population envelope (0.90 if the two distributions agree);
    - ``width_ratio_decoded`` / ``width_ratio_pm20``: mean population envelope width over the
      true one (1 = same spread);
    - ``energy_distance_decoded_m`` / ``_pm20_m``: energy distance of the final-error
      distributions to the true one; ``final_mean_*_m``: their means.
    """
    w = np.asarray(times) >= onset - 1e-9
    out = {}
    for a, name in enumerate(AXES):
        t, d, p = g["true"][a][:, w], g["decoded"][a][:, :, w], g["pm20"][a][:, :, w]
        n, k, _ = d.shape
        per_d = float(np.mean([envelope_stats(t[i], d[i])[0] for i in range(n)]))
        per_p = float(np.mean([envelope_stats(t[i], p[i])[0] for i in range(n)]))
        lo_t, hi_t = envelope(t)
        lo_d, hi_d = envelope(d.reshape(n * k, -1))
        lo_p, hi_p = envelope(p.reshape(n * k, -1))
        wt = float(np.mean(hi_t - lo_t))
        out[name] = {
            "inside_decoded_per_seed": per_d, "inside_pm20_per_seed": per_p,
            "coverage_decoded": float(np.mean((t >= lo_d) & (t <= hi_d))),
            "coverage_pm20": float(np.mean((t >= lo_p) & (t <= hi_p))),
            "width_true_m": wt,
            "width_ratio_decoded": float(np.mean(hi_d - lo_d)) / wt if wt > 0 else float("nan"),
            "width_ratio_pm20": float(np.mean(hi_p - lo_p)) / wt if wt > 0 else float("nan"),
            "energy_distance_decoded_m": energy_distance(d[:, :, -1].ravel(), t[:, -1]),
            "energy_distance_pm20_m": energy_distance(p[:, :, -1].ravel(), t[:, -1]),
            "final_mean_true_m": float(t[:, -1].mean()), "final_mean_decoded_m": float(d[:, :, -1].mean()),
            "final_mean_pm20_m": float(p[:, :, -1].mean())}
    out["failed"] = {k: float(np.mean(v)) for k, v in g["failed"].items()}
    return out
