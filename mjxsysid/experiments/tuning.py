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

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders
from mjxsysid.control.references import Delayed, Lemniscate, stack
from mjxsysid.experiments.common import fmt_ms, markdown_table, write_results
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.runtime.progress import echo
from mjxsysid.render.tuning import plot_gains, plot_tracking
from mjxsysid.rollout.flight import minsnap_segments, random_minsnaps
from mjxsysid.rollout.harness import metrics
from mjxsysid.sim import Quadrotor, SimConfig
from mjxsysid.tune.cem import CEMConfig
from mjxsysid.tune.compare import RESULT_KEYS, common_summary, compare_methods, results_dict
from mjxsysid.tune.tuner import CEM_METHODS, HEADING_COST, METHOD_LABELS, NOMINAL_TAU_M, TunerConfig

FULL_TUNER = TunerConfig(models=16, horizon=0.5, rate=10.0, cem=CEMConfig(candidates=32, iterations=2), unroll=5)
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
LEAD_IN_S = 2.0
"""tune-lemniscate hovers this long (s) at the lemniscate's start point before the three cycles
(a real flight takes off and hovers first); the tuner runs from the start, so the CEM methods'
naive initial gains meet a hover, not a moving reference. Scores are over the three cycles."""
HARDWARE_SIM = SimConfig(gyro_noise=0.01, accel_noise=0.1, gyro_bias=0.005, accel_bias=0.05, imu_latency=1)
"""The paper vehicle's "hardware" imperfections for tune-lemniscate (per-step white noise,
per-flight bias, 2 ms latency)."""


def _log(msg):
    import sys

    echo(msg, file=sys.stderr)


def _prior_table(name, res, methods, common):
    paper = PAPER[name]
    header = ["metric"] + [f"{METHOD_LABELS[m]}" for m in methods]
    rows = []
    for k, label in METRICS:
        rows.append([f"{label}, ours (same {common['n']} vehicles)"] + [fmt_ms(common[m][k]) for m in methods])
        rows.append([f"{label}, ours (own successes)"] + [fmt_ms(res[m]["summary"][k]) for m in methods])
        rows.append([f"{label}, paper"] + [f"{paper[k][m]:.3f}" if m in paper[k] else "–" for m in methods])
    rows.append(["success, ours"] + [f"{res[m]['summary']['success_rate']:.0%}" for m in methods])
    return markdown_table(header, rows)


def _ratio(res, a, b, k="pos_rmse_m", common=None):
    """Mean of method a over method b: over the same vehicles (``common``) or each over its own
    successful flights."""
    if a not in res or b not in res:
        return None
    x, y = ((common[a][k]["mean"], common[b][k]["mean"]) if common is not None
            else (res[a]["summary"][k]["mean"], res[b]["summary"][k]["mean"]))
    return None if x is None or y is None else x / y


VARIANTS = {"heading_cost": "the tuner's cost with a heading term (weight HEADING_COST = 0.1), "
                            "not the paper's cost",
            "no_lead_in": "tune-lemniscate without the hover lead-in (the lemniscate from t = 0)",
            "steady_rotor_state": "each model's rollouts start the rotors at its steady state for the last motor "
                                  "command",
            "true_rotor_state": "the rollouts start from the simulator's true rotor speeds (a diagnostic: "
                                "hardware cannot see them)",
            "baseline_start": "the tuner starts from the Baseline gains instead of the Naive ones",
            "protect": "the tuner switches gains only when 75 % of its K models predict the new ones better",
            "apply_best": "the tuner applies the best candidate of its last CEM iteration, not the mean",
            "cem_3_iterations": "3 CEM iterations per update instead of 2",
            "horizon_1s": "a 1 s predictive horizon instead of 0.5 s",
            "log_grounded": "the tuner given a log: Log+CEM added, its K models drawn from each vehicle's "
                            "log-grounded posterior (mjxsysid.identify) of a 10 s identification flight (the "
                            "lag-aware oracle on a lemniscate, its IMU and motor commands), with the vehicle's "
                            "mass weighed (an IMU log cannot see it); the other methods as in the default protocol",
            "log_grounded_known_drag": "log_grounded with the ensemble's drag set to each vehicle's true drag too "
                                       "(a diagnostic: the posterior's drag is as broad as its prior)",
            "log_grounded_log_drag": "log_grounded with the ensemble's drag set to what the log's velocity shows: "
                                     "the drag per mass of each body axis fitted by the accelerometer, times the "
                                     "weighed mass"}
