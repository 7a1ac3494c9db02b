"""Where NUTS's calibration holds and where it does not, by flight: the figures docs/identify.md quotes for the
over-covering held-out cells, the slow flights and hovers, the motor-map threshold's hovers and thrust-to-weight
without velocity, from the committed rows alone (no flight).

    python benchmarks/calibration_by_flight.py [--out docs/runs/measurements/log-grounded/calibration-by-flight]

1. A three-fold split of NUTS's training rows (:mod:`benchmarks.calibration_strata`'s folds, the shipped
   protocol): mean and least coverage per flight; the slow flights (20 s figure-eight, hover) fitted apart by
   their name, which no log shows; the cells of the logs like the held-out sets' (the oracle's figure-eights with
   velocity, min-snap flights without) against the rest.
2. The motor-map check's statistic: its 99th percentile per flight and level over the rows carrying it, and the
   logs the shipped threshold flags.
3. Logs without velocity: the median of ``acc_nsr`` and ``acc_noise`` per level, thrust-to-weight's 90 %
   error quantile per flight and level (training and held-out rows), and its held-out width and coverage per
   level with velocity and without.
4. Min-snap paths without velocity: a piece flies ``paths`` path draws a level (``MinSnap.random``'s seed is the
   flight's; :func:`~mjxsysid.experiments.posterior_calibration.path_of`), so per row file, level and path,
   thrust-to-weight's 90 % error quantile and the median ``drag_signal``; and per
   level, the correlation of ``drag_signal`` with log |error| over every log without velocity that carries it.
5. Upper bounds: NUTS's table fitted without the slow flights, without the aerodynamic ones, or on the held-out-like
   flights alone (chosen by name, which no log shows), scored on the held-out rows.
6. The held-out cells outside 0.85–0.95, each with its median width over the oracle's.
7. In sample: the shipped fit scored on its own rows per level, and the share of logs whose ρ1 median meets the truth.
"""
from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path

import numpy as np

from _bench import emit
from calibration_strata import fitted, folds, score

RUNS = Path("docs/runs/measurements/log-grounded")
ROWS = RUNS / "nuts-calibration/rows"
SLOW = ("hover", "lemniscate:20")
"""The flights that excite the rates least (their name's prefix)."""


def held_out_like(r: dict) -> bool:
    """A training row like the held-out sets' logs: the oracle's 10 s figure-eight with velocity, or its min-snap
    flight without."""
    vel = bool(r["features"].get("velocity_used"))
    return (r.get("flight") == "lemniscate:10" and vel) or (r.get("flight") == "minsnap:10" and not vel)


def _by_flight(evals: list[dict]) -> dict:
    """Per-flight evaluations of the folds -> {flight: (logs, mean coverage, least coordinate's)}."""
    acc, n = collections.defaultdict(list), collections.Counter()
    for e in evals:
        for k, c in e.items():
            acc[k].append(list(c["coverage"].values()))
            n[k] += c["logs"]
    return {k: (n[k], float(np.nanmean(v)), float(np.nanmin(np.nanmean(v, 0)))) for k, v in acc.items()}


def split(rows: list[dict]) -> dict:
    """Section 1 (the table on two folds, counted on the third)."""
    from mjxsysid.experiments.posterior_calibration import evaluate
    from mjxsysid.identify.calibrate import VIBRATION_COORDS
    from mjxsysid.identify.calibration_fit import WINDOWED
    win, vib = WINDOWED["smc_nuts"], VIBRATION_COORDS["smc_nuts"]
    slow = lambda r: str(r.get("flight", "")).startswith(SLOW)              # noqa: E731
    # the slow rows' own table: too few of them with velocity or vibration for strata of their own
    plain = lambda rs: [dict(r, features=dict(r["features"], velocity_used=False, vibration=False)) for r in rs]  # noqa: E731
    pooled, apart, like, rest = [], [], [], []
    for train, test in folds(rows):
        table = fitted(train, win, vib)
        pooled.append(evaluate(test, table, by="flight"))
        like.append(evaluate([r for r in test if held_out_like(r)], table))
        rest.append(evaluate([r for r in test if not held_out_like(r)], table))
        t_slow = fitted(plain([r for r in train if slow(r)]), win | {"logs": 150}, ())
        t_fast = fitted([r for r in train if not slow(r)], win, vib)
        apart.append(evaluate(plain([r for r in test if slow(r)]), t_slow, by="flight")
                     | evaluate([r for r in test if not slow(r)], t_fast, by="flight"))
    return {"pooled": _by_flight(pooled), "slow_apart": _by_flight(apart),
            "held_out_like": score(like), "rest": score(rest)}


