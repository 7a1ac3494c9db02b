"""The log-grounded posterior's sampler checked against a long MCMC on the same target.

The tempered SMC of :func:`mjxsysid.identify.inference.log_grounded_posterior` (``force_smc=True``),
alone (``refine=False``) and its same draws refined by short NUTS chains as the library runs it
(:func:`~mjxsysid.identify.inference.refine_posterior`, :mod:`mjxsysid.identify.nuts`), and blackjax's NUTS (:func:`nuts_reference`: ``chains`` chains, Stan's window adaptation with a
dense mass matrix, then ``draws`` draws each) sample one target per log: the same data, the
same discrepancy δ and channel weights w (the SMC run's), the 17 coordinates y = [v (12),
log σ (4), acc_z bias] (:func:`~mjxsysid.identify.target._log_target_y`). NUTS runs in
unconstrained coordinates (:func:`to_constrained`): the prior's box through a logistic map, with
the triangle inequality of J built into the yaw inertia's lower bound; only ρ_4's range stays
a wall of −inf. There, an affine map u -> m + L u (m the mode, L L^T the SMC draws' covariance)
makes the posterior's scales of order one: a clean log's posterior is 10⁻⁴ wide in some
directions and 1 in others, below the floor blackjax's mass-matrix estimate regularises towards
(10⁻³), and without the map the warm-up ends with steps of 2 · 10⁻⁴ and its chains apart (R̂ up
to 3.7 after 500 + 1000 steps). The map only conditions the sampler: the target is the same,
the warm-up still adapts a dense mass matrix, and R̂ across chains started apart checks it.

Per log and visible coordinate the run reports both 5/50/95 % quantiles and the **sampler error**
(|SMC − NUTS| per quantile over the NUTS 90 % band's width), whether the truth is inside each
band, and the **model error** (|truth − NUTS median| over the NUTS band's width). A truth
outside both bands is the model's miss, not the sampler's. NUTS's convergence: rank-normalised
split R̂ and bulk ESS per coordinate (blackjax.diagnostics), divergences.

The logs: vehicles of the ``wide_actuators`` prior (seed 5: the calibration run's draw) flown by
the lag-aware oracle on the 10 s lemniscate in the MJX simulator, at the IMU noise levels
:data:`LEVELS`, logs taken round-robin over the levels::

    mjxsysid experiment sampler-reference \\
        --out docs/runs/measurements/log-grounded/sampler-reference
    mjxsysid experiment sampler-reference --quick --out /tmp/sampler_quick      # one log, short chains
"""
from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.experiments.common import markdown_table, write_results
from mjxsysid.experiments.log_grounded_coverage import level_flights
from mjxsysid.identify import logspace as L
from mjxsysid.identify.calibrate import raw_bands
from mjxsysid.identify.coords import V_NAMES, visible_from_theta
from mjxsysid.identify.inference import default_method, log_grounded_posterior, refine_posterior
from mjxsysid.identify.logdata import prepare
from mjxsysid.identify.nuts import INIT_JITTER, TARGET_ACCEPTANCE, nuts_reference
from mjxsysid.identify.target import N_Y
from mjxsysid.rollout.flight import flight_log
from mjxsysid.runtime.progress import echo

LEVELS = ("clean", "x1", "x5_white", "x20")
"""The IMU noise levels of the logs (:data:`mjxsysid.uses.imu_noise.LEVELS`), taken in turn."""
PRIOR = "wide_actuators"
"""The prior the vehicles are drawn from (the log-grounded calibration run's)."""
FULL = {"logs": 20, "chains": 4, "warmup": 1000, "draws": 2000}
"""The committed run's sizes."""
QUICK = {"logs": 1, "chains": 2, "warmup": 150, "draws": 200}
RHAT_MAX = 1.01
"""A log whose NUTS run ends with R̂ at or above this on any coordinate is run again once with
:data:`LONGER` times the warm-up and draws (an × 1 log at 1000 + 2000 steps: R̂ 1.020 on the yaw
authority; at 2000 + 8000, 1.001)."""
LONGER = (2, 4)


# ---- the comparison -----------------------------------------------------------------------------

