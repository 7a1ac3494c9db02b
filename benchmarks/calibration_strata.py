"""Which coordinates should a vibrating log's calibration be fitted apart for? A three-fold split by vehicle of
NUTS's training rows (the shipped windows, :data:`~mjxsysid.identify.calibration_fit.WINDOWED`): each variant's
table fitted on two folds, its coverage counted on the third, per level and coordinate (5 levels × 12 × 3 folds).
The held-out rows are not read: the variant is chosen here, then evaluated once (tools/refit_calibration.py).
``--method smc --rows docs/runs/measurements/log-grounded/calibrated/rows/cal*.json.xz``: the SMC's table, in bins.

    python benchmarks/calibration_strata.py [--out docs/runs/measurements/log-grounded/vibration-stratum]

Variants: none (one table for every log), the rate coordinates apart (thrust-to-weight pooled), every
coordinate apart (:data:`~mjxsysid.identify.calibrate.VIBRATION_COORDS` says which each sampler ships). Writes
OUT/strata_METHOD.md and OUT/strata_METHOD.json.

    python benchmarks/calibration_strata.py --window-logs 150 200 300 400

The windows' size instead (NUTS's table, every coordinate apart as shipped): each size's cells on the same split.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from _bench import write_results

ROWS = Path("docs/runs/measurements/log-grounded/nuts-calibration/rows/train")
BAND = (0.85, 0.95)
"""The target band of a cell's 90 % coverage."""


def folds(rows: list[dict], k: int = 3):
    """(train, test) pairs split k ways by vehicle index (a vehicle's logs at every level fall in one fold)."""
    for f in range(k):
        yield [r for r in rows if r["vehicle"] % k != f], [r for r in rows if r["vehicle"] % k == f]


def score(evals: list[dict]) -> dict:
    """Per-level evaluations (:func:`~mjxsysid.experiments.posterior_calibration.evaluate`, one per fold) ->
    cells within :data:`BAND`, over, under (cells without a seen log left out) and the worst coverage."""
    cov = np.array([v for e in evals for c in e.values() for v in c["coverage"].values()], np.float64)
    cov = cov[np.isfinite(cov)]
    return {"cells": int(np.sum((cov >= BAND[0]) & (cov <= BAND[1]))), "of": int(cov.size),
            "over": int(np.sum(cov > BAND[1])), "under": int(np.sum(cov < BAND[0])), "worst": float(cov.min())}


def fitted(rows: list[dict], windows: dict | None, vibration: tuple, method: str = "smc_nuts") -> dict:
    """The shipped table with ``method``'s entry fitted on ``rows`` (``windows``, ``vibration``: :func:`~mjxsysid.
    identify.calibration_fit.fit`'s): the window check's and the motor-map check's thresholds are the shipped ones,
    so a fold is scored with the checks the held-out evaluation applies."""
    from mjxsysid.identify.calibrate import load, with_method
    from mjxsysid.identify.calibration_fit import fit
    return with_method(load(), fit(rows, windows=windows, vibration=vibration), method)


def split_evals(rows: list[dict], windows: dict | None, vibration: tuple, method: str = "smc_nuts") -> list[dict]:
    """Per fold: the table fitted on the other two (:func:`fitted`) evaluated per level on this one."""
    from mjxsysid.experiments.posterior_calibration import evaluate
    return [evaluate(test, fitted(train, windows, vibration, method)) for train, test in folds(rows)]


def window_sizes(paths, sizes) -> dict:
    """NUTS's table in windows of each of ``sizes`` logs (the shipped strata), scored on the three-fold split."""
    from mjxsysid.experiments.posterior_calibration import read_rows
    from mjxsysid.identify.calibrate import VIBRATION_COORDS
    from mjxsysid.identify.calibration_fit import WINDOWED
    rows = [r for r in read_rows(paths) if r.get("method") == "smc_nuts"]
    out = {}
    for n in sizes:
        out[n] = score(split_evals(rows, dict(WINDOWED["smc_nuts"], logs=int(n)), VIBRATION_COORDS["smc_nuts"]))
        print(f"{n} logs a window: {out[n]['cells']} of {out[n]['of']} cells, {out[n]['over']} over, "
              f"{out[n]['under']} under, the worst {out[n]['worst']:.3f}", flush=True)
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", nargs="+", default=[str(ROWS)])
    ap.add_argument("--method", default="smc_nuts", help="the sampler whose rows and fit (windows or bins) are split")
    ap.add_argument("--out", default=None)
    ap.add_argument("--window-logs", type=int, nargs="+", default=None,
                    help="compare these window sizes (logs a window) instead of the strata")
    a = ap.parse_args(argv)
    if a.window_logs:
        return window_sizes(a.rows, a.window_logs)
    from mjxsysid.experiments.posterior_calibration import read_rows
    from mjxsysid.identify.calibration_fit import WINDOWED
    from mjxsysid.identify.logspace import N_V
    t0 = time.perf_counter()
    rows = [r for r in read_rows(a.rows) if r.get("method") == a.method]
    variants = {"none": (), "rate coordinates apart": tuple(range(1, N_V)), "every coordinate apart": tuple(range(N_V))}
    out = {"rows": len(rows), "vibrating": int(sum(r["features"]["vibration"] for r in rows)), "variants": {}}
    for name, coords in variants.items():
        evals = split_evals(rows, WINDOWED.get(a.method), coords, a.method)
        vib_width = [list(e["x5_vibration"]["median_width"].values()) for e in evals]
        out["variants"][name] = score(evals) | {"vibration_width": np.mean(vib_width, 0).tolist(),
                                                "tw_width_pct": {lv: float(np.mean([e[lv]["tw_width_pct"] for e in evals]))
                                                                 for lv in evals[0]}}
    base = np.array(out["variants"]["none"]["vibration_width"])
    lines = [f"# Vibrating logs calibrated apart: a three-fold split of {out['rows']} training rows of `{a.method}`", "",
             f"{out['vibrating']} of the rows vibrate. Cells: level × coordinate × fold, coverage within "
             f"{BAND[0]}–{BAND[1]}; each fold's table carries the shipped window and motor-map checks' thresholds. "
             f"`python benchmarks/calibration_strata.py --method {a.method}` "
             f"({time.perf_counter() - t0:.0f} s).", "",
             "| variant | cells | over | under | the worst | × 5 vibration's widths / none's (median) | T/W width, clean / × 5 vibration |",
             "|---|---|---|---|---|---|---|"]
    for name, v in out["variants"].items():
        ratio = float(np.median(np.array(v["vibration_width"]) / np.maximum(base, 1e-12)))
        tw = v["tw_width_pct"]
        lines.append(f"| {name} | {v['cells']} of {v['of']} | {v['over']} | {v['under']} | {v['worst']:.3f} | "
                     f"{ratio:.2f} | ±{tw['clean']:.1f} / ±{tw['x5_vibration']:.1f} % |")
    print("\n".join(lines))
    if a.out:
        write_results(a.out, f"strata_{a.method}", out, lines)
    return out


if __name__ == "__main__":
    main()
