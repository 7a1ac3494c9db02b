"""Online predictive tuning of the high-level gains on an ensemble of models (paper §V-A).

Every ``1/rate`` s of a flight the tuner

1. draws K models θ_1..θ_K: from the decoder p(θ | ẑ) at the policy's current latent (``cfm``),
   from the vehicle's own nominal system with independent ±20 % perturbations (``nominal_cem``,
   the paper's ablation: the vehicle's θ with its motor time constant at the nominal value,
   :func:`nominal_theta`) or K copies of the true θ (``oracle_cem``, an upper reference), all
   projected to valid θ; or (``log_cem``) from a fixed per-vehicle ensemble given with the flight — the
   draws of the log-grounded posterior of an earlier identification flight (:mod:`mjxsysid.identify`):
   the tuner given a log;
2. runs K × N predictive rollouts from the current state, each model flown by the *frozen*
   policy (its current history and latent carried over) under one of N candidate gain vectors
   of the cascade, over a horizon H of the upcoming reference, without disturbances, in the
   deterministic rigid-body twin of the simulator (:mod:`mjxsysid.sim.rigid`: the same
   equations and integrator as the MJX simulator without MuJoCo's generic machinery). The
   rotor speeds are not observed: each model starts its rollouts from the rotor speeds *its
   own* motor lag (τ_m, Ω_max) gives the motor commands the controller sent over the last
   ``rotor_window`` s (:func:`estimate_rotor_speed`; ``TunerConfig.rotor_state``);
3. scores each candidate by the ensemble mean of :func:`rollout_cost` (position RMSE + motor
   saturation + failure, the paper's cost; a heading term is an option, off by default) and runs CEM (:mod:`mjxsysid.tune.cem`), warm-started
   from the last solution; the mean of the final distribution (``apply``) is applied until the
   next update — with ``protect`` > 0 only when that share of the K models predicts it better
   than the gains in use (else those stay).

:func:`tuner_update` is one pure update for one vehicle; :class:`OnlineTuner` jits it once,
vmapped over the vehicle batch (K and N are vmapped inside), and :func:`fly_tuned` flies a
batch with the tuner in the loop. Fixed gains (``naive``, ``baseline``) fly through the same
loop without updates, so every method sees identical physics, noise and disturbances.
"""
from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.sample import _sample
from mjxsysid.control.high_level import Cascade
from mjxsysid.control.high_level import gains as gain_vector
from mjxsysid.rollout.harness import Disturbance, Flight, LoopCarry, low_level_axes, metrics, run_loop, start_loop
from mjxsysid.sim.quadrotor import Quadrotor
from mjxsysid.sim.rigid import RigidSim, from_sim_state
from mjxsysid.tune.cem import CEMConfig, CEMState, cem_init, cem_minimize, cem_warm, mean_gains
from mjxsysid.tune.rotor_state import ROTOR_STATES, CommandHistory, empty_history, push_history, start_rotor_speed

METHODS = ("naive", "baseline", "cfm", "nominal_cem", "oracle_cem", "log_cem")
"""Fixed presets and the four CEM variants (model sources)."""
CEM_METHODS = ("cfm", "nominal_cem", "oracle_cem", "log_cem")
METHOD_LABELS = {"naive": "Naive", "baseline": "Baseline", "cfm": "CFM-tuned",
                 "nominal_cem": "Nominal+CEM", "oracle_cem": "Oracle-CEM", "log_cem": "Log+CEM"}


@dataclasses.dataclass(frozen=True)
class CostWeights:
    """Predictive cost = pos RMSE (m) + heading · heading RMSE (rad) + saturation · fraction of
    motor commands at 0 or 1 + failure · [the rollout failed]. A rollout fails when it diverges,
    hits the ground or strays ``fail_dist`` m from the reference (RMSEs count the steps before).

    ``heading`` is 0 by default: the paper's cost penalises position error, motor saturation and
    failure only. :data:`HEADING_COST` (0.1) is the variant with
    a heading term."""
    heading: float = 0.0
    saturation: float = 0.5
    failure: float = 5.0
    fail_dist: float = 1.0


HEADING_COST = 0.1
"""The heading weight of the cost variant with a heading term (``--variant heading_cost``)."""