def compare(smc_v, mcmc_v, truth_v) -> dict:
    """SMC draws (S, 12), MCMC draws (N, 12), the truth (12,) -> per coordinate: ``smc`` and ``mcmc``
    quantiles (3, 12) (5, 50, 95 %: :func:`~mjxsysid.identify.calibrate.raw_bands`), ``sampler_error``
    (3, 12) |SMC − MCMC| per quantile over the MCMC's 90 % band width, ``width_ratio`` (12,) the
    SMC's band width over the MCMC's,
    ``inside_smc`` / ``inside_mcmc`` (12,) the truth in each 90 % band, ``model_error`` (12,)
    |truth − MCMC median| over the MCMC band's width."""
    qs, qm = raw_bands(smc_v), raw_bands(mcmc_v)
    t = np.asarray(truth_v, np.float64)
    width = np.maximum(qm[2] - qm[0], 1e-12)
    return {"smc": qs, "mcmc": qm, "sampler_error": np.abs(qs - qm) / width, "width_ratio": (qs[2] - qs[0]) / width,
            "inside_smc": (qs[0] <= t) & (t <= qs[2]), "inside_mcmc": (qm[0] <= t) & (t <= qm[2]),
            "model_error": np.abs(t - qm[1]) / width}


def check_log(rec: dict, truth_theta, *, seed: int, chains: int, warmup: int, draws: int,
              particles: int | None = None) -> dict:
    """One log: the SMC posterior (raw, ``force_smc``), NUTS on its target (longer where R̂ ≥
    :data:`RHAT_MAX`; ``nuts_steps`` the warm-up and draws it ran), their comparison
    (:func:`compare`) against θ's visible coordinates, the same comparison between the first half of
    NUTS's chains and the rest (``nuts_halves_error`` (3, 12): the measurement's own noise), and the
    seconds of each. The SMC runs once: the refined posterior is its draws refined by the library's
    short chains (``refined_seconds``: the SMC's seconds and theirs)."""
    data = prepare(rec)
    t0 = time.perf_counter()
    post = log_grounded_posterior(data, None, force_smc=True, refine=False, seed=seed, calibration=None,
                                  particles=particles)
    t_smc = time.perf_counter() - t0
    t0 = time.perf_counter()
    refined = refine_posterior(data, post, seed=seed, calibration=None)
    t_refined = t_smc + time.perf_counter() - t0
    mode = np.asarray(post["mode"], np.float64)
    start = L.y_from_x(np.asarray(mode))
    ld, w = post["nuisance"][0, L.LOG_DISCREPANCY], post["weights"]      # δ is fixed: any draw's
    smc_y = np.concatenate([post["v_raw"], post["nuisance"][:, L.NUIS_IN_Y]], 1)
    t0 = time.perf_counter()
    ref = nuts_reference(data, ld, w, start, smc_y, chains=chains, warmup=warmup, draws=draws, seed=seed)
    if np.max(ref["rhat"]) >= RHAT_MAX:
        warmup, draws = LONGER[0] * warmup, LONGER[1] * draws
        ref = nuts_reference(data, ld, w, start, smc_y, chains=chains, warmup=warmup, draws=draws, seed=seed)
    t_nuts = time.perf_counter() - t0
    truth = np.asarray(visible_from_theta(np.asarray(truth_theta, np.float32)), np.float64)
    cmp = compare(post["v_raw"], ref["y"].reshape(-1, N_Y)[:, L.Y_V], truth)
    half = chains // 2          # NUTS against itself: its first chains against the others
    floor = compare(ref["y"][:half].reshape(-1, N_Y)[:, L.Y_V], ref["y"][half:].reshape(-1, N_Y)[:, L.Y_V], truth)
    ref_cmp = compare(refined["v_raw"], ref["y"].reshape(-1, N_Y)[:, L.Y_V], truth)
    return {**cmp, "refined_sampler_error": ref_cmp["sampler_error"], "refined_width_ratio": ref_cmp["width_ratio"],
            "inside_refined": ref_cmp["inside_smc"], "refined_seconds": t_refined, "refined_nuts": refined["nuts"],
            "nuts_halves_error": floor["sampler_error"], "truth": truth, "rhat": ref["rhat"],
            "ess_bulk": ref["ess_bulk"], "divergences": ref["divergences"], "leapfrog_mean": ref["leapfrog_mean"],
            "step_size": ref["step_size"], "nuts_steps": [warmup, draws], "smc_seconds": t_smc, "nuts_seconds": t_nuts,
            "method_default": default_method(post), "smc_stages": post["smc_stages"],
            "smc_acceptance": post["smc_acceptance"], "smc_tempering": post["smc_tempering"],
            "laplace_is": post["laplace_is"]}