"""Protocol variants of the tune-* experiments (``mjxsysid experiment NAME --variant V[,V2]``):
choices made after seeing a result, or knobs measured, reported beside the default protocol."""


def _variant(name: str, variant: str | None, cfg: TunerConfig) -> TunerConfig:
    """The tuner config of ``variant`` (None: the default protocol; several joined by commas); a
    ValueError names the valid ones."""
    if variant is None:
        return cfg
    allowed = [v for v in VARIANTS if name == "tune-lemniscate" or v != "no_lead_in"]
    for v in variant.split(","):
        if v not in allowed:
            raise ValueError(f"{name} has no variant {v!r}; choose from {', '.join(allowed)}")
        if v == "heading_cost":
            cfg = dataclasses.replace(cfg, weights=dataclasses.replace(cfg.weights, heading=HEADING_COST))
        elif v in ("steady_rotor_state", "true_rotor_state"):
            cfg = dataclasses.replace(cfg, rotor_state=v.split("_")[0])
        elif v == "baseline_start":
            cfg = dataclasses.replace(cfg, initial="baseline")
        elif v == "protect":
            cfg = dataclasses.replace(cfg, protect=0.75)
        elif v == "apply_best":
            cfg = dataclasses.replace(cfg, apply="best")
        elif v == "cem_3_iterations":
            cfg = dataclasses.replace(cfg, cem=dataclasses.replace(cfg.cem, iterations=3))
        elif v == "horizon_1s":
            cfg = dataclasses.replace(cfg, horizon=1.0)
    return cfg


LOG_ENSEMBLE = 64
"""Draws of each vehicle's log-grounded posterior that Log+CEM takes its K models from."""
LOG_PARTICLES = 512
"""The SMC particles of those posteriors (the default 2048 is 4× the time; 64 draws need fewer)."""


def log_ensembles(theta, seed: int, *, draws: int = LOG_ENSEMBLE, particles: int | None = None,
                  progress: bool = True, known_drag: bool = False, log_drag: bool = False) -> np.ndarray:
    """The tuner given a log (variant ``log_grounded``): for each vehicle θ (B, 19) a 10 s
    identification flight (the lag-aware oracle, 10 s lemniscate, clean IMU, its own seed), the
    log-grounded posterior of its IMU and motor commands (no decoded proposal: the stated prior and
    the log), ``draws`` of it with the true mass (a vehicle put on a scale: the log cannot see the
    mass) -> (B, draws, 19). A failed identification flight is an error (no log, no models).
    ``particles``: the posterior's SMC particles (default its own). ``known_drag``: the draws' drag
    set to the true one as well (a diagnostic); ``log_drag``: set to the log's fitted drag per mass
    (:func:`mjxsysid.identify.inference.log_grounded_posterior`'s ``drag_per_mass``, body x, y, z) times
    the weighed mass."""
    from mjxsysid.identify import log_grounded_posterior
    from mjxsysid.identify.coords import with_mass
    from mjxsysid.runtime.progress import progress as bar
    from mjxsysid.rollout.flight import flight_log, fly_vehicles
    theta = np.asarray(theta, np.float32)
    fl, m, _ = fly_vehicles(theta, controller="oracle", reference="lemniscate", period=10.0, seed=seed + 1)
    failed = np.asarray(m["failed"])
    if failed.any():
        raise RuntimeError(f"identification flights failed for vehicles {np.flatnonzero(failed).tolist()}: no log")
    out = np.empty((len(theta), draws, theta.shape[1]), np.float32)
    it = bar(range(len(theta)), desc="log-grounded posteriors", enabled=progress)
    for i in it:
        post = log_grounded_posterior(flight_log(fl.frame, i), None, samples=draws, seed=seed + i, particles=particles)
        out[i] = with_mass(post["theta"], float(theta[i, P.MASS]))
        if known_drag:
            out[i][:, P.DRAG] = theta[i, P.DRAG]
        elif log_drag:
            d = post["drag_per_mass"]
            if d is None or any(x is None for x in d):
                raise RuntimeError(f"vehicle {i}: the identification log shows no drag (no velocity)")
            out[i][:, P.DRAG] = np.asarray(d, np.float32) * theta[i, P.MASS]
    return out


