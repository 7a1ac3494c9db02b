"""The Python API for the common path (re-exported lazily by ``mjxsysid``)::

    import mjxsysid
    res = mjxsysid.fly(mjxsysid.paper_vehicle(), controller="policy", reference="lemniscate")
    res.metrics["pos_rmse_m"]                     # what `mjxsysid fly` writes to metrics.json
    post = mjxsysid.decode(res, samples=100)      # what `mjxsysid decode` writes
    post["summary"]["thrust_to_weight"]           # {mean, q05, q95, true, inside}
    post = mjxsysid.decode("my_flight.csv")       # a recorded flight log (README: log format)
    mjxsysid.check_log("my_flight.csv")           # its physical plausibility checks alone

Thin wrappers over :func:`mjxsysid.rollout.flight.fly_vehicles`,
:func:`mjxsysid.decoding.decode_posterior` and the vehicle-file readers of
:mod:`mjxsysid.theta`: the same checks, the same numbers as the command line.
"""
from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Mapping

import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
from mjxsysid.logs import checks as _logcheck
from mjxsysid.logs.checks import Finding, LogError
from mjxsysid.logs.csvlog import read_any_log
from mjxsysid.logs.ulog import read_ulog
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.rollout.flight import CONTROLLERS, fly_vehicles, metrics_dict, one_flight, save_flight, seen_imu
from mjxsysid.rollout.harness import metrics_to_host
from mjxsysid.decoding import (check_window, checks_summary, decode_posterior, decoders_prior, flight_checks,
                                     ground_in_log, log_latents, parse_window)

__all__ = ["Finding", "FlightResult", "LogError", "check_log", "decode", "fly", "load_vehicle", "paper_vehicle", "prior_vehicles",
           "read_ulog", "save_vehicle", "to_theta"]

load_vehicle = P.load_vehicle
save_vehicle = P.save_vehicle


def paper_vehicle() -> np.ndarray:
    """The paper's hardware vehicle θ (19,) (``mjxsysid/assets/vehicles/paper_hardware.json``)."""
    return P.paper_hardware()


def prior_vehicles(n: int, prior: str = "default", seed: int = 0) -> np.ndarray:
    """n vehicles θ (n, 19) drawn from a named prior (``default``, ``slow_actuators``, ``xadap``)."""
    import jax
    if int(n) < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    return np.asarray(P.get_prior(prior).sample(jax.random.PRNGKey(seed), int(n)))


def to_theta(v=None) -> np.ndarray:
    """θ from any vehicle description: None (the paper vehicle), a vehicle-file path, a vehicle
    dict (vehicle-file keys), or θ (19,) / (B, 19). Files and dicts get the full vehicle-file
    checks (keys, types, physics, flyability); arrays :func:`mjxsysid.theta.validate_theta`."""
    if v is None:
        return P.paper_hardware()
    if isinstance(v, (str, Path)):
        return P.load_vehicle(v)
    if isinstance(v, Mapping):
        return P.theta_from_dict(v)
    return P.validate_theta(v, what="vehicle")


@dataclasses.dataclass(frozen=True)
class FlightResult:
    """What :func:`fly` returns.

    flight: :class:`~mjxsysid.rollout.harness.Flight` with (B, T, ...) leaves (``latent`` set
    for a policy); metrics: for one vehicle its ``metrics.json`` dict (``pos_rmse_m``,
    ``failed``, …), for several the batch summary (success rate, mean/std/median) with
    ``per_vehicle`` lists; theta (B, 19); duration (s); controller; reference; policy (the
    resolved :class:`~mjxsysid.policy.interface.PolicyRef` or None)."""
    flight: object
    metrics: dict
    theta: np.ndarray
    duration: float
    controller: str
    reference: str
    policy: object = None

    def one(self, index: int = 0):
        """The flight of vehicle ``index`` as host arrays (leaves (T, ...))."""
        return one_flight(self.flight, index)

    def save(self, out, index: int = 0) -> Path:
        """Write ``out/flight.npz`` (vehicle ``index``), ``out/flight.ulg`` and ``out/flight.csv`` (the
        flight as logs) and ``out/metrics.json`` as ``mjxsysid fly``."""
        from mjxsysid.runtime import jsonout
        from mjxsysid.logs.ulog_write import write_flight_logs

        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        save_flight(self.flight, self.theta, out / "flight.npz", index)
        write_flight_logs(one_flight(self.flight, index), out)
        (out / "metrics.json").write_text(jsonout.dumps(self.metrics, indent=2) + "\n")
        return out