NOMINAL_TAU_M = float(np.mean(P.DEFAULT_PRIOR.motor_time_constant))
"""The nominal motor time constant (s) of ``nominal_cem``: the mid-point of the policy's training
range τ_m ∈ [0.02, 0.04] s (the paper's 'nominal τ_m'), whatever the vehicle's true τ_m."""


def nominal_theta(theta):
    """A vehicle's nominal system: its own θ (..., 19) with the motor time constant at
    :data:`NOMINAL_TAU_M` (the nominal actuators the slow-actuator experiment departs from)."""
    return jnp.asarray(theta).at[..., P.TAU_M].set(NOMINAL_TAU_M)


@dataclasses.dataclass(frozen=True)
class TunerConfig:
    """Settings of the online tuner (static: a change re-traces).

    models: K models per update. horizon: predictive horizon H (s). rate: updates per second.
    warmup: no update before this time (s): the policy's history fills first (0.2 s).
    cem: :class:`~mjxsysid.tune.cem.CEMConfig` (N = ``cem.candidates``). weights: the cost.
    perturbation: half-width of the uniform relative perturbation of ``nominal_cem`` (around
    each vehicle's :func:`nominal_theta`).
    decoder_steps: Euler steps of the CFM sampler. initial: gains before the first update
    (and the first CEM mean): a preset name. unroll: control steps per iteration of the
    predictive rollouts' compiled loop (a speed knob for accelerators; results are the same).
    rotor_state: where each model's rollouts start their rotors (:data:`ROTOR_STATES`):
    'estimate' (default) runs each model's own motor lag over the commands of the last
    ``rotor_window`` s (what hardware can do); 'steady' the model's steady state for the last
    command (ignores the motor lag of the commands before it); 'true' the simulator's hidden rotor speeds (a
    diagnostic only: hardware cannot see them). rotor_window: s of command history (several
    τ_m of the slowest prior: 0.6 s forgets a wrong start of a 0.12 s motor to e^-5).
    apply: 'mean' (the final CEM mean, the paper's) or 'best' (the best candidate of the last
    iteration). protect: 0 (off) or the share of the K models in (0, 1] that must predict the
    new gains better than the ones in use for the tuner to switch.
    """
    models: int = 16
    horizon: float = 0.5
    rate: float = 10.0
    warmup: float = 0.2
    cem: CEMConfig = CEMConfig()
    weights: CostWeights = CostWeights()
    perturbation: float = 0.2
    decoder_steps: int = 50
    initial: str = "naive"
    unroll: int = 1
    rotor_state: str = "estimate"
    rotor_window: float = 0.6
    apply: str = "mean"
    protect: float = 0.0

    def __post_init__(self):
        if int(self.models) != self.models or self.models < 1:
            raise ValueError(f"tuner models (K) must be an integer >= 1, got {self.models}")
        if not (math.isfinite(self.horizon) and self.horizon > 0):
            raise ValueError(f"tuner horizon must be > 0 s, got {self.horizon}")
        if not (math.isfinite(self.rate) and self.rate > 0):
            raise ValueError(f"tuner rate must be > 0 Hz, got {self.rate}")
        if not self.warmup >= 0:
            raise ValueError(f"tuner warmup must be >= 0 s, got {self.warmup}")
        if not 0 <= self.perturbation < 1:
            raise ValueError(f"perturbation must be in [0, 1), got {self.perturbation}")
        gain_vector(self.initial)  # a known preset
        if int(self.unroll) != self.unroll or self.unroll < 1:
            raise ValueError(f"tuner unroll must be an integer >= 1, got {self.unroll}")
        if self.rotor_state not in ROTOR_STATES:
            raise ValueError(f"tuner rotor_state must be one of {ROTOR_STATES}, got {self.rotor_state!r}")
        if not (math.isfinite(self.rotor_window) and self.rotor_window > 0):
            raise ValueError(f"tuner rotor_window must be > 0 s, got {self.rotor_window}")
        if self.apply not in ("mean", "best"):
            raise ValueError(f"tuner apply must be 'mean' or 'best', got {self.apply!r}")
        if not 0.0 <= self.protect <= 1.0:
            raise ValueError(f"tuner protect must be in [0, 1] (0: off), got {self.protect}")

    def steps(self, dt: float) -> tuple[int, int]:
        """(control steps between updates, control steps of the horizon)."""
        return max(1, int(round(1.0 / (self.rate * dt)))), max(1, int(round(self.horizon / dt)))

    def window(self, dt: float) -> int:
        """Control steps of motor-command history the rotor estimate runs over."""
        return max(1, int(round(self.rotor_window / dt)))