def _variant_note(variant: str | None) -> str:
    return "; ".join(f"{v}: {VARIANTS[v]}" for v in variant.split(",")) if variant else ""


def _size(quick, cpu):
    return "quick" if quick else ("cpu" if cpu else "full")


def _prior_experiment(name, prior, methods, out, quick, policy, seed, progress, cpu=False, variant=None,
                      decoders=None):
    t0 = time.time()
    policy = _ref(policy)
    decoder, dec_dir = _decoder(decoders, policy, methods)
    size = _size(quick, cpu)
    n, duration = {"quick": (3, 2.0), "cpu": (12, 5.0), "full": (100, 5.0)}[size]
    cfg = _variant(name, variant, {"quick": QUICK_TUNER, "cpu": CPU_TUNER, "full": FULL_TUNER}[size])
    theta = np.asarray(P.get_prior(prior).sample(jax.random.PRNGKey(seed), n))
    refs = random_minsnaps(n, seed, duration)
    sim = Quadrotor()
    steps = int(round(duration / sim.config.dt))
    ensemble = None
    variants = (variant or "").split(",")
    if {"log_grounded", "log_grounded_known_drag", "log_grounded_log_drag"} & set(variants):
        methods = tuple(methods) + (() if "log_cem" in methods else ("log_cem",))
        _log(f"{name}: identification flights and log-grounded posteriors of {n} vehicles")
        ensemble = log_ensembles(theta, seed, particles=LOG_PARTICLES, progress=progress,
                                 known_drag="log_grounded_known_drag" in variants,
                                 log_drag="log_grounded_log_drag" in variants)
    _log(f"{name}: {n} {prior}-prior vehicles × {duration:g} s min-snap, methods {methods}")
    res = compare_methods(theta, refs, steps=steps, methods=methods, cfg=cfg, policy=policy, sim=sim,
                          decoder=decoder, seed=seed, log=_log, progress=progress, ensemble=ensemble)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_gains(res, out / "gains.png", labels=METHOD_LABELS, tuned=CEM_METHODS, title=f"{name}: gains over time (mean, 5–95 % over vehicles)")
    plot_tracking(res, out / "tracking.png", labels=METHOD_LABELS, title=f"{name}: position error over vehicles")
    numbers = results_dict(res)
    common = common_summary(res)
    numbers["common_set"] = {"n": common["n"], "vehicles": common["vehicles"],
                             **{RESULT_KEYS[m]: common[m] for m in methods}}
    head = {f"{RESULT_KEYS[m]}_pos_rmse": common[m]["pos_rmse_m"]["mean"] for m in methods}
    head.update({f"{RESULT_KEYS[m]}_success": res[m]["summary"]["success_rate"] for m in methods})
    numbers["headline"] = head
    pairs = {"cfm_over_baseline": ("cfm", "baseline"), "cfm_over_naive": ("cfm", "naive"),
             "cfm_over_nominal_cem": ("cfm", "nominal_cem"), "log_cem_over_baseline": ("log_cem", "baseline"),
             "log_cem_over_cfm": ("log_cem", "cfm")}
    numbers["ratios"] = {f"{n}{suffix}": _ratio(res, a, b, k, common if same else None)
                         for n, (a, b) in pairs.items()
                         for k, suffix0 in (("pos_rmse_m", ""), ("max_pos_err_m", "_max"), ("heading_rmse_deg", "_heading"))
                         for same, suffix in ((True, suffix0), (False, suffix0 + "_own_successes"))}
    config = {"quick": quick, "size": size, "variant": variant, "prior": prior, "vehicles": n, "duration_s": duration,
              "methods": list(methods),
              "tuner": dataclasses.asdict(cfg), "reference": f"random min-snap ({minsnap_segments(duration)} segments, 2 m box, "
                                                        "whole path ≥ 0.2 m above the ground)"}
    notes = (f"Mean ± std over vehicles. 'same {common['n']} vehicles': those no method lost (the fair "
             "comparison); 'own successes': each method over the flights it completed (favours a method "
             "that loses its hardest vehicles). The paper reports mean ± std over rollouts. Oracle-CEM tunes "
             "on K copies of the true θ: an upper reference, not in the paper. Nominal+CEM tunes on ±20 % "
             f"perturbations of each vehicle's own nominal system (its θ with τ_m = {NOMINAL_TAU_M:g} s). "
             + (f"Variant {_variant_note(variant)}. " if variant else "The tuner's cost is the paper's "
                "(position RMSE, saturation, failure; no heading term). ") + "\n"
             "Ratios over the same vehicles: " + ", ".join(f"{k} {v:.2f}" for k, v in numbers["ratios"].items()
                                                          if v is not None and "own" not in k))
    return write_results(out, name, config=config, seeds={"vehicles": seed, "references": seed, "flight": seed},
                         numbers=numbers, table_md=_prior_table(name, res, methods, common), t0=t0, policy=policy,
                         decoders=dec_dir, notes=notes)


