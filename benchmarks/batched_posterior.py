"""Many logs at once: the log-grounded posterior batched over logs
(:func:`mjxsysid.identify.inference.log_grounded_posteriors`) against one log at a time.

Flies ``--vehicles`` vehicles of the wide_actuators prior with the lag-aware oracle (10 s lemniscate),
split over the noise levels asked for, turns each flight into a log (IMU, motors, body velocity),
and times, in one run:

- the logs' reduction (``prepare``), one process and ``--workers`` processes;
- the calibrated posterior of every log, batched (the defaults a user gets), cold (its first call
  compiles) and warm;
- the phases inside (the mode, both model checks, the SMC, NUTS, each log's finish), of the warm pass or,
  with ``--no-warm``, of the cold one;
- the first ``--sequential`` logs one at a time (batch 1), for the ratio.

It also reports the share of truths inside the calibrated 90 % bands, and how far the batched bands
of the sequential logs lie from their one-at-a-time bands, as a fraction of the band's width, beside
how far another seed's bands lie (the sampler's own Monte Carlo spread).

    python benchmarks/batched_posterior.py --vehicles 1000 --levels clean,x1,x5_white,x20 \
        --sequential 16 --out docs/runs/measurements/log-grounded/batched/h200.json
    python benchmarks/batched_posterior.py --vehicles 256 --levels x1 --sequential 0 --no-warm   # the phases alone
"""
from __future__ import annotations

import argparse
import collections
import time
from pathlib import Path

import jax
import numpy as np
from _bench import write_json


def flights(vehicles: int, levels: list[str], seed: int):
    """(logs, true θ (n, 19), their levels) of ``vehicles`` vehicles split over ``levels``."""
    from mjxsysid import theta as P
    from mjxsysid.experiments.log_grounded_coverage import level_flights
    from mjxsysid.rollout.flight import flight_log
    th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(seed), vehicles))
    recs, truth, lv = [], [], []
    for k, level in enumerate(levels):
        part = th[k::len(levels)]
        frame, flown = level_flights(part, level, seed + 97 * k)
        for i in flown:
            recs.append(flight_log(frame, i))
            truth.append(part[i])
            lv.append(level)
    return recs, np.asarray(truth), lv


def inside(posts, truth) -> np.ndarray:
    """(n, 12) whether each truth lies inside its calibrated 90 % band (visible coordinates)."""
    from mjxsysid.identify.coords import visible_from_theta
    tv = np.asarray(visible_from_theta(np.asarray(truth, np.float32)), np.float64)
    out = []
    for p, t in zip(posts, tv):
        lo, hi = np.percentile(p["v"], [5, 95], 0)
        out.append((lo <= t) & (t <= hi))
    return np.asarray(out)


def shifts(ref, posts) -> dict:
    """How far the 5/50/95 % quantiles of ``posts`` lie from those of ``ref`` (the same logs), the
    largest over the quantiles as a fraction of ``ref``'s 90 % width (the sampler reference's
    ``sampler_error``): median and max over logs and coordinates."""
    from mjxsysid.experiments.sampler_reference import compare
    out = [compare(p["v"], q["v"], np.zeros(q["v"].shape[1]))["sampler_error"].max(0) for p, q in zip(posts, ref)]
    return {"median": round(float(np.median(out)), 3), "max": round(float(np.max(out)), 3)} if out else {}


PHASES: dict = {}
CALLS: list = []
"""Each call of NUTS (:meth:`~mjxsysid.identify.batched._Logs.nuts`): (its logs, seconds)."""


def timed_phases():
    """Accumulate the wall time of the batched posterior's phases in :data:`PHASES` (the mode, the model checks
    (``window_check``, the motor-map check's ``run``), the targets, the SMC, NUTS, each log's finish; and the
    batched calls inside them: ``fit``, ``residuals``, ``rate_logliks``), printed as the run goes. Phases nest:
    ``fit`` is counted inside the mode and the checks too. Each NUTS call's logs and seconds go to :data:`CALLS`
    (the chains that did not mix run again, longer)."""
    import functools

    from mjxsysid.identify import idlecheck
    from mjxsysid.identify import inference as I

    def wrap(owner, name):
        f = getattr(owner, name, None)
        if f is None:                              # an older commit without it (a run against the code before)
            return

        @functools.wraps(f)
        def run(*args, **kw):
            t = time.perf_counter()
            out = f(*args, **kw)
            dt = time.perf_counter() - t
            PHASES[name] = PHASES.get(name, 0.0) + dt
            if name == "nuts":                     # each call: (logs, seconds), NUTS's first run and its retry
                CALLS.append((len(args[1]), round(dt, 1)))
            return out
        setattr(owner, name, run)
    for name in ("find_modes", "_finish", "_prepare_all", "window_check"):
        wrap(I, name)
    wrap(idlecheck, "run")
    for name in ("targets", "smc", "nuts", "fit", "jacobians", "residuals", "rate_logliks"):
        wrap(I._Logs, name)


def say(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg} | phases {({k: round(v, 1) for k, v in PHASES.items()})}", flush=True)