def fly(vehicle=None, controller: str = "policy", *, reference: str = "lemniscate", period: float = 10.0,
        duration: float | None = None, policy="mjxsysid", weights=None, gains: str = "baseline",
        force_step=(0.0, 0.0, 0.0), force_step_time: float = 1.0, force_sigma: float = 0.0,
        seed: int = 0) -> FlightResult:
    """Fly one vehicle or a batch (see :func:`to_theta` for what ``vehicle`` may be) under
    ``controller``: ``"policy"`` (the frozen latent policy ``policy``/``weights``: ``"mjxsysid"``
    — the shipped one —, ``"xadap"`` with ``weights``, or a path), ``"oracle"`` (the lag-aware
    K_θ with the true θ), ``"k_theta"`` (the paper's K_θ with the true θ) or ``"nominal"`` (K_θ
    with the paper vehicle's θ), on ``reference`` (``hover``,
    ``lemniscate`` of ``period`` s, ``minsnap``) for ``duration`` s (default one period / 5 s),
    with an optional world-force step and Gaussian force noise. Same as ``mjxsysid fly``."""
    if controller not in CONTROLLERS:
        raise ValueError(f"controller must be one of {CONTROLLERS}, got {controller!r}")
    theta = P.as_batch(to_theta(vehicle))
    ref = None
    if controller == "policy":
        ref = resolve_policy(policy, weights)
    flight, m, dur = fly_vehicles(theta, controller=controller, reference=reference, period=period,
                                  duration=duration, gains=gains, force_step=tuple(force_step),
                                  force_step_time=force_step_time, force_sigma=force_sigma, seed=seed,
                                  policy=ref)
    if len(theta) == 1:
        met = metrics_dict(m, 0)
    else:
        met = dict(metrics_dict(m, None), per_vehicle=metrics_to_host(m))
    return FlightResult(flight, met, np.asarray(theta), float(dur), controller, reference, ref)