def idle_gains(rows: list[dict]) -> dict:
    """Section 2: per flight and level (rows with every map's statistic), the statistic's 99th percentile and how
    many logs the shipped threshold flags."""
    from mjxsysid.identify.calibrate import load
    from mjxsysid.identify.idlecheck import KEY, MAPS
    threshold = load()[KEY]["threshold"]
    g = collections.defaultdict(list)
    for r in rows:
        f = r["features"]
        if f.get("idle_maps") == len(MAPS) and f.get("idle_gain") is not None:
            g[f"{r.get('flight')}, {r['level']}"].append(f["idle_gain"])
    return {k: (len(v), float(np.quantile(v, 0.99)), int(np.sum(np.array(v) > threshold))) for k, v in sorted(g.items())}


def no_velocity(train: list[dict], held: list[dict]) -> dict:
    """Section 3: features and thrust-to-weight errors of the logs without velocity."""
    out = {"features": {}, "tw_error_q90": {}}
    feats = collections.defaultdict(list)
    for r in train + held:
        if not r["features"].get("velocity_used") and "acc_noise" in r["features"]:
            feats[r["level"]].append((r["features"]["acc_nsr"], r["features"]["acc_noise"]))
    out["features"] = {lv: tuple(np.median(v, 0).round(2).tolist()) for lv, v in sorted(feats.items())}
    err = collections.defaultdict(list)
    for name, rs in (("training", train), ("held out", held)):
        for r in rs:
            if not r["features"].get("velocity_used") and r.get("method") == "smc_nuts":
                err[f"{name} {r.get('flight')}, {r['level']}"].append(abs(r["truth_v"][0] - r["bands"][1][0]))
    out["tw_error_q90"] = {k: (len(v), float(np.quantile(v, 0.9))) for k, v in sorted(err.items())}
    out["tw_held_out"] = tw_by_velocity(held)
    return out


def tw_by_velocity(held: list[dict]) -> dict:
    """Thrust-to-weight on the held-out rows under the shipped table, per level and whether the log carried
    velocity -> {level: {"velocity" / "no velocity": (logs, median half-width %, coverage)}}: the level's median
    width (the top table's) lies between its two halves."""
    from mjxsysid.experiments.posterior_calibration import evaluate
    from mjxsysid.identify.calibrate import load
    table, out = load(), {}
    for lv in dict.fromkeys(r["level"] for r in held):
        ev = evaluate([r for r in held if r["level"] == lv], table, by="velocity")
        out[lv] = {k: (c["logs"], c["tw_width_pct"], c["coverage"]["log_thrust_to_weight"]) for k, c in ev.items()}
    return out


def minsnap_paths() -> dict:
    """Section 4 (NUTS's mixed rows without velocity)."""
    from mjxsysid.experiments.posterior_calibration import path_of, read_json
    per_path, pairs = {}, collections.defaultdict(list)
    files = sorted((ROWS / "train").glob("novel_*")) + sorted((ROWS / "held_out").glob("test_novel*"))
    for f in files:
        settings = read_json(f)
        for r in settings["rows"]:
            if r.get("method") != "smc_nuts" or r["features"].get("drag_signal") is None:
                continue
            e = abs(r["truth_v"][0] - r["bands"][1][0])
            pairs[r["level"]].append((r["features"]["drag_signal"], np.log10(e + 1e-5)))
            if "minsnap" in str(r.get("flight")):
                key = f"{f.name.split('.json')[0]}, {r['level']}, path {path_of(settings, r['vehicle'])}"
                per_path.setdefault(key, []).append((e, r["features"]["drag_signal"]))
    return {"paths": {k: (len(v), float(np.quantile([e for e, _ in v], 0.9)), float(np.median([d for _, d in v])))
                      for k, v in per_path.items()},
            "correlation": {lv: (len(v), float(np.corrcoef(np.array(v).T)[0, 1])) for lv, v in sorted(pairs.items())}}


