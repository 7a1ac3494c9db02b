"""Predictive tuning experiments (paper §V-A): ``tune-nominal``, ``tune-slow``, ``tune-lemniscate``.

- tune-nominal: 100 default-prior vehicles, 5 s random min-snap each; Naive / Baseline /
  CFM-tuned (+ Oracle-CEM, an upper reference the paper does not have).
- tune-slow: the same on the slow-actuator prior (τ_m ∈ [0.05, 0.10] s); Baseline /
  Nominal+CEM / CFM-tuned (+ Oracle-CEM).
- tune-lemniscate: the paper vehicle ("hardware": IMU noise, bias and one step of latency),
  lemniscates of 15 / 10 / 7.5 s period, three cycles each; Baseline vs CFM-tuned (+ Oracle-CEM).

Full settings are sized for one GPU (100 vehicles, K = 16 models, N = 32 candidates, H = 0.5 s,
2 CEM iterations per update); ``cpu`` keeps the protocol (5 s min-snap flights, three
lemniscate cycles, H = 0.5 s) with 12 vehicles, K = 4 and N = 12 (tens of minutes on two
cores); ``quick`` shrinks everything to a smoke test of minutes (its numbers are not results).
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import params as P
from mjxsysid.analysis.flight import broadcast, random_minsnaps
from mjxsysid.control.references import Lemniscate, stack
from mjxsysid.experiments.common import fmt_ms, markdown_table, write_results
from mjxsysid.sim import Quadrotor, SimConfig
from mjxsysid.tune.cem import CEMConfig
from mjxsysid.tune.compare import RESULT_KEYS, compare_methods, plot_gains, plot_tracking, results_dict
from mjxsysid.tune.tuner import METHOD_LABELS, TunerConfig

FULL_TUNER = TunerConfig(models=16, horizon=0.5, rate=10.0, cem=CEMConfig(candidates=32, iterations=2))
CPU_TUNER = TunerConfig(models=4, horizon=0.5, rate=10.0, cem=CEMConfig(candidates=12, iterations=2))
QUICK_TUNER = TunerConfig(models=4, horizon=0.3, rate=10.0, cem=CEMConfig(candidates=8, iterations=2),
                          decoder_steps=20)

PAPER = {
    "tune-nominal": {"pos_rmse_m": {"naive": 0.330, "baseline": 0.198, "cfm": 0.218},
                     "max_pos_err_m": {"naive": 0.624, "baseline": 0.470, "cfm": 0.510},
                     "heading_rmse_deg": {"naive": 2.68, "baseline": 4.70, "cfm": 4.89}},
    "tune-slow": {"pos_rmse_m": {"baseline": 0.705, "nominal_cem": 0.584, "cfm": 0.546},
                  "max_pos_err_m": {"baseline": 1.671, "nominal_cem": 1.332, "cfm": 1.155},
                  "heading_rmse_deg": {"baseline": 14.25, "nominal_cem": 13.81, "cfm": 7.85}},
    # hardware table: (pos RMSE, max pos err, heading RMSE) per period and controller
    "tune-lemniscate": {15.0: {"baseline": (0.046, 0.079, 1.197), "cfm": (0.025, 0.048, 1.303)},
                        10.0: {"baseline": (0.060, 0.090, 1.316), "cfm": (0.038, 0.062, 1.258)},
                        7.5: {"baseline": (0.110, 0.252, 1.354), "cfm": (0.129, 0.187, 1.386)}},
}
METRICS = (("pos_rmse_m", "pos RMSE (m)"), ("max_pos_err_m", "max pos err (m)"),
           ("heading_rmse_deg", "heading RMSE (deg)"))
SETTLE_S = 2.0
"""tune-lemniscate also scores each flight after this time (s): the take-off transient excluded."""
HARDWARE_SIM = SimConfig(gyro_noise=0.01, accel_noise=0.1, gyro_bias=0.005, accel_bias=0.05, imu_latency=1)
"""The paper vehicle's "hardware" imperfections for tune-lemniscate (per-step white noise,
per-flight bias, 2 ms latency)."""


def _log(msg):
    import sys

    from mjxsysid.progress import echo
    echo(msg, file=sys.stderr)


def _prior_table(name, res, methods):
    paper = PAPER[name]
    header = ["metric"] + [f"{METHOD_LABELS[m]}" for m in methods]
    rows = []
    for k, label in METRICS:
        rows.append([f"{label}, ours"] + [fmt_ms(res[m]["summary"][k]) for m in methods])
        rows.append([f"{label}, paper"] + [f"{paper[k][m]:.3f}" if m in paper[k] else "–" for m in methods])
    rows.append(["success, ours"] + [f"{res[m]['summary']['success_rate']:.0%}" for m in methods])
    return markdown_table(header, rows)


def _ratio(res, a, b, k="pos_rmse_m"):
    x, y = res.get(a), res.get(b)
    if not x or not y or x["summary"][k]["mean"] is None or y["summary"][k]["mean"] is None:
        return None
    return x["summary"][k]["mean"] / y["summary"][k]["mean"]


def _size(quick, cpu):
    return "quick" if quick else ("cpu" if cpu else "full")


def _prior_experiment(name, prior, methods, out, quick, policy, seed, progress, cpu=False):
    t0 = time.time()
    size = _size(quick, cpu)
    n, duration = {"quick": (3, 2.0), "cpu": (12, 5.0), "full": (100, 5.0)}[size]
    cfg = {"quick": QUICK_TUNER, "cpu": CPU_TUNER, "full": FULL_TUNER}[size]
    theta = np.asarray(P.get_prior(prior).sample(jax.random.PRNGKey(seed), n))
    refs = random_minsnaps(n, seed, duration)
    sim = Quadrotor()
    steps = int(round(duration / sim.config.dt))
    _log(f"{name}: {n} {prior}-prior vehicles × {duration:g} s min-snap, methods {methods}")
    res = compare_methods(theta, refs, steps=steps, methods=methods, cfg=cfg, policy=policy, sim=sim,
                          seed=seed, log=_log, progress=progress)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_gains(res, out / "gains.png", title=f"{name}: gains over time (mean, 5–95 % over vehicles)")
    plot_tracking(res, out / "tracking.png", title=f"{name}: position error over vehicles")
    numbers = results_dict(res)
    head = {f"{RESULT_KEYS[m]}_pos_rmse": res[m]["summary"]["pos_rmse_m"]["mean"] for m in methods}
    numbers["headline"] = head
    numbers["ratios"] = {"cfm_over_baseline": _ratio(res, "cfm", "baseline"),
                         "cfm_over_naive": _ratio(res, "cfm", "naive"),
                         "cfm_over_nominal_cem": _ratio(res, "cfm", "nominal_cem")}
    config = {"quick": quick, "size": size, "prior": prior, "vehicles": n, "duration_s": duration, "methods": list(methods),
              "tuner": dataclasses.asdict(cfg), "reference": "random min-snap (5 segments, 2 m box)"}
    notes = ("Mean ± std over the successful flights of each method (the paper: over rollouts). "
             "Oracle-CEM tunes on K copies of the true θ: an upper reference, not in the paper.\n"
             f"Ratios (pos RMSE): " + ", ".join(f"{k} {v:.2f}" for k, v in numbers["ratios"].items() if v is not None))
    return write_results(out, name, config=config, seeds={"vehicles": seed, "references": seed, "flight": seed},
                         numbers=numbers, table_md=_prior_table(name, res, methods), t0=t0, policy=_ref(policy),
                         decoders=_ref(policy).decoders_dir, notes=notes)


def _ref(policy):
    from mjxsysid.policy.interface import resolve_policy
    return resolve_policy(policy or "mjxsysid")


def run_nominal(out, *, quick=False, policy=None, seed=0, progress=True, methods=None, cpu=False):
    """tune-nominal (see the module doc)."""
    return _prior_experiment("tune-nominal", "default", methods or ("naive", "baseline", "cfm", "oracle_cem"),
                             out, quick, policy, seed, progress, cpu)


def run_slow(out, *, quick=False, policy=None, seed=0, progress=True, methods=None, cpu=False):
    """tune-slow (see the module doc)."""
    return _prior_experiment("tune-slow", "slow_actuators",
                             methods or ("baseline", "nominal_cem", "cfm", "oracle_cem"), out, quick, policy,
                             seed, progress, cpu)


def run_lemniscate(out, *, quick=False, policy=None, seed=0, progress=True, methods=None, cpu=False):
    """tune-lemniscate: the three periods fly as one batch of three copies of the paper vehicle
    (each flight's metrics over its own three cycles)."""
    t0 = time.time()
    methods = methods or ("baseline", "cfm", "oracle_cem")
    periods = (15.0, 10.0, 7.5)
    cycles = 3
    size = _size(quick, cpu)
    cfg = {"quick": QUICK_TUNER, "cpu": CPU_TUNER, "full": FULL_TUNER}[size]
    sim = Quadrotor(HARDWARE_SIM)
    duration = 2.0 if quick else cycles * max(periods)
    steps = int(round(duration / sim.config.dt))
    theta = np.repeat(P.PAPER_HARDWARE[None], len(periods), 0)
    refs = stack([Lemniscate.make(period=p) for p in periods])
    _log(f"tune-lemniscate: paper vehicle, periods {periods} s, {duration:g} s flown, methods {methods}")
    res = compare_methods(theta, refs, steps=steps, methods=methods, cfg=cfg, policy=policy, sim=sim,
                          seed=seed, log=_log, progress=progress)
    # metrics over each period's own three cycles
    from mjxsysid.analysis.harness import metrics
    # ... and over the same window after the first SETTLE_S s (the take-off transient, which the
    # CEM methods fly with the naive gains until their first updates)
    n0 = int(round(SETTLE_S / sim.config.dt))
    per = {}
    for m in methods:
        fl = res[m]["tuned"].flight
        per[m] = {}
        for i, p in enumerate(periods):
            n_i = steps if quick else int(round(cycles * p / sim.config.dt))
            one = jax.tree.map(lambda a: a[i, :n_i], fl)
            mm = {k: float(v) for k, v in metrics(one).items() if k != "fail_time_s"}
            if n_i > n0:
                late = metrics(jax.tree.map(lambda a: a[i, n0:n_i], fl))
                mm.update({f"{k}_after_settle": float(late[k]) for k in ("pos_rmse_m", "max_pos_err_m",
                                                                         "heading_rmse_deg")})
            per[m][p] = mm
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_gains(res, out / "gains.png", title="tune-lemniscate: gains (mean over the three periods)")
    plot_tracking(res, out / "tracking.png", index=1, title="tune-lemniscate: position error; path at 10 s period")
    rows = []
    for p in periods:
        for m in methods:
            d = per[m][p]
            pp = PAPER["tune-lemniscate"][p].get(m)
            late = (f"{d['pos_rmse_m_after_settle']:.3f} / {d['max_pos_err_m_after_settle']:.3f}"
                    if "pos_rmse_m_after_settle" in d else "–")
            rows.append([f"{p:g} s", METHOD_LABELS[m], f"{d['pos_rmse_m']:.3f}", f"{d['max_pos_err_m']:.3f}",
                         f"{d['heading_rmse_deg']:.2f}", late, "failed" if d["failed"] else "ok",
                         " / ".join(f"{x:g}" for x in pp) if pp else "–"])
    table = markdown_table(["period", "controller", "pos RMSE (m)", "max err (m)", "heading (deg)",
                            f"after {SETTLE_S:g} s: RMSE / max (m)", "status", "paper (RMSE / max / heading)"], rows)
    numbers = {"per_period": {RESULT_KEYS[m]: {str(p): per[m][p] for p in periods} for m in methods},
               "final_gains": {RESULT_KEYS[m]: res[m]["tuned"].gains[:, -1].tolist() for m in methods},
               "headline": {f"{RESULT_KEYS[m]}_{p:g}s": per[m][p]["pos_rmse_m"] for m in methods for p in periods}}
    if "cfm" in methods and "baseline" in methods:
        numbers["cfm_le_baseline"] = {str(p): per["cfm"][p]["pos_rmse_m"] <= per["baseline"][p]["pos_rmse_m"]
                                      for p in periods}
        if not quick:
            numbers["cfm_le_baseline_after_settle"] = {
                str(p): per["cfm"][p]["pos_rmse_m_after_settle"] <= per["baseline"][p]["pos_rmse_m_after_settle"]
                for p in periods}
    config = {"quick": quick, "size": size, "periods_s": periods, "cycles": cycles, "duration_s": duration,
              "methods": list(methods), "tuner": dataclasses.asdict(cfg), "sim": dataclasses.asdict(HARDWARE_SIM)}
    return write_results(out, "tune-lemniscate", config=config, seeds={"flight": seed}, numbers=numbers,
                         table_md=table, t0=t0, policy=_ref(policy), decoders=_ref(policy).decoders_dir,
                         notes="Our simulated 'hardware' is the paper vehicle with IMU noise, bias and latency.")