def _ref(policy):
    return resolve_policy(policy or "mjxsysid")


def _decoder(decoders, policy, methods):
    """(CFM decoder or None, its folder): from ``decoders`` (a folder with cfm.npz and
    regression.npz, checked against ``policy``), else the policy's shipped one, loaded by
    :func:`~mjxsysid.tune.compare.compare_methods`."""
    if decoders is None:
        return None, policy.decoders_dir
    return load_decoders(decoders, policy, warn=_log)[0], Path(decoders)


def run_nominal(out, *, quick=False, policy=None, seed=0, progress=True, methods=None, cpu=False, variant=None,
                decoders=None):
    """tune-nominal (see the module doc). ``decoders``: folder with cfm.npz and regression.npz
    (default: the policy's shipped ones)."""
    return _prior_experiment("tune-nominal", "default", methods or ("naive", "baseline", "cfm", "oracle_cem"),
                             out, quick, policy, seed, progress, cpu, variant, decoders)


def run_slow(out, *, quick=False, policy=None, seed=0, progress=True, methods=None, cpu=False, variant=None,
             decoders=None):
    """tune-slow (see the module doc; ``decoders`` as for :func:`run_nominal`)."""
    return _prior_experiment("tune-slow", "slow_actuators",
                             methods or ("baseline", "nominal_cem", "cfm", "oracle_cem"), out, quick, policy,
                             seed, progress, cpu, variant, decoders)


