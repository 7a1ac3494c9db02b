"""Thrust-to-weight on logs without velocity: can NUTS's entry be as sharp as its error, grouped by the
accelerometer's own noise, if each flight family of the calibration set is held at 90 % on its own? From the
committed rows alone (no flight).

    python benchmarks/no_velocity_families.py [--out docs/runs/measurements/log-grounded/no-velocity-families]

The shipped entry groups these logs by ``acc_nsr``, whose residual holds the drag's misfit at every noise level:
its windows pool clean with × 20, and hold 0.98–0.99 at ±8–12 %. ``acc_noise`` tells the levels apart, but its
windows pooled the figure-eights (the drag error's 90 % quantile 0.003 at clean) with the min-snap flights (0.016)
and left held-out min-snap flights too narrow. Here each window's two sides hold both families at 90 %
(:func:`~mjxsysid.identify.calibration_fit._fit_windows`'s ``families``; the family is the flight's name, which no
log shows). Scored per level on the rows' thrust-to-weight alone: the training rows by family (in sample), NUTS's
held-out min-snap flights (``test_novel``) and the path-per-vehicle check (``minsnap-paths``). Rows: NUTS's, mixed
in thrust-to-weight, without velocity, not vibrating (the vibration stratum takes those).
"""
from __future__ import annotations

import argparse
import collections
import time
from pathlib import Path

import numpy as np

from _bench import emit

RUNS = Path("docs/runs/measurements/log-grounded")
ROWS = RUNS / "nuts-calibration/rows"
PATHS = RUNS / "minsnap-paths/ms_paths.json.xz"
ORDER = ("clean", "x1", "x2", "x5_white", "x10", "x20")


def no_velocity_rows(paths) -> list[dict]:
    """NUTS's rows of ``paths`` whose thrust-to-weight would take the no-velocity entry: no velocity, no vibration,
    chains mixed there."""
    from mjxsysid.experiments.posterior_calibration import read_rows
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.nuts import mixed_coords
    keep = []
    for r in read_rows(paths):
        f = r["features"]
        if r.get("method") != "smc_nuts" or f.get("velocity_used") or f.get("vibration") or "acc_noise" not in f:
            continue
        if r.get("rhat_v") is None or mixed_coords(r["rhat_v"])[L.LOG_TW]:
            keep.append(r)
    return keep


def entry(rows: list[dict], feature: str, logs: int, families: bool) -> dict:
    """Thrust-to-weight's windowed entry fitted on ``rows`` grouped by ``feature`` (NUTS's windows with ``logs``
    logs each), each flight family at 90 % apart where ``families``."""
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.calibration_fit import WINDOWED, _fit_windows
    truth = np.array([r["truth_v"] for r in rows], np.float64)
    bands = np.array([r["bands"] for r in rows], np.float64)
    x = np.array([r["features"][feature] for r in rows], np.float64)
    fam = [r.get("flight") for r in rows] if families else None
    return _fit_windows(L.LOG_TW, truth, bands, x, 0.9, **(WINDOWED["smc_nuts"] | {"logs": logs}), families=fam) | {
        "feature": feature}


def scored(coord: dict, rows: list[dict]) -> dict:
    """Per level of ``rows``: (logs, coverage, median half-width in %) of thrust-to-weight's band under ``coord``."""
    from mjxsysid.identify import logspace as L
    from mjxsysid.identify.calibrate import stretch
    cells = collections.defaultdict(list)
    for r in rows:
        q = np.asarray(r["bands"], np.float64)[:, L.LOG_TW]
        _, k_lo, k_hi = stretch(q, coord, r["features"][coord["feature"]])
        lo, hi = q[1] - k_lo * (q[1] - q[0]), q[1] + k_hi * (q[2] - q[1])
        cells[r["level"]].append((lo <= r["truth_v"][L.LOG_TW] <= hi, 100.0 * np.expm1((hi - lo) / 2)))
    return {lv: (len(cells[lv]), float(np.mean([c for c, _ in cells[lv]])), float(np.median([w for _, w in cells[lv]])))
            for lv in ORDER if lv in cells}


VARIANTS = {"acc_nsr, 300 logs a window (the shipped protocol)": ("acc_nsr", 300, False),
            "acc_nsr, 300, each family at 90 %": ("acc_nsr", 300, True),
            "acc_noise, 300": ("acc_noise", 300, False),
            "acc_noise, 300, each family at 90 %": ("acc_noise", 300, True),
            "acc_noise, 150": ("acc_noise", 150, False),
            "acc_noise, 150, each family at 90 %": ("acc_noise", 150, True)}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    train, held, paths = (no_velocity_rows([p]) for p in (ROWS / "train", ROWS / "held_out", PATHS))
    flights = sorted({r.get("flight") for r in train})
    sets = {**{f"training, {f}": [r for r in train if r.get("flight") == f] for f in flights},
            "held out (test_novel)": held, "a path per vehicle (minsnap-paths)": paths}
    res = {"rows": {k: len(v) for k, v in sets.items()}, "variants": {}}
    for name, (feature, logs, fam) in VARIANTS.items():
        coord = entry(train, feature, logs, fam)
        res["variants"][name] = {k: scored(coord, v) for k, v in sets.items()}
    lines = [f"# Thrust-to-weight without velocity: each flight family at 90 % ({len(train)} training rows)", "",
             f"`python benchmarks/no_velocity_families.py` ({time.perf_counter() - t0:.0f} s, no flight). Each cell: "
             "coverage / median half-width (%), per level.", ""]
    for k, v in sets.items():
        levels = [lv for lv in ORDER if any(r["level"] == lv for r in v)]
        lines += [f"## {k} ({len(v)} logs)", "", "| grouped by | " + " | ".join(levels) + " |", "|---|" + "---|" * len(levels)]
        for name, by_set in res["variants"].items():
            lines.append(f"| {name} | " + " | ".join(f"{c:.2f} / ±{w:.1f}" for _, c, w in by_set[k].values()) + " |")
        lines.append("")
    return emit(a.out, "results", res, lines)


if __name__ == "__main__":
    main()