def decode(flight_or_log, *, samples: int = 100, rate: float = 10.0, policy=None, weights=None,
           decoders=None, seed: int = 0, truth=None, index: int = 0, allow_mismatch: bool = False,
           window="flight", decoder_only: bool = False, segment=None, rates: str | None = None,
           refine: bool | None = None, shared_maps=None) -> dict:
    """Decode a policy's latent into a distribution of vehicles, as ``mjxsysid decode``.

    ``flight_or_log``: a :class:`FlightResult` of :func:`fly` with ``controller="policy"``
    (vehicle ``index`` of it; its policy and true θ are used) or the path of a flight-log CSV
    (replayed through ``policy``, default the shipped one; ``truth``: optionally the vehicle
    that flew it, anything :func:`to_theta` takes). ẑ is read at ``rate`` Hz after the first
    0.2 s and each decoded into ``samples`` models by the policy's CFM (or that in
    ``decoders``). Returns the arrays of ``decoded.npz`` — times (K,), zhat (K, 8), samples
    (K, S, 19), regression (K, 19), theta_true (19,) (NaN if unknown) — and ``summary``, the
    dict of ``summary.json`` (per parameter and identifiable combination: mean, q05, q95,
    and with a known truth, true and inside).

    ``window`` (as ``mjxsysid decode --window``): ``"flight"`` (default) — the summary is the
    flight-level posterior given every latent so far (10 Hz, the sequence decoder
    ``cfm_seq.npz`` beside the CFM), also returned as samples_window (K, S, 19) with n_window
    (K,); a number of seconds — a sliding window of that length; ``"instant"`` — the
    single-latent CFM alone. Without a sequence decoder it falls back to ``"instant"`` and
    ``summary["_window"]`` says which was used.

    A log (CSV or PX4 ULog ``.ulg``; ``segment`` "t0:t1" as ``--segment``) is grounded in its own
    physics unless ``decoder_only``: the summary's top-level entries are then the log-grounded
    posterior's (:func:`mjxsysid.decoding.ground_in_log`: the log's IMU given its motor
    commands under a physical prior, the decoded samples as its proposal), the decoders' under
    ``summary["_decoder_only"]``, the information gap under ``summary["_log_grounded"]["gap"]``,
    and ``samples_log_grounded`` (S, 19) is returned too; ``rates`` its likelihood's rate term
    (``"windows"``, the default, or ``"innovations"``: docs/identify.md); ``refine=False`` keeps the
    SMC's draws where it falls back to its SMC (default: refined by NUTS). ``shared_maps``: command→speed maps
    other flights of the same vehicle showed ((idle, κ) pairs of :data:`mjxsysid.identify.idlecheck.MAPS`, as
    ``decode --same-vehicle`` passes them; ``summary["_log_grounded"]`` reports them under the motor-map check).

    A log is checked first, as by :func:`check_log`: one that cannot be right raises
    :class:`LogError`; warnings and a flight outside the decoders' training prior are printed
    (stderr) and kept in ``summary["_checks"]``."""
    if rates not in (None, "windows", "innovations"):
        raise ValueError(f"rates must be 'windows' or 'innovations', got {rates!r}")
    for name, given in (("rates", rates), ("refine", refine), ("shared_maps", shared_maps)):
        if given is not None and (decoder_only or not isinstance(flight_or_log, (str, Path))):
            raise ValueError(f"{name} applies to the log-grounded posterior of a log path (not decoder_only)")
    if not rate > 0:
        raise ValueError(f"rate must be > 0 Hz, got {rate}")
    if samples < 2:
        raise ValueError(f"samples must be >= 2, got {samples}")
    window = parse_window(window)
    checks = {}

    def decoders_for(ref):
        cfm, reg = load_decoders(decoders, ref, allow_mismatch=allow_mismatch, warn=print)
        seq = None if window == "instant" else load_sequence_decoder(decoders, ref, echo=print,
                                                                     allow_mismatch=allow_mismatch)
        return cfm, reg, seq

    if isinstance(flight_or_log, FlightResult):
        res = flight_or_log
        if res.controller != "policy":
            raise ValueError(f"decode needs a flight flown by a latent policy (controller='policy'), "
                             f"this one was flown by {res.controller!r}")
        if weights is not None or (policy is not None and resolve_policy(policy) != res.policy):
            raise ValueError("this flight was flown by another policy than the one given; decode it "
                             "with the policy that flew it (leave policy=None)")
        ref = res.policy
        cfm, reg, seq = decoders_for(ref)
        one = res.one(index)
        zhat_t, times = np.asarray(one.latent), np.asarray(one.time)
        th = res.theta[index] if truth is None else to_theta(truth)
        rec = {"imu": seen_imu(one.frame.imu), "motor": one.frame.motor_cmd}
    elif isinstance(flight_or_log, (str, Path)):
        rec = read_any_log(flight_or_log, segment=segment)
        th = None if truth is None else to_theta(truth)
        ref = resolve_policy(policy or "mjxsysid", weights)
        cfm, reg, seq = decoders_for(ref)   # first: the log's IMU noise is judged against their training
        zhat_t, times = log_latents(ref, rec, source=flight_or_log, checks=checks,
                                    imu_limit=_logcheck.imu_noise_limit(cfm, reg, seq))
    else:
        raise ValueError(f"decode takes a FlightResult of mjxsysid.fly or a flight-log path, "
                         f"got {type(flight_or_log).__name__}")
    if th is not None and np.shape(th) != (P.N_PARAMS,):
        raise ValueError(f"truth must be one vehicle, θ ({P.N_PARAMS},); got shape {np.shape(th)}")
    check_window(window, float(times[-1]))
    flight_checks(rec, decoders_prior(seq, cfm), checks)
    for f in checks["findings"]:
        _logcheck.warn(f)
    post = decode_posterior(zhat_t, times, th, decoder=cfm, regression=reg, rate=rate, samples=samples,
                            seed=seed, window=window, seq_decoder=seq)
    post["summary"]["_checks"] = checks_summary(checks)
    if isinstance(flight_or_log, (str, Path)) and not decoder_only:
        ground_in_log(post, post["summary"], rec, th, seed=seed, rates=rates, refine=refine, shared_maps=shared_maps)
    return post


def check_log(log, *, policy=None, weights=None, prior: str | None = "wide_actuators") -> list:
    """The physical plausibility checks of ``mjxsysid decode --log``, alone: a flight-log CSV or
    PX4 ULog (``.ulg``) path (or the dict of arrays :func:`~mjxsysid.logs.csvlog.read_log` returns) -> a list of
    :class:`Finding` (level 'error', 'warning' or 'out_of_prior', the column, the message;
    empty: nothing found). Errors do not raise here. ``policy`` (default the shipped one; None
    with ``prior=None`` skips the replay): the policy's own actions on the logged inputs are
    compared with the logged motor commands; ``prior``: the decoders' training prior the
    log-only vehicle estimates are compared with (None: not compared)."""
    rec = read_any_log(log) if isinstance(log, (str, Path)) else log
    found = _logcheck.check_log(rec)
    if not any(f.level == "error" for f in found):
        ctrl = resolve_policy(policy or "mjxsysid", weights).load()
        if hasattr(ctrl, "replay_actions"):
            z = ctrl.replay(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
            found += _logcheck.check_replay(rec, ctrl, z)
        if prior is not None:
            found += _logcheck.prior_check(rec, prior)
    return found