def summarise(rows: list) -> dict:
    """Per visible coordinate over the logs: the median and largest sampler error per quantile, the
    median and smallest width ratio, how often the truth is inside the SMC's and the NUTS band, and
    how often outside both (the posterior's miss, not the sampler's); NUTS's largest R̂ and smallest
    bulk ESS."""
    err = np.array([r["sampler_error"] for r in rows])           # (L, 3, 12)
    floor = np.array([r["nuts_halves_error"] for r in rows])
    ins, inm = (np.array([r[k] for r in rows]) for k in ("inside_smc", "inside_mcmc"))
    rh, es = np.array([r["rhat"] for r in rows]), np.array([r["ess_bulk"] for r in rows])
    out = {}
    for j, name in enumerate(V_NAMES):
        out[name] = {"sampler_error_median": np.median(err[:, :, j], 0).round(3).tolist(),
                     "sampler_error_max": err[:, :, j].max(0).round(3).tolist(),
                     "width_ratio_median": float(np.median([r["width_ratio"][j] for r in rows]).round(3)),
                     "width_ratio_min": float(np.min([r["width_ratio"][j] for r in rows]).round(3)),
                     "nuts_halves_error_median": float(np.median(floor[:, :, j]).round(3)),
                     "nuts_halves_error_max": float(floor[:, :, j].max().round(3)),
                     "inside_smc": int(ins[:, j].sum()), "inside_mcmc": int(inm[:, j].sum()),
                     "outside_both": int((~ins[:, j] & ~inm[:, j]).sum()),
                     "model_error_median": float(np.median([r["model_error"][j] for r in rows]).round(3)),
                     "rhat_max": float(rh[:, j].max().round(4)), "ess_bulk_min": float(es[:, j].min().round(0))}
    return out


def by_level(rows: list, levels: list[str]) -> dict:
    """Per noise level (``levels``: each row's): logs, the sampler error's median and largest over
    every coordinate and quantile, NUTS halves' median, the median width ratio, the truths inside
    the SMC's and NUTS's bands and outside both (of 12 per log)."""
    out = {}
    for lv in dict.fromkeys(levels):
        rs = [r for r, x in zip(rows, levels) if x == lv]
        err = np.array([r["sampler_error"] for r in rs])
        out[lv] = {"logs": len(rs), "sampler_error_median": float(np.median(err).round(3)),
                   "sampler_error_max": float(err.max().round(3)),
                   "nuts_halves_error_median": float(np.median([r["nuts_halves_error"] for r in rs]).round(3)),
                   "width_ratio_median": float(np.median([r["width_ratio"] for r in rs]).round(3)),
                   "refined_sampler_error_median": float(np.median([r["refined_sampler_error"] for r in rs]).round(3)),
                   "refined_sampler_error_max": float(np.max([r["refined_sampler_error"] for r in rs]).round(3)),
                   "refined_width_ratio_median": float(np.median([r["refined_width_ratio"] for r in rs]).round(3)),
                   "inside_refined": int(sum(r["inside_refined"].sum() for r in rs)),
                   "inside_smc": int(sum(r["inside_smc"].sum() for r in rs)),
                   "inside_mcmc": int(sum(r["inside_mcmc"].sum() for r in rs)),
                   "outside_both": int(sum((~r["inside_smc"] & ~r["inside_mcmc"]).sum() for r in rs)),
                   "bands": 12 * len(rs)}
    return out