def rollout_cost(flight: Flight, w: CostWeights) -> jax.Array:
    """Cost () of one predictive rollout (leaves (H, ...)); see :class:`CostWeights`."""
    m = metrics(flight, box=w.fail_dist)
    return (m["pos_rmse_m"] + w.heading * jnp.deg2rad(m["heading_rmse_deg"])
            + w.saturation * m["saturation_frac"] + w.failure * m["failed"].astype(jnp.float32))


def predict(sim, theta, low, gains, max_rate, ref, carry: LoopCarry, rotor_speed, start,
            steps: int, unroll: int = 1) -> Flight:
    """One predictive rollout: model θ (19,) flown by ``low`` (its carry in ``carry``) under
    the cascade with ``gains`` (8,) for ``steps`` steps from the current state of the (MJX) loop
    ``carry``, the first step having global index ``start``, in the deterministic rigid-body twin
    of the simulator (:class:`~mjxsysid.sim.rigid.RigidSim`; ``sim`` gives its config). The
    rotors start at ``rotor_speed`` (4,) rad/s (:func:`start_rotor_speed`: the rotor speed
    itself is not observed); the IMU latency buffer, the cascade's integral and the policy's
    history carry over from ``carry``; no disturbance."""
    twin = sim if isinstance(sim, RigidSim) else RigidSim(sim.config)
    s = from_sim_state(carry.sim, rotor_speed=rotor_speed)
    high = Cascade(gains, max_rate)
    _, fl = run_loop(twin, theta, low, high, ref, carry._replace(sim=s), jnp.zeros((steps, 3)), start, steps,
                     unroll=unroll)
    return fl


class DecoderArgs(NamedTuple):
    """What the ``cfm`` model source needs inside jit: the CFM's params and normaliser
    (pytrees) — its static config travels separately."""
    params: object
    normalizer: object


def _model_sources(dec_cfg, cfg: TunerConfig) -> tuple[tuple[str, ...], list]:
    """The model sources compiled into an update (those without a decoder when there is none):
    (method names, branch functions ``f(key, theta_true (19,), ensemble (M, 19), zhat (8,) | None, dec) ->
    (K, 19)``)."""
    k = cfg.models

    def oracle(key, theta_true, ensemble, zhat, dec):
        return jnp.broadcast_to(theta_true, (k, P.N_PARAMS))

    def nominal(key, theta_true, ensemble, zhat, dec):
        u = jax.random.uniform(key, (k, P.N_PARAMS), minval=1 - cfg.perturbation, maxval=1 + cfg.perturbation)
        return nominal_theta(theta_true) * u

    def log(key, theta_true, ensemble, zhat, dec):   # K of the ensemble's M draws, with replacement
        return ensemble[jax.random.randint(key, (k,), 0, ensemble.shape[0])]

    def cfm(key, theta_true, ensemble, zhat, dec):
        theta0 = jax.random.normal(key, (1, k, dec_cfg.theta_dim), jnp.float32)   # as cfm.sample draws it
        v = _sample(dec.params, dec_cfg, theta0, zhat[None], k, cfg.decoder_steps, "euler")[0]
        return dec.normalizer.denormalize(dec.normalizer.from_flow(v))

    if dec_cfg is None:
        return ("oracle_cem", "nominal_cem", "log_cem"), [oracle, nominal, log]
    return ("oracle_cem", "nominal_cem", "log_cem", "cfm"), [oracle, nominal, log, cfm]


