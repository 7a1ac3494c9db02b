"""Refit the shipped posterior calibration from the committed rows, and evaluate it where it was not fitted:
one command for what ``mjxsysid calibrate-posterior --fit/--evaluate`` does in six calls.

    python tools/refit_calibration.py            # writes mjxsysid/pretrained/posterior_calibration.json
    python tools/refit_calibration.py --table /tmp/t.json --evaluations /tmp/ev   # a trial, nothing shipped
    python tools/refit_calibration.py --table /tmp/t.json --evaluations /tmp/ev --no-figures   # its numbers only

1. The SMC's (pooled) table on docs/runs/measurements/log-grounded/calibrated/rows/cal*.json.xz.
2. NUTS's table (``--method smc_nuts``) on nuts-calibration/rows/train, added to it.
3. Held out, each sampler's coverage recorded in its own table's provenance: calibrated/rows/test*.json.xz
   (calibrated/test), the held-out families (calibrated/families), nuts-calibration/rows/held_out
   (nuts-calibration/test).
4. The misfit set (nuts-calibration/rows/misfit: an idle offset), evaluated apart, never recorded.

The window check's and the motor-map check's thresholds: the 0.99 quantile of each statistic over the training
rows that carry it and the checks' own 200 simulated logs (window-check/simulated.json.gz).

The notes (where the rows came from) are kept from the table being replaced.
"""
from __future__ import annotations

import argparse
import os
import json
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RUNS = Path("docs/runs/measurements/log-grounded")
SMC_ROWS = [RUNS / "calibrated/rows" / f"{n}.json.xz" for n in ("cal", "cal_velocity", "cal_aero")]
NUTS_ROWS = RUNS / "nuts-calibration/rows"
HELD_OUT = [([RUNS / "calibrated/rows" / f"{n}.json.xz" for n in ("test", "test_velocity", "test_aero")],
             RUNS / "calibrated/test"),
            ([RUNS / "calibrated/rows/fam.json.xz"], RUNS / "calibrated/families"),
            ([NUTS_ROWS / "held_out"], RUNS / "nuts-calibration/test")]
MISFIT = ([NUTS_ROWS / "misfit"], RUNS / "nuts-calibration/misfit")
WINDOW_SET = RUNS / "window-check/simulated.json.gz"
"""The window check's own simulated logs (benchmarks/window_check.py: 200 logs, hovers and slow figure-eights
among them, which the calibration rows carrying the statistic lack): pooled with those rows for its threshold."""


def window_rows(path: Path = WINDOW_SET) -> list[dict]:
    """The checks' simulated logs at ``path`` as calibration rows ({level, flight, features: {window_shift,
    idle_gain, idle_maps}}, each None where that check did not run)."""
    from mjxsysid.experiments.posterior_calibration import read_json
    rows = read_json(path)["rows"]
    return [{"level": r["level"], "flight": r["flight"],
             "features": {"window_shift": r.get("shift"), "idle_gain": r.get("idle_gain"),
                          "idle_maps": r.get("idle_maps")}} for r in rows]


def _notes(path: Path) -> tuple[str, str]:
    """The pooled table's and NUTS's table's provenance notes in the table at ``path`` ('' where none)."""
    if not path.is_file():
        return "", ""
    t = json.loads(path.read_text())
    return (t.get("provenance", {}).get("note", ""),
            t.get("by_method", {}).get("smc_nuts", {}).get("provenance", {}).get("note", ""))


def main(argv=None) -> None:
    from mjxsysid.experiments.posterior_calibration import fit_file, mean_coverage, report
    from mjxsysid.identify.calibrate import SHIPPED
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--table", type=Path, default=SHIPPED, help="where the table is written (default the shipped one)")
    ap.add_argument("--evaluations", type=Path, default=None,
                    help="a folder for the evaluations (default each one's docs/runs folder)")
    ap.add_argument("--no-figures", action="store_true", help="the evaluations' numbers only (no coverage_width.png, ranks.png)")
    ap.add_argument("--nuts-note", default=None, help="NUTS's rows' provenance note (default the replaced table's)")
    a = ap.parse_args(argv)
    a.table = a.table.resolve()
    os.chdir(ROOT)                                   # the held-out records are keyed by the folder, relative
    smc_note, nuts_note = _notes(SHIPPED)
    t0 = time.perf_counter()

    def out(folder: Path) -> Path:
        return folder if a.evaluations is None else a.evaluations / folder.relative_to(RUNS)
    fit_file(SMC_ROWS, a.table, smc_note, command="python tools/refit_calibration.py (step 1)")
    fit_file([NUTS_ROWS / "train"], a.table, a.nuts_note or nuts_note, method="smc_nuts", base=a.table,
             command="python tools/refit_calibration.py (step 2)", window_rows=window_rows())
    print(f"fitted both tables in {time.perf_counter() - t0:.1f} s -> {a.table}", flush=True)
    for paths, folder in HELD_OUT:
        res = report(paths, a.table, out(folder), record=True, figures=not a.no_figures)
        print(f"{folder}: {res['rows']} logs, mean coverage {mean_coverage(res['calibrated'])}", flush=True)
    res = report(MISFIT[0], a.table, out(MISFIT[1]), figures=not a.no_figures)
    print(f"{MISFIT[1]} (apart): {res['rows']} logs, mean coverage {mean_coverage(res['calibrated'])}", flush=True)
    print(f"done in {time.perf_counter() - t0:.0f} s", flush=True)


if __name__ == "__main__":
    main()