def tables(summary: dict, levels: dict, rows: list, labels: list[str]) -> str:
    """The results' markdown: the summary per coordinate, then each log's largest sampler error,
    its misses and NUTS's convergence."""
    n = len(rows)
    head = ["coordinate", "sampler error q05 / q50 / q95 (median)", "(max)", "NUTS halves (median / max)",
            "SMC / NUTS width (median / min)",
            f"truth inside SMC / NUTS (of {n})", "outside both", "model error (median)", "R̂ max", "bulk ESS min"]
    body = [[k, " / ".join(f"{e:.2f}" for e in s["sampler_error_median"]),
             " / ".join(f"{e:.2f}" for e in s["sampler_error_max"]),
             f"{s['nuts_halves_error_median']:.2f} / {s['nuts_halves_error_max']:.2f}",
             f"{s['width_ratio_median']:.2f} / {s['width_ratio_min']:.2f}", f"{s['inside_smc']} / {s['inside_mcmc']}",
             s["outside_both"], f"{s['model_error_median']:.2f}", f"{s['rhat_max']:.3f}", f"{s['ess_bulk_min']:.0f}"]
            for k, s in summary.items()]
    per = [[lab, r["method_default"], r["smc_stages"], f"{r['smc_acceptance']:.2f}",
            f"{float(np.max(r['sampler_error'])):.2f}", V_NAMES[int(np.argmax(np.max(r['sampler_error'], 0)))],
            f"{float(np.median(r['width_ratio'])):.2f}",
            f"{int(r['inside_smc'].sum())} / {int(r['inside_mcmc'].sum())}",
            f"{float(np.max(r['rhat'])):.3f}", f"{float(np.min(r['ess_bulk'])):.0f}", r["divergences"],
            f"{r['nuts_steps'][0]} + {r['nuts_steps'][1]}", f"{r['leapfrog_mean']:.0f}",
            f"{r['smc_seconds']:.0f} / {r['nuts_seconds']:.0f}"] for lab, r in zip(labels, rows)]
    lv = [[k, x["logs"], f"{x['sampler_error_median']:.2f} ({x['sampler_error_max']:.2f})",
           f"{x['refined_sampler_error_median']:.2f} ({x['refined_sampler_error_max']:.2f})",
           f"{x['nuts_halves_error_median']:.2f}", f"{x['width_ratio_median']:.2f} / {x['refined_width_ratio_median']:.2f}",
           f"{x['inside_smc']} / {x['inside_refined']} / {x['inside_mcmc']} / {x['bands']}", x["outside_both"]]
          for k, x in levels.items()]
    return ("## Per noise level\n\nThe SMC alone (``refine=False``) and the library's sampler, the SMC refined by "
            "short NUTS chains (identify/nuts.py), each against the long NUTS run.\n\n" + markdown_table(
        ["level", "logs", "sampler error, SMC: median (max)", "SMC + short NUTS: median (max)", "NUTS halves (median)",
         "width over the long run's: SMC / SMC + short NUTS", "truth inside SMC / SMC + short NUTS / long NUTS / bands",
         "outside SMC and long NUTS"], lv)
            + "\n## Per visible coordinate\n\nSampler error: |SMC quantile − NUTS quantile| / NUTS 90 % band width. "
            "NUTS halves: the same between NUTS's first chains and the others (the measurement's own noise, "
            "over all three quantiles). Width: the SMC's 90 % band width over NUTS's. "
            "Model error: |truth − NUTS median| / NUTS band width.\n\n"
            + markdown_table(head, body)
            + "\n## Per log\n\nR̂, ESS: over all 17 sampled coordinates.\n\n"
            + markdown_table(["log", "default method", "SMC stages", "SMC acceptance", "sampler error max", "at",
                              "SMC / NUTS width (median)",
                              "truth inside SMC / NUTS (of 12)", "R̂ max", "bulk ESS min", "divergences",
                              "NUTS warm-up + draws", "leapfrog / draw", "seconds SMC / NUTS"], per))