def draw_models(method: str, key, theta_true, zhat, dec: DecoderArgs | None, dec_cfg, cfg: TunerConfig,
                ensemble=None):
    """K models (K, 19) for one update (see the module doc), projected to valid θ. ``ensemble``
    (M, 19): the draws ``log_cem`` takes its models from (default: θ itself, M = 1)."""
    names, fns = _model_sources(dec_cfg, cfg)
    if method not in names:
        raise ValueError(f"no models for method {method!r} here; available: {names}"
                         + ("" if dec_cfg is not None else " (method 'cfm' needs a decoder)"))
    if ensemble is None:
        ensemble = jnp.zeros((1, P.N_PARAMS), jnp.float32) if theta_true is None else jnp.asarray(theta_true)[None]
    return P.project_valid_jax(fns[names.index(method)](key, theta_true, ensemble, zhat, dec))


def tuner_update(sim: Quadrotor, low, method, cfg: TunerConfig, dec: DecoderArgs | None, dec_cfg,
                 theta_true, ensemble, ref, carry: LoopCarry, hist: CommandHistory, incumbent, max_rate, start,
                 state: CEMState, key):
    """One tuner update for one vehicle. ``method``: a CEM method name, or its index in the
    model sources of :func:`_model_sources` as an (unbatched) traced int — then one compiled
    update serves every method (``lax.switch`` runs only the chosen source). ``hist``: the
    motor commands sent (:class:`CommandHistory`); ``incumbent`` (8,): the gains in use;
    ``ensemble`` (M, 19): the draws of ``log_cem``.
    Returns (new CEM state, gains to apply (8,), info): info = {'cost': ensemble-mean cost of
    every candidate of the last iteration (N,), 'models_twr': the K models' thrust-to-weight
    (K,), 'switched': () bool, whether the applied gains are the new ones (always, unless
    ``cfg.protect``)}."""
    _, horizon = cfg.steps(sim.config.dt)
    k_models, k_cem = jax.random.split(key)
    zhat = low.latent(carry.low) if hasattr(low, "latent") else None
    if isinstance(method, str):
        thetas = draw_models(method, k_models, theta_true, zhat, dec, dec_cfg, cfg, ensemble)
    else:
        _, fns = _model_sources(dec_cfg, cfg)
        thetas = P.project_valid_jax(jax.lax.switch(method, fns, k_models, theta_true, ensemble, zhat, dec))
    speeds = jax.vmap(lambda th: start_rotor_speed(cfg.rotor_state, th, hist, carry, sim.config))(thetas)  # (K, 4)

    def cost_one(theta, speed, g):
        return rollout_cost(predict(sim, theta, low, g, max_rate, ref, carry, speed, start, horizon,
                                     cfg.unroll),
                            cfg.weights)

    def costs_per_model(gains):   # (N, 8) -> (K, N)
        return jax.vmap(lambda th, sp: jax.vmap(lambda g: cost_one(th, sp, g))(gains))(thetas, speeds)

    state, hist_c, cands = cem_minimize(lambda g, _k: costs_per_model(g).mean(0), state, k_cem, cfg.cem,
                                        candidates=True)
    new = mean_gains(state) if cfg.apply == "mean" else cands[-1][jnp.argmin(jnp.where(
        jnp.isfinite(hist_c[-1]), hist_c[-1], jnp.inf))]
    switched = jnp.array(True)
    if cfg.protect > 0:
        c = costs_per_model(jnp.stack([new, incumbent]))      # (K, 2)
        switched = jnp.mean((c[:, 0] < c[:, 1]).astype(jnp.float32)) >= cfg.protect
        new = jnp.where(switched, new, incumbent)
    return state, new, {"cost": hist_c[-1], "models_twr": P.thrust_to_weight(thetas), "switched": switched}


class TunedFlight(NamedTuple):
    """A flight with the tuner in the loop: flight (B, T, ...), gains (B, U, 8) applied in each
    of the U segments, update_times (U,) s (start of each segment), predicted (B, U): the
    ensemble-mean predicted cost of the applied mean (NaN where no update ran)."""
    flight: Flight
    gains: np.ndarray
    update_times: np.ndarray
    predicted: np.ndarray