SUBSETS = {"every flight (shipped)": lambda r: True,
           "without the slow flights": lambda r: not str(r.get("flight", "")).startswith(SLOW),
           "without the aerodynamic flights": lambda r: not r.get("aero"),
           "the held-out-like flights only": held_out_like}
"""Section 5's training subsets, by the flight's name (which no log shows)."""


def nuts_table(rows: list[dict]) -> dict:
    """The shipped table with NUTS's entry fitted on ``rows`` as the release fits it (its windows, vibrating logs
    apart); the SMC's entry and the checks' thresholds stay the shipped ones."""
    from mjxsysid.identify.calibrate import VIBRATION_COORDS
    from mjxsysid.identify.calibration_fit import WINDOWED
    return fitted(rows, WINDOWED["smc_nuts"], VIBRATION_COORDS["smc_nuts"])


def upper_bounds(mixed: list[dict], held: list[dict]) -> dict:
    """Section 5: NUTS's table fitted on subsets of the training rows chosen by flight (:data:`SUBSETS`,
    :func:`nuts_table`), scored on the held-out rows as the top table of docs/identify.md is: what a feature
    telling those flights apart could give at most."""
    from mjxsysid.experiments.posterior_calibration import evaluate
    out = {}
    for name, keep in SUBSETS.items():
        rows = [r for r in mixed if keep(r)]
        out[name] = {"rows": len(rows), **score([evaluate(held, nuts_table(rows))])}
    return out


def cells_outside(path: Path = RUNS / "nuts-calibration/test/evaluation.json") -> list:
    """Section 6: the held-out cells (the top table's, from their evaluation) outside 0.85–0.95, each with its
    median calibrated width over the oracle's (the 90 % quantile of the median's error over the cell's logs)."""
    import json
    ev = json.loads(path.read_text())["calibrated"]
    return [(lv, k, cov, c["median_width"][k] / c["oracle_width"][k]) for lv, c in ev.items()
            for k, cov in c["coverage"].items() if cov is not None and not 0.85 <= cov <= 0.95]