def plan(logs: int, levels=LEVELS) -> list[tuple[int, str]]:
    """(vehicle, level) of each of ``logs`` logs: the levels in turn, a new vehicle after each round."""
    if logs < 1:
        raise ValueError(f"logs must be >= 1, got {logs}")
    return [(k // len(levels), levels[k % len(levels)]) for k in range(logs)]


def run(out, *, quick=False, policy=None, seed=5, logs=None, chains=None, warmup=None, draws=None,
        particles=None, progress=True) -> dict:
    """The comparison of the module doc into OUT/results.json and results.md. ``logs``, ``chains``,
    ``warmup``, ``draws`` default to :data:`FULL` (:data:`QUICK` with ``quick``); ``particles``: the
    SMC's (default the library's). ``policy`` is not used (the oracle flies)."""
    t0 = time.time()
    cfg = dict(QUICK if quick else FULL)
    for k, v in (("logs", logs), ("chains", chains), ("warmup", warmup), ("draws", draws)):
        if v is not None:
            cfg[k] = int(v)
    todo = plan(cfg["logs"])
    n_veh = max(v for v, _ in todo) + 1
    theta = np.asarray(P.get_prior(PRIOR).sample(jax.random.PRNGKey(seed), n_veh), np.float32)
    rows, labels, levels, lost = [], [], [], []
    for level in dict.fromkeys(lv for _, lv in todo):
        vehicles = [v for v, lv in todo if lv == level]
        frame, flown = level_flights(theta[: max(vehicles) + 1], level, seed)
        for v in vehicles:
            if v not in flown:
                lost.append(f"vehicle {v} {level}")
                continue
            r = check_log(flight_log(frame, v), theta[v], seed=v, chains=cfg["chains"], warmup=cfg["warmup"],
                          draws=cfg["draws"], particles=particles)
            rows.append(r)
            labels.append(f"vehicle {v} {level}")
            levels.append(level)
            if progress:
                echo(f"[{len(rows)}/{len(todo)}] {labels[-1]}: sampler error max {np.max(r['sampler_error']):.2f}, "
                     f"refined {np.max(r['refined_sampler_error']):.2f}, "
                     f"inside SMC/refined/NUTS {int(r['inside_smc'].sum())}/{int(r['inside_refined'].sum())}/"
                     f"{int(r['inside_mcmc'].sum())} of 12, "
                     f"R-hat max {np.max(r['rhat']):.3f}, ESS min {np.min(r['ess_bulk']):.0f}, "
                     f"{r['divergences']} divergences; {r['smc_seconds']:.0f} s SMC, {r['nuts_seconds']:.0f} s NUTS")
    if not rows:
        raise ValueError(f"no log to check: every flight failed ({', '.join(lost)})")
    summary, per_level = summarise(rows), by_level(rows, levels)
    err = np.array([r["sampler_error"] for r in rows])
    floor = np.array([r["nuts_halves_error"] for r in rows])
    headline = {"logs": len(rows), "sampler_error_median": float(np.median(err).round(3)),
                "sampler_error_max": float(err.max().round(3)),
                "nuts_halves_error_median": float(np.median(floor).round(3)),
                "nuts_halves_error_max": float(floor.max().round(3)),
                "inside_smc": int(sum(r["inside_smc"].sum() for r in rows)),
                "inside_mcmc": int(sum(r["inside_mcmc"].sum() for r in rows)),
                "bands": 12 * len(rows),
                "outside_both": int(sum((~r["inside_smc"] & ~r["inside_mcmc"]).sum() for r in rows)),
                "width_ratio_median": float(np.median([r["width_ratio"] for r in rows]).round(3)),
                "refined_sampler_error_median": float(np.median([r["refined_sampler_error"] for r in rows]).round(3)),
                "refined_sampler_error_max": float(np.max([r["refined_sampler_error"] for r in rows]).round(3)),
                "refined_width_ratio_median": float(np.median([r["refined_width_ratio"] for r in rows]).round(3)),
                "inside_refined": int(sum(r["inside_refined"].sum() for r in rows)),
                "refined_not_mixed": int(sum(not r["refined_nuts"]["converged"] for r in rows)),
                "rhat_max": float(max(np.max(r["rhat"]) for r in rows).round(4)),
                "method_default": {m: sum(r["method_default"] == m for r in rows)
                                   for m in ("decoded_is", "laplace_is", "smc")}}
    per_log = [{"log": lab, "sampler_error_max": float(np.max(r["sampler_error"]).round(3)),
                "width_ratio_median": float(np.median(r["width_ratio"]).round(3)),
                "inside_smc": int(r["inside_smc"].sum()), "inside_mcmc": int(r["inside_mcmc"].sum()),
                "refined_sampler_error_max": float(np.max(r["refined_sampler_error"]).round(3)),
                "refined_width_ratio_median": float(np.median(r["refined_width_ratio"]).round(3)),
                "inside_refined": int(r["inside_refined"].sum()), "refined_nuts": r["refined_nuts"],
                "refined_seconds": round(r["refined_seconds"], 1),
                "rhat_max": float(np.max(r["rhat"]).round(4)), "nuts_steps": r["nuts_steps"]}
               for lab, r in zip(labels, rows)]        # the rest of each log's figures: results.md
    numbers = {"headline": headline, "per_level": per_level, "per_coordinate": summary, "per_log": per_log, "lost": lost}
    config = {"quick": quick, **cfg, "levels": list(LEVELS), "prior": PRIOR, "particles": particles,
              "nuts": f"blackjax window_adaptation (dense mass matrix, target acceptance {TARGET_ACCEPTANCE}) then NUTS",
              "init": f"the SMC run's mode + N(0, {INIT_JITTER}^2) in the preconditioned coordinates"}
    notes = (f"{len(rows)} logs; {cfg['chains']} chains × ({cfg['warmup']} warm-up + {cfg['draws']} draws) of NUTS "
             f"per log, {LONGER[0]}× and {LONGER[1]}× those where R̂ ≥ {RHAT_MAX}. Raw posteriors (no calibration). "
             f"Lost flights: {', '.join(lost) or 'none'}.")
    return write_results(Path(out), "sampler-reference", config=config, seeds={"seed": seed}, numbers=numbers,
                         table_md=tables(summary, per_level, rows, labels), t0=t0, notes=notes)