@functools.lru_cache(maxsize=16)
def _advance(sim: Quadrotor, steps: int, low_axes_def, low_axes_leaves):
    low_axes = jax.tree_util.tree_unflatten(low_axes_def, low_axes_leaves)

    def one(theta, low, gains, max_rate, ref, carry, forces, start):
        return run_loop(sim, theta, low, Cascade(gains, max_rate), ref, carry, forces, start, steps)

    return jax.jit(jax.vmap(one, in_axes=(0, low_axes, 0, None, 0, 0, 0, None)))


@functools.lru_cache(maxsize=16)
def _start(sim: Quadrotor, low_axes_def, low_axes_leaves):
    low_axes = jax.tree_util.tree_unflatten(low_axes_def, low_axes_leaves)

    def one(theta, low, ref, keys):
        return start_loop(sim, theta, low, Cascade.make("naive"), ref, (keys[0], keys[1]))

    return jax.jit(jax.vmap(one, in_axes=(0, low_axes, 0, 0)))


@functools.lru_cache(maxsize=16)
def _update(sim: Quadrotor, cfg: TunerConfig, dec_cfg, low_axes_def, low_axes_leaves):
    low_axes = jax.tree_util.tree_unflatten(low_axes_def, low_axes_leaves)

    def one(method, low, dec, theta_true, ensemble, ref, carry, hist, incumbent, max_rate, start, state, key):
        return tuner_update(sim, low, method, cfg, dec, dec_cfg, theta_true, ensemble, ref, carry, hist, incumbent,
                            max_rate, start, state, key)

    return jax.jit(jax.vmap(one, in_axes=(None, low_axes, None, 0, 0, 0, 0, 0, 0, None, None, 0, 0)))


def _axes(low):
    leaves, treedef = jax.tree_util.tree_flatten(low_level_axes(low), is_leaf=lambda x: x is None)
    return treedef, tuple(leaves)


class OnlineTuner:
    """Jitted, batched tuner updates for one method and config.

    ``update(low, theta_true (B, 19), ref (batched), carry (batched), hist (batched
    :class:`CommandHistory`), incumbent (B, 8), start, state (batched CEMState), key, ensemble=None
    (B, M, 19))`` -> (state, gains (B, 8), info). The decoder (a
    :class:`~mjxsysid.cfm.sample.Decoder` of kind 'cfm') is needed for ``method='cfm'``; with
    one, every method shares one compiled update (the method is a runtime switch).
    """

    def __init__(self, sim: Quadrotor, method: str, cfg: TunerConfig = TunerConfig(), decoder=None,
                 max_rate: float = 12.0):
        if method not in CEM_METHODS:
            raise ValueError(f"unknown tuner method {method!r}; choose from {CEM_METHODS}")
        if decoder is not None:
            if decoder.kind != "cfm":
                raise ValueError(f"the tuner needs a CFM decoder (kind 'cfm'), got {decoder.kind!r}")
            self.dec, self.dec_cfg = DecoderArgs(decoder.params, decoder.normalizer), decoder.cfg
        elif method == "cfm":
            raise ValueError("method 'cfm' needs a CFM decoder (Decoder of kind 'cfm')")
        else:
            self.dec, self.dec_cfg = None, None
        names, _ = _model_sources(self.dec_cfg, cfg)
        self.index = jnp.int32(names.index(method))
        self.sim, self.method, self.cfg, self.max_rate = sim, method, cfg, jnp.float32(max_rate)

    def init(self, n: int) -> CEMState:
        s = cem_init(gain_vector(self.cfg.initial), self.cfg.cem)
        return jax.tree.map(lambda a: jnp.broadcast_to(a, (n,) + a.shape), s)

    def update(self, low, theta_true, ref, carry, hist: CommandHistory, incumbent, start, state, key,
               ensemble=None):
        fn = _update(self.sim, self.cfg, self.dec_cfg, *_axes(low))
        theta_true = jnp.asarray(theta_true, jnp.float32)
        n = theta_true.shape[0]
        ensemble = theta_true[:, None] if ensemble is None else jnp.asarray(ensemble, jnp.float32)
        return fn(self.index, low, self.dec, theta_true, ensemble, ref, carry, hist,
                  jnp.asarray(incumbent, jnp.float32), self.max_rate, jnp.int32(start), state,
                  jax.random.split(key, n))