def in_sample(mixed: list[dict]) -> dict:
    """Section 7: NUTS's table fitted on every training row (as shipped) and scored on the same rows, per level
    (the mean over the coordinates and ρ1's), and per level the share of logs whose ρ1 median lies within 10⁻⁴ of
    the truth (a tie no conformal quantile splits)."""
    from mjxsysid.experiments.posterior_calibration import evaluate
    out = {}
    for lv, c in evaluate(mixed, nuts_table(mixed)).items():
        d = np.array([abs(r["truth_v"][1] - r["bands"][1][1]) for r in mixed if r["level"] == lv])
        out[lv] = (c["logs"], float(np.nanmean(list(c["coverage"].values()))), c["coverage"]["rel_effectiveness[0]"],
                   float(np.mean(d <= 1e-4)))
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    from mjxsysid.experiments.posterior_calibration import read_rows
    t0 = time.perf_counter()
    train = read_rows([ROWS / "train"])
    held = read_rows([ROWS / "held_out"])
    mixed = [r for r in train if r.get("method") == "smc_nuts"]
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
    from refit_calibration import window_rows
    res = {"split": split(mixed), "idle_gain_q99": idle_gains(train + window_rows()),
           "no_velocity": no_velocity(train, held), "minsnap_paths": minsnap_paths(), "upper_bounds": upper_bounds(mixed, held),
           "cells_outside": cells_outside(), "in_sample": in_sample(mixed)}
    lines = [f"# NUTS's calibration by flight ({len(mixed)} mixed training rows, {len(held)} held out)", "",
             f"`python benchmarks/calibration_by_flight.py` ({time.perf_counter() - t0:.0f} s, no flight).", "",
             "## 1. Three-fold split: coverage per flight (mean, least coordinate)", "",
             "Each fold's table carries the shipped window and motor-map checks' thresholds, as the held-out rows' "
             "evaluation applies them.", "",
             "| flight | logs | shipped protocol | slow flights fitted apart by name |", "|---|---|---|---|"]
    for k, (n, m, lo) in res["split"]["pooled"].items():
        _, m2, lo2 = res["split"]["slow_apart"].get(k, (0, np.nan, np.nan))
        lines.append(f"| {k} | {n} | {m:.3f} ({lo:.2f}) | {m2:.3f} ({lo2:.2f}) |")
    for name in ("held_out_like", "rest"):
        s = res["split"][name]
        lines.append(f"\n{name.replace('_', '-')}: {s['cells']} of {s['of']} cells within 0.85–0.95, {s['over']} over, "
                     f"{s['under']} under.")
    lines += ["", "## 2. The motor-map check's statistic (linear-map logs)", "",
              "| flight, level | logs | 99th percentile | flagged at the shipped threshold |", "|---|---|---|---|"]
    lines += [f"| {k} | {n} | {q:.2f} | {c} |" for k, (n, q, c) in res["idle_gain_q99"].items()]
    lines += ["", "## 3. Logs without velocity", "", "| level | acc_nsr | acc_noise |", "|---|---|---|"]
    lines += [f"| {lv} | {x:.2f} | {y:.2f} |" for lv, (x, y) in res["no_velocity"]["features"].items()]
    lines += ["", "| rows, flight, level | logs | T/W error, 90 % quantile (log) |", "|---|---|---|"]
    lines += [f"| {k} | {n} | {q:.4f} |" for k, (n, q) in res["no_velocity"]["tw_error_q90"].items()]
    lines += ["", "Thrust-to-weight held out, shipped table: logs, median half-width and coverage, with velocity and without.",
              "", "| level | with velocity | without |", "|---|---|---|"]
    order = ("clean", "x1", "x2", "x5_white", "x5_vibration", "x10", "x20")
    for lv, c in sorted(res["no_velocity"]["tw_held_out"].items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else 99):
        cell = [f"{c[k][0]}: ±{c[k][1]:.1f} %, {c[k][2]:.3f}" if k in c else "—" for k in ("velocity", "no velocity")]
        lines.append(f"| {lv} | {cell[0]} | {cell[1]} |")
    lines += ["", "## 4. Min-snap paths without velocity (a row file's path draws per level)", "",
              "| row file, level, path | logs | T/W error, 90 % quantile (log) | drag_signal, median |", "|---|---|---|---|"]
    lines += [f"| {k} | {n} | {q:.4f} | {d:.2f} |" for k, (n, q, d) in res["minsnap_paths"]["paths"].items()]
    lines += ["", "| level | logs | correlation of drag_signal with log T/W error |", "|---|---|---|"]
    lines += [f"| {lv} | {n} | {c:.2f} |" for lv, (n, c) in res["minsnap_paths"]["correlation"].items()]
    lines += ["", "## 5. Upper bounds: the table fitted on flights chosen by name, scored on the held-out rows", "",
              "| training rows | logs | cells within 0.85–0.95 (of 84) | over | under | the worst |", "|---|---|---|---|---|---|"]
    lines += [f"| {k} | {u['rows']} | {u['cells']} | {u['over']} | {u['under']} | {u['worst']:.3f} |"
              for k, u in res["upper_bounds"].items()]
    out = res["cells_outside"]
    sharp = sum(1 for _, _, cov, r in out if cov > 0.95 and r <= 1.0)
    lines += ["", "## 6. The held-out cells outside 0.85–0.95 (the top table's evaluation)", "",
              f"{len(out)} cells; {sharp} of the {sum(1 for o in out if o[2] > 0.95)} over 0.95 are no wider than the "
              "oracle's band (a fixed width about the median that holds 90 % of the cell).", "",
              "| level | coordinate | coverage | median width / the oracle's |", "|---|---|---|---|"]
    lines += [f"| {lv} | {k} | {cov:.3f} | {r:.2f} |" for lv, k, cov, r in out]
    lines += ["", "## 7. In sample: the table fitted on every training row, scored on them", "",
              "| level | logs | mean coverage | ρ1 | ρ1's median within 10⁻⁴ of the truth |", "|---|---|---|---|---|"]
    lines += [f"| {lv} | {n} | {m:.3f} | {r:.3f} | {t:.2f} |" for lv, (n, m, r, t) in res["in_sample"].items()]
    return emit(a.out, "results", res, lines)


if __name__ == "__main__":
    main()
