"""Would a calibration table refitted on the NUTS-refined posterior's rows hold its coverage, and how much
sharper would it be? Two-fold cross-validation by vehicle on calibration rows (``mjxsysid calibrate-posterior
--collect``): a table fitted on one half of the vehicles, applied to the other half, against the shipped table
(fitted on the SMC's rows) and the raw bands on the same held-out rows.

    python benchmarks/calibration_refit.py ROWS.json [ROWS.json ...] --out docs/runs/measurements/log-grounded/nuts-refit

Writes OUT/summary.json and OUT/results.md. ``--bins``: the table's feature bins (fewer rows than the shipped
table's: 2 by default, against its 4).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def folds(rows: list[dict], k: int = 2):
    """(train, test) pairs: vehicles in pairs (shards i/2 hold the even and the odd ones) split k ways."""
    for f in range(k):
        test = [r for r in rows if (r["vehicle"] // 2) % k == f]
        yield [r for r in rows if (r["vehicle"] // 2) % k != f], test


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+")
    ap.add_argument("--out", required=True)
    ap.add_argument("--bins", type=int, default=2)
    a = ap.parse_args(argv)
    from mjxsysid.experiments.posterior_calibration import evaluate, read_rows
    from mjxsysid.identify.calibrate import load
    from mjxsysid.identify.calibration_fit import fit
    rows = read_rows(a.rows)
    shipped = load()
    evals = {"raw": [], "shipped": [], "refit": []}
    for train, test in folds(rows):
        tab = fit(train, bins=a.bins)
        for name, t in (("raw", None), ("shipped", shipped), ("refit", tab)):
            evals[name].append(evaluate(test, t))
    levels = [lv for lv in evals["raw"][0] if all(lv in e for e in evals["raw"])]
    names = list(evals["raw"][0][levels[0]]["coverage"])
    out = {"rows": len(rows), "methods": sorted({r["method"] for r in rows}), "bins": a.bins,
           "flights": sorted({r.get("flight", "?") for r in rows}), "levels": {}}
    for lv in levels:
        d = {"logs": sum(e[lv]["logs"] for e in evals["raw"])}
        for name, es in evals.items():
            cov = {c: float(np.mean([e[lv]["coverage"][c] for e in es])) for c in names}
            d[name] = {"coverage": float(np.mean(list(cov.values()))), "per_coordinate": cov,
                       "median_width": {c: float(np.mean([e[lv]["median_width"][c] for e in es])) for c in names},
                       "share_under_half": float(np.mean([e[lv]["share_under_half"] for e in es]))}
        d["width_refit_over_shipped"] = float(np.median([d["refit"]["median_width"][c] / d["shipped"]["median_width"][c]
                                                         for c in names]))
        out["levels"][lv] = d
    dst = Path(a.out)
    dst.mkdir(parents=True, exist_ok=True)
    (dst / "summary.json").write_text(json.dumps(out, indent=1))
    md = ["# A calibration table refitted on the NUTS-refined rows (two-fold cross-validation by vehicle)", "",
          f"{out['rows']} rows ({', '.join(out['flights'])}; methods {', '.join(out['methods'])}), {a.bins} bins.", "",
          "| level | logs | raw | shipped table | refitted (held out) | width, refitted / shipped | logs holding < half: shipped / refitted |",
          "|---|---|---|---|---|---|---|"]
    for lv, d in out["levels"].items():
        md.append(f"| {lv} | {d['logs']} | {d['raw']['coverage']:.3f} | {d['shipped']['coverage']:.3f} | "
                  f"{d['refit']['coverage']:.3f} | {d['width_refit_over_shipped']:.2f} | "
                  f"{d['shipped']['share_under_half']:.2f} / {d['refit']['share_under_half']:.2f} |")
    md += ["", "Per coordinate, refitted (held out):", "", "| level | " + " | ".join(names) + " |",
           "|---|" + "---|" * len(names)]
    for lv, d in out["levels"].items():
        md.append(f"| {lv} | " + " | ".join(f"{d['refit']['per_coordinate'][c]:.2f}" for c in names) + " |")
    (dst / "results.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return out


if __name__ == "__main__":
    main()
