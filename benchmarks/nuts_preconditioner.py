"""NUTS preconditioned by the SMC's draws (what the posterior does) against NUTS preconditioned by the Laplace
proposal's draws (no SMC): do the chains mix, and at what cost?

    python benchmarks/nuts_preconditioner.py --vehicles 3 --out docs/runs/measurements/log-grounded/nuts_preconditioner.json

The same logs both ways: ``wide_actuators`` vehicles flown by the oracle on the first calibration reference at
× 1, × 5 white and × 20, seed 31, with velocity (:func:`mjxsysid.experiments.posterior_calibration.flights`). Each
log's posterior runs with ``force_smc`` and NUTS's refinement, uncalibrated. For the Laplace arm, ``_Logs.smc`` is
replaced by draws of the log's Laplace Student-t (uniform weights): NUTS's preconditioner and the fallback draws
then come from the Laplace proposal, and nothing else changes. One process, CPU.
"""
from __future__ import annotations

import argparse
import datetime
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def laplace_smc(self, idx, keys, y0, ld, w, qv, qn, lap, prior, n_mcmc, max_stages):
    """A stand-in for ``_Logs.smc``: each log's Laplace draws, as many as the SMC's particles, equally weighted."""
    n, p = len(idx), y0.shape[1]
    pts = np.stack([q.sample(np.random.default_rng(int(k[1])), p) for q, k in zip(lap, keys)]).astype(np.float32)
    return pts, np.ones((n, p), np.float32), np.ones(n), np.zeros(n, int), np.zeros(n), np.zeros(n)


def run(arm: str, settings: dict) -> list[dict]:
    """Every log of ``settings`` through the posterior with NUTS preconditioned by ``arm`` ('smc' or 'laplace')."""
    from mjxsysid.experiments.posterior_calibration import flights
    from mjxsysid.identify.batched import _Logs
    from mjxsysid.identify.inference import log_grounded_posterior
    real = _Logs.smc
    _Logs.smc = laplace_smc if arm == "laplace" else real
    out = []
    try:
        for rec, vehicle, _, level, _ in flights(settings):
            t0 = time.perf_counter()
            p = log_grounded_posterior(rec, seed=vehicle, calibration=None, force_smc=True)
            n = p.get("nuts", {})
            r = {"arm": arm, "level": level, "vehicle": vehicle, "method": p["method"], "attempts": n.get("attempts"),
                 "converged": n.get("converged"), "rhat_max": n.get("rhat_max"), "ess_bulk_min": n.get("ess_bulk_min"),
                 "first_why": n.get("first", {}).get("why"), "seconds": round(time.perf_counter() - t0, 1)}
            print(json.dumps(r), file=sys.stderr, flush=True)
            out.append(r)
    finally:
        _Logs.smc = real
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=3, help="vehicles per level (default 3)")
    ap.add_argument("--levels", default="x1,x5_white,x20", help="noise levels, comma-separated")
    ap.add_argument("--out", type=Path, default=None, help="write the results as JSON")
    a = ap.parse_args(argv)
    from mjxsysid.experiments.posterior_calibration import REFERENCES
    settings = {"prior": "wide_actuators", "vehicles": a.vehicles, "seed": 31, "shard": None,
                "levels": a.levels.split(","), "references": list(REFERENCES)[:1], "velocity": True}
    rows = run("laplace", settings) + run("smc", settings)
    lines = ["| NUTS preconditioned by | logs | mixed at the first run | mixed after the retry | median s per log |",
             "|---|---|---|---|---|"]
    for arm, name in (("smc", "the SMC's draws (shipped)"), ("laplace", "the Laplace proposal's draws")):
        rs = [r for r in rows if r["arm"] == arm]
        first = sum(bool(r["converged"]) and r["attempts"] == 1 for r in rs)
        lines.append(f"| {name} | {len(rs)} | {first} | {sum(bool(r['converged']) for r in rs)} | "
                     f"{np.median([r['seconds'] for r in rs]):.1f} |")
    print("\n".join(lines))
    if a.out:
        from _bench import write_json
        write_json(a.out, {"date": datetime.date.today().isoformat(), "machine": platform.platform(),
                           "command": "python benchmarks/nuts_preconditioner.py " + " ".join(argv or sys.argv[1:]),
                           "settings": settings, "rows": rows, "table": lines})
    return 0


if __name__ == "__main__":
    sys.exit(main())