def run_lemniscate(out, *, quick=False, policy=None, seed=0, progress=True, methods=None, cpu=False,
                   variant=None, decoders=None):
    """tune-lemniscate: the three periods fly as one batch of three copies of the paper vehicle,
    each a hover lead-in of :data:`LEAD_IN_S` at the lemniscate's start point (take-off done, the
    tuner already running) and then three cycles; each flight is scored over its own three cycles
    (the paper's window), and over its last cycle. ``decoders`` as for :func:`run_nominal`."""
    t0 = time.time()
    policy = _ref(policy)
    methods = methods or ("baseline", "cfm", "oracle_cem")
    decoder, dec_dir = _decoder(decoders, policy, methods)
    periods = (15.0, 10.0, 7.5)
    cycles = 3
    size = _size(quick, cpu)
    cfg = _variant("tune-lemniscate", variant, {"quick": QUICK_TUNER, "cpu": CPU_TUNER, "full": FULL_TUNER}[size])
    sim = Quadrotor(HARDWARE_SIM)
    lead = 0.0 if "no_lead_in" in (variant or "").split(",") else (0.5 if quick else LEAD_IN_S)
    duration = 2.0 if quick else lead + cycles * max(periods)
    steps = int(round(duration / sim.config.dt))
    theta = np.repeat(P.PAPER_HARDWARE[None], len(periods), 0)
    refs = stack([Delayed.make(Lemniscate.make(period=p), lead) for p in periods])
    _log(f"tune-lemniscate: paper vehicle, {lead:g} s hover lead-in, then periods {periods} s × {cycles} cycles "
         f"({duration:g} s flown), methods {methods}")
    res = compare_methods(theta, refs, steps=steps, methods=methods, cfg=cfg, policy=policy, sim=sim,
                          decoder=decoder, seed=seed, log=_log, progress=progress)
    n0 = int(round(lead / sim.config.dt))
    per = {}
    for m in methods:
        fl = res[m]["tuned"].flight
        per[m] = {}
        for i, p in enumerate(periods):
            n_i = steps if quick else n0 + int(round(cycles * p / sim.config.dt))
            n_last = n_i - int(round(p / sim.config.dt))
            mm = {k: float(v) for k, v in metrics(jax.tree.map(lambda a: a[i, n0:n_i], fl)).items()
                  if k != "fail_time_s"}
            if not quick:
                last = metrics(jax.tree.map(lambda a: a[i, n_last:n_i], fl))
                mm.update({f"{k}_last_cycle": float(last[k]) for k in ("pos_rmse_m", "max_pos_err_m",
                                                                       "heading_rmse_deg")})
            if n0 > 0:
                lead_m = metrics(jax.tree.map(lambda a: a[i, :n0], fl))
                mm["failed"] = bool(mm["failed"]) or bool(lead_m["failed"])
                mm["lead_in_pos_rmse_m"] = float(lead_m["pos_rmse_m"])
            per[m][p] = mm
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plot_gains(res, out / "gains.png", labels=METHOD_LABELS, tuned=CEM_METHODS, title="tune-lemniscate: gains (mean over the three periods)")
    plot_tracking(res, out / "tracking.png", labels=METHOD_LABELS, index=1, title="tune-lemniscate: position error; path at 10 s period")
    rows = []
    for p in periods:
        for m in methods:
            d = per[m][p]
            pp = PAPER["tune-lemniscate"][p].get(m)
            last = (f"{d['pos_rmse_m_last_cycle']:.3f} / {d['max_pos_err_m_last_cycle']:.3f}"
                    if "pos_rmse_m_last_cycle" in d else "–")
            rows.append([f"{p:g} s", METHOD_LABELS[m], f"{d['pos_rmse_m']:.3f}", f"{d['max_pos_err_m']:.3f}",
                         f"{d['heading_rmse_deg']:.2f}", last,
                         f"{d['lead_in_pos_rmse_m']:.3f}" if "lead_in_pos_rmse_m" in d else "–",
                         "failed" if d["failed"] else "ok", " / ".join(f"{x:g}" for x in pp) if pp else "–"])
    table = markdown_table(["period", "controller", "pos RMSE (m)", "max err (m)", "heading (deg)",
                            "last cycle: RMSE / max (m)", f"{lead:g} s lead-in hover RMSE (m)", "status",
                            "paper (RMSE / max / heading)"], rows)
    numbers = {"per_period": {RESULT_KEYS[m]: {str(p): per[m][p] for p in periods} for m in methods},
               "final_gains": {RESULT_KEYS[m]: res[m]["tuned"].gains[:, -1].tolist() for m in methods},
               "headline": {f"{RESULT_KEYS[m]}_{p:g}s": per[m][p]["pos_rmse_m"] for m in methods for p in periods}}
    if "cfm" in methods and "baseline" in methods:
        numbers["cfm_le_baseline"] = {str(p): per["cfm"][p]["pos_rmse_m"] <= per["baseline"][p]["pos_rmse_m"]
                                      for p in periods}
    config = {"quick": quick, "size": size, "variant": variant, "periods_s": periods, "cycles": cycles, "lead_in_s": lead,
              "duration_s": duration,
              "methods": list(methods), "tuner": dataclasses.asdict(cfg), "sim": dataclasses.asdict(HARDWARE_SIM)}
    return write_results(out, "tune-lemniscate", config=config, seeds={"flight": seed}, numbers=numbers,
                         table_md=table, t0=t0, policy=policy, decoders=dec_dir,
                         notes=("Our simulated 'hardware' is the paper vehicle with IMU noise, bias and latency. "
                                f"Each flight: {lead:g} s hover at the start point (tuner running), then "
                                f"{cycles} cycles, scored over the cycles. "
                                + (f"Variant {_variant_note(variant)}." if variant else
                                   "The tuner's cost is the paper's (no heading term).")))
