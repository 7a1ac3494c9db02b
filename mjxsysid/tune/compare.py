"""Fly the same vehicles under every tuning method and compare (``mjxsysid tune``, the
``tune-*`` experiments): fixed ``naive`` / ``baseline`` gains and the online CEM tuner on the
decoded ensemble (``cfm``), on ±20 % perturbations of each vehicle's nominal system (``nominal_cem``) and on
the true θ (``oracle_cem``). Every method flies the identical noise and disturbance realisation.
"""
from __future__ import annotations

import time

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders
from mjxsysid.control.high_level import GAIN_NAMES
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.runtime.progress import progress
from mjxsysid.rollout.flight import broadcast
from mjxsysid.rollout.harness import Disturbance, batch_metrics, metrics_to_host, summarize
from mjxsysid.sim import Quadrotor, SimConfig
from mjxsysid.tune.tuner import CEM_METHODS, METHOD_LABELS, METHODS, TunerConfig, fly_tuned

RESULT_KEYS = {"naive": "naive", "baseline": "baseline", "cfm": "cfm_tuned", "nominal_cem": "nominal_cem",
               "oracle_cem": "oracle_cem", "log_cem": "log_cem"}
"""method -> key in metrics.json / results.json."""
PER_VEHICLE = ("pos_rmse_m", "max_pos_err_m", "heading_rmse_deg", "saturation_frac", "failed")


def check_methods(methods) -> tuple[str, ...]:
    methods = tuple(methods)
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"unknown method(s) {bad or methods}; choose from {METHODS}")
    return methods


def compare_methods(theta, refs, *, steps: int, methods=None, cfg: TunerConfig = TunerConfig(),
                    policy="mjxsysid", decoder=None, sim: Quadrotor | None = None,
                    disturbance: Disturbance | None = None, seed: int = 0, log=None,
                    progress: bool = True, ensemble=None) -> dict:
    """Fly θ (B, 19) on the batched references ``refs`` for ``steps`` control steps under each
    method (default: every method, 'log_cem' only with an ``ensemble``). ``policy``: a
    name/path/:class:`~mjxsysid.policy.interface.PolicyRef` of the frozen low-level policy;
    ``decoder``: its CFM (default: the policy's shipped one; needed for 'cfm'); ``ensemble``
    (B, M, 19): each vehicle's models for 'log_cem' (the tuner given a log).

    Returns {method: {'metrics': per-vehicle dict of lists, 'summary': harness.summarize
    (success rate and mean/std/median over successful flights), 'tuned': TunedFlight,
    'wall_s': float}}.
    """
    if methods is None:
        methods = tuple(m for m in METHODS if m != "log_cem" or ensemble is not None)
    methods = check_methods(methods)
    if "log_cem" in methods and ensemble is None:
        raise ValueError("method 'log_cem' needs an ensemble (B, M, 19): each vehicle's models from its log")
    theta = P.validate_theta(P.as_batch(theta))
    b = theta.shape[0]
    sim = sim or Quadrotor(SimConfig())
    ref = resolve_policy(policy)
    low = ref.batched(b)
    if decoder is None and any(m in CEM_METHODS for m in methods):
        # With a decoder every CEM method shares one compiled update; it is required for 'cfm'.
        try:
            decoder = load_decoders(policy=ref, warn=log)[0]
        except FileNotFoundError:
            if "cfm" in methods:
                raise
    dist = disturbance if disturbance is not None else broadcast(Disturbance.make(), b)
    key = jax.random.PRNGKey(seed)
    out = {}
    for m in methods:
        t0 = time.time()
        bar = _bar(progress, m, -(-steps // cfg.steps(sim.config.dt)[0]))
        tf = fly_tuned(sim, theta, low, refs, dist, m, key, steps, cfg=cfg, decoder=decoder,
                       progress=(lambda d, n: bar.update(1)) if bar else None,
                       ensemble=ensemble if m == "log_cem" else None)
        if bar:
            bar.close()
        mm = batch_metrics(tf.flight)
        out[m] = {"metrics": metrics_to_host(mm), "summary": summarize(mm), "tuned": tf,
                  "wall_s": time.time() - t0}
        if log:
            s = out[m]["summary"]
            log(f"{METHOD_LABELS[m]:>12}: success {s['success_rate']:.0%}, pos RMSE "
                f"{_ms(s['pos_rmse_m'])} m, max {_ms(s['max_pos_err_m'])} m, heading "
                f"{_ms(s['heading_rmse_deg'])} deg ({out[m]['wall_s']:.0f} s)")
    return out


def _bar(enabled: bool, method: str, total: int):
    if not enabled:
        return None
    return progress(total=total, desc=f"{METHOD_LABELS[method]} (tuner segments)")


def _ms(d):
    return "–" if d["mean"] is None else f"{d['mean']:.3f} ± {d['std']:.3f}"


def results_dict(res: dict, index: int | None = None) -> dict:
    """JSON-ready metrics per method (keys of :data:`RESULT_KEYS`): for one vehicle
    (``index``) the per-vehicle values, else the summary plus per-vehicle lists; with the
    applied gains at the end of the flight."""
    out = {}
    for m, r in res.items():
        if index is not None:
            d = {k: (r["metrics"][k][index] if isinstance(r["metrics"][k], list) else r["metrics"][k])
                 for k in PER_VEHICLE}
            d["failed"] = bool(d["failed"])
            d["final_gains"] = dict(zip(GAIN_NAMES, np.asarray(r["tuned"].gains[index, -1]).round(4).tolist()))
        else:
            d = dict(r["summary"])
            d["per_vehicle"] = {k: r["metrics"][k] for k in PER_VEHICLE}
            d["final_gains_mean"] = dict(zip(GAIN_NAMES, np.asarray(r["tuned"].gains[:, -1]).mean(0).round(4).tolist()))
        d["wall_s"] = round(r["wall_s"], 2)
        out[RESULT_KEYS[m]] = d
    return out


def common_summary(res: dict, keys=("pos_rmse_m", "max_pos_err_m", "heading_rmse_deg", "saturation_frac")) -> dict:
    """Every method scored on the same vehicles: those that no method lost (a flight that fails
    under one method drops out for all). Returns {'n': int, 'vehicles': indices, method: {metric:
    {'mean', 'std', 'median'}}}; the per-method summaries average each method over its *own*
    successful flights, which favours a method that loses its hardest vehicles."""
    failed = np.stack([np.asarray(r["metrics"]["failed"], bool) for r in res.values()])   # (M, B)
    ok = ~failed.any(0)
    out = {"n": int(ok.sum()), "vehicles": np.flatnonzero(ok).tolist()}
    for m, r in res.items():
        d = {}
        for k in keys:
            v = np.asarray(r["metrics"][k], np.float64)[ok]
            d[k] = ({"mean": float(v.mean()), "std": float(v.std()), "median": float(np.median(v))}
                    if v.size else {"mean": None, "std": None, "median": None})
        out[m] = d
    return out