def segments(steps: int, seg: int) -> list[tuple[int, int]]:
    """The (first step, length) of each segment a ``steps``-long tuned flight is flown in: ``seg``
    steps each (one tuner update before each), the last one shorter when ``seg`` does not
    divide ``steps``."""
    if steps < 1 or seg < 1:
        raise ValueError(f"steps and segment length must be >= 1, got {steps} and {seg}")
    return [(i0, min(seg, steps - i0)) for i0 in range(0, steps, seg)]


def fly_tuned(sim: Quadrotor, theta, low, ref, disturbance: Disturbance, method: str, key, steps: int, *,
              cfg: TunerConfig = TunerConfig(), decoder=None, max_rate: float = 12.0,
              progress=None, ensemble=None) -> TunedFlight:
    """Fly a batch θ (B, 19) with ``low`` (batched, e.g. ``PolicyRef.batched(B)``) on the
    batched reference ``ref`` under ``disturbance`` (batched) for ``steps`` control steps, the
    gains set by ``method``: a preset ('naive', 'baseline': fixed) or a CEM method updated
    every ``1/cfg.rate`` s after ``cfg.warmup``. The key splits like :func:`~mjxsysid.uses.
    harness.fly` (per vehicle: simulator, disturbance, controller), so every method sees the
    same noise and disturbance realisation for the same key. ``progress``: optional callable
    ``progress(done, total)`` after each segment. ``ensemble`` (B, M, 19): each vehicle's models for
    ``log_cem`` (e.g. draws of the log-grounded posterior of an identification flight); required by it."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
    theta = jnp.asarray(P.validate_theta(P.as_batch(theta)), jnp.float32)
    b = theta.shape[0]
    dt = sim.config.dt
    seg, horizon = cfg.steps(dt)
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    if method == "log_cem":
        if ensemble is None:
            raise ValueError("method 'log_cem' needs an ensemble (B, M, 19) of each vehicle's models")
        ensemble = jnp.asarray(P.validate_theta(np.asarray(ensemble, np.float32).reshape(-1, P.N_PARAMS)),
                               jnp.float32).reshape(np.shape(ensemble))
        if ensemble.ndim != 3 or ensemble.shape[0] != b:
            raise ValueError(f"ensemble must be (B={b}, M, {P.N_PARAMS}), got {tuple(ensemble.shape)}")
    else:
        ensemble = None
    if method in CEM_METHODS and horizon > steps:
        raise ValueError(f"tuner horizon {cfg.horizon} s is longer than the flight ({steps * dt:g} s)")
    keys = jax.vmap(lambda k: jnp.stack(jax.random.split(k, 3)))(jax.random.split(key, b))  # (B, 3, 2)
    k_sim, k_dist, k_low = keys[:, 0], keys[:, 1], keys[:, 2]
    theta_fly = theta.at[:, P.TAU_EXT].add(disturbance.torque)
    forces = jax.vmap(lambda d, k: d.forces(k, steps, dt))(disturbance, k_dist)   # (B, steps, 3)
    carry = _start(sim, *_axes(low))(theta_fly, low, ref, jax.vmap(lambda a, c: jnp.stack([a, c]))(k_sim, k_low))
    tuner = OnlineTuner(sim, method, cfg, decoder, max_rate) if method in CEM_METHODS else None
    state = tuner.init(b) if tuner else None
    gains = jnp.broadcast_to(gain_vector(cfg.initial if tuner else method), (b, 8))
    hist = empty_history(cfg.window(dt), b)
    k_tune = jax.random.fold_in(key, 7919)
    chunks, gain_log, times, pred = [], [], [], []
    spans = segments(steps, seg)
    n_seg = len(spans)
    mr = jnp.float32(max_rate)
    updated = False
    for u, (i0, n) in enumerate(spans):
        t = i0 * dt
        cost = np.full(b, np.nan, np.float32)
        if tuner is not None and t >= cfg.warmup - 1e-9:
            state = cem_warm(state, cfg.cem) if updated else state
            updated = True
            state, gains, info = tuner.update(low, theta, ref, carry, hist, gains, i0, state,
                                              jax.random.fold_in(k_tune, u), ensemble)
            # candidate 0 of the last iteration is the mean entering it
            cost = np.asarray(info["cost"][:, 0])
        fn = _advance(sim, n, *_axes(low))
        carry, fl = fn(theta_fly, low, gains, mr, ref, carry, forces[:, i0:i0 + n], jnp.int32(i0))
        if tuner is not None:
            hist = push_history(hist, fl.frame.motor_cmd)
        chunks.append(fl)
        gain_log.append(np.asarray(gains))
        times.append(t)
        pred.append(cost)
        if progress is not None:
            progress(u + 1, n_seg)
    flight = jax.tree.map(lambda *a: np.concatenate([np.asarray(x) for x in a], 1), *chunks)
    return TunedFlight(flight, np.stack(gain_log, 1), np.asarray(times, np.float32), np.stack(pred, 1))


@functools.lru_cache(maxsize=8)
def _predict_batch(sim: Quadrotor, mode: str, steps: int, low_axes_def, low_axes_leaves):
    low_axes = jax.tree_util.tree_unflatten(low_axes_def, low_axes_leaves)

    def one(theta, low, gains, max_rate, ref, carry, hist, start):
        speed = start_rotor_speed(mode, theta, hist, carry, sim.config)
        return predict(sim, theta, low, gains, max_rate, ref, carry, speed, start, steps), speed

    return jax.jit(jax.vmap(one, in_axes=(0, low_axes, 0, None, 0, 0, 0, None)))


def prediction_error(sim: Quadrotor, theta, low, ref, *, gains="baseline", start: int, steps: int,
                     rotor_states=ROTOR_STATES, cfg: TunerConfig = TunerConfig(), key=None,
                     max_rate: float = 12.0) -> dict:
    """How well the tuner's predictions reproduce the flight: fly θ (B, 19) with ``low``
    (batched) under fixed ``gains`` on the batched ``ref`` for ``start`` steps in the simulator
    ``sim``, then continue the flight ``steps`` steps (no disturbance) and predict the same
    steps with the true θ from the loop's state, the rotors started by each of ``rotor_states``
    (over ``cfg``'s command window; the flight is flown in ``cfg``'s update segments).

    Returns {'time' (steps,) s after the start, mode: {'pos_err' (B, steps) m, 'rotor_err' (B,)
    rad/s: max over rotors of |start − the simulator's|}}: the rollout the tuner would score
    against the flight it would get."""
    theta = jnp.asarray(P.validate_theta(P.as_batch(theta)), jnp.float32)
    b = theta.shape[0]
    if start < 1 or steps < 1:
        raise ValueError(f"start and steps must be >= 1, got {start} and {steps}")
    key = jax.random.PRNGKey(0) if key is None else key
    keys = jax.vmap(lambda k: jnp.stack(jax.random.split(k, 2)))(jax.random.split(key, b))
    g = jnp.broadcast_to(gain_vector(gains), (b, 8))
    mr = jnp.float32(max_rate)
    axes = _axes(low)
    carry = _start(sim, *axes)(theta, low, ref, keys)
    hist = empty_history(cfg.window(sim.config.dt), b)
    seg = cfg.steps(sim.config.dt)[0]   # the tuned flight's segments: their compiles are shared

    def fly(carry, i0, n):
        parts = []
        for j0, m in segments(n, seg):
            carry, fl = _advance(sim, m, *axes)(theta, low, g, mr, ref, carry, jnp.zeros((b, m, 3)),
                                                jnp.int32(i0 + j0))
            parts.append(fl)
        return carry, jax.tree.map(lambda *a: jnp.concatenate(a, 1), *parts)

    carry, fl = fly(carry, 0, start)
    hist = push_history(hist, fl.frame.motor_cmd)
    _, real = fly(carry, start, steps)
    out = {"time": sim.config.dt * (1 + np.arange(steps))}
    for mode in rotor_states:
        pred, speed = _predict_batch(sim, mode, steps, *axes)(theta, low, g, mr, ref, carry, hist, jnp.int32(start))
        out[mode] = {"pos_err": np.linalg.norm(np.asarray(pred.frame.pos) - np.asarray(real.frame.pos), axis=-1),
                     "rotor_err": np.abs(np.asarray(speed) - np.asarray(carry.sim.rotor_speed)).max(-1)}
    return out