def retried(posts) -> dict:
    """The logs NUTS ran twice: how many, how many mixed the second time, and why the first did not mix
    (a count per reason: R̂ on a coordinate, or too few effective draws)."""
    from mjxsysid.identify.nuts import RHAT_OK
    again = [p["nuts"] for p in posts if p.get("nuts", {}).get("attempts", 1) > 1]
    why = collections.Counter(("split R̂ on " + n["first"]["why"].rsplit(" on ", 1)[-1].rstrip(")"))
                              if not n["first"]["rhat_max"] < RHAT_OK else "too few effective draws" for n in again)
    return {"logs": len(again), "mixed_second": sum(bool(n["converged"]) for n in again),
            "first_why": dict(why.most_common())}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, default=1000)
    ap.add_argument("--levels", default="clean,x1,x5_white,x20")
    ap.add_argument("--seed", type=int, default=41)
    ap.add_argument("--batch", type=int, default=None, help="logs per batch (default: the library's)")
    ap.add_argument("--workers", type=int, default=16, help="processes that reduce the logs")
    ap.add_argument("--sequential", type=int, default=16, help="logs also identified one at a time")
    ap.add_argument("--warm", action=argparse.BooleanOptionalAction, default=True,
                    help="also time a second, warm pass over every log (--no-warm: the cold pass's phases alone)")
    ap.add_argument("--cache", action="store_true",
                    help="JAX's persistent compilation cache and the exported programs on, as the CLI runs "
                         "(MJXSYSID_JAX_CACHE names the folder); default off: every run compiles and traces")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    from mjxsysid.runtime.xla_flags import GPU_LOOP_GRAPHS, use_xla_flags
    use_xla_flags(GPU_LOOP_GRAPHS)                      # as `mjxsysid decode` runs it; before JAX starts its backend
    if a.cache:
        from mjxsysid.runtime.startup import compilation_cache
        compilation_cache()
    from mjxsysid.identify import inference as I
    from mjxsysid.identify.inference import log_grounded_posteriors
    from mjxsysid.identify.logdata import prepare

    timed_phases()
    t0 = time.perf_counter()
    recs, truth, levels = flights(a.vehicles, a.levels.split(","), a.seed)
    fly_s = time.perf_counter() - t0
    say(f"flew {len(recs)} logs in {fly_s:.0f} s")
    n = len(recs)
    k = min(32, n)
    t0 = time.perf_counter()
    for r in recs[:k]:
        prepare(r)
    prep_one = (time.perf_counter() - t0) / k
    seeds = list(range(n))
    nb = min(n, a.batch or I.LOG_BATCH)
    t0 = time.perf_counter()
    cold = log_grounded_posteriors(recs[:nb], seeds=seeds[:nb], batch=a.batch, workers=a.workers)
    cold_s = time.perf_counter() - t0
    say(f"cold: {nb} logs in {cold_s:.0f} s")
    phases = {k: round(v, 1) for k, v in PHASES.items()}
    nuts_calls = list(CALLS)
    posts, warm_s = cold, float("nan")
    if a.warm:
        PHASES.clear()
        CALLS.clear()
        t0 = time.perf_counter()
        posts = log_grounded_posteriors(recs, seeds=seeds, batch=a.batch, workers=a.workers)
        warm_s = time.perf_counter() - t0
        phases = {k: round(v, 1) for k, v in PHASES.items()}
        nuts_calls = list(CALLS)
        say(f"warm: {n} logs in {warm_s:.0f} s")
    else:
        truth, levels = truth[:nb], levels[:nb]
    m = min(a.sequential, n)
    seq_first = seq_s = float("nan")
    dev = noise = {}
    if m:                                          # --sequential 0: the batched run alone
        t0 = time.perf_counter()
        log_grounded_posteriors(recs[:1], seeds=seeds[:1], batch=1, workers=1)
        seq_first = time.perf_counter() - t0
        t0 = time.perf_counter()
        seq = log_grounded_posteriors(recs[:m], seeds=seeds[:m], batch=1, workers=1)
        seq_s = (time.perf_counter() - t0) / m
        say(f"one at a time: {seq_s:.1f} s a log")
        other = log_grounded_posteriors(recs[:m], seeds=[s + 10_000 for s in seeds[:m]], batch=1, workers=1)
        dev, noise = shifts(seq, posts[:m]), shifts(seq, other)
    ins = inside(posts, truth)
    res = {
        "device": str(jax.devices()[0]), "backend": jax.default_backend(), "jax": jax.__version__,
        "date": time.strftime("%Y-%m-%d"), "logs": len(posts), "levels": sorted(set(levels)), "seconds_of_flight": 10.0,
        "batch": a.batch, "workers": a.workers, "fly_s": round(fly_s, 1),
        "prepare_s_per_log_one_thread": round(prep_one, 4),
        "cold_s": round(cold_s, 1), "cold_logs": len(cold),
        "batched_s": round(warm_s, 1), "batched_phases_s": phases, "nuts_calls_logs_s": nuts_calls, "batched_logs_per_s": round(len(posts) / warm_s, 2),
        "sequential_s_per_log": round(seq_s, 3), "sequential_first_call_s": round(seq_first, 1),
        "speedup": round(seq_s * len(posts) / warm_s, 1),
        "methods": {mm: sum(p["method"] == mm for p in posts) for mm in ("decoded_is", "laplace_is", "smc", "smc_nuts")},
        "nuts_retried": retried(posts),
        "smc_stages_max": max((p.get("smc_stages", 0) for p in posts), default=0),
        "truth_inside_90": round(float(ins.mean()), 3),
        "truth_inside_90_by_level": {lv: round(float(ins[[x == lv for x in levels]].mean()), 3) for lv in sorted(set(levels))},
        "shift_over_width_batched_vs_one_at_a_time": dev,
        "shift_over_width_another_seed": noise,
    }
    res = {k: None if isinstance(v, float) and not np.isfinite(v) else v for k, v in res.items()}  # valid JSON
    for key, val in res.items():
        print(f"{key}: {val}")
    if a.out:
        write_json(Path(a.out), res)


if __name__ == "__main__":
    main()
