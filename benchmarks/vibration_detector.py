"""Does the vibration detector (:mod:`mjxsysid.identify.vibration`) fire on a log exactly when its IMU vibrates?
The flights of committed calibration row files are flown again (seeded: the logs their rows came from), each
reduced as ``decode --log`` reduces it (:func:`~mjxsysid.identify.logdata.prepare`), and the feature
``vibration`` (:func:`~mjxsysid.identify.calibrate.log_features`) counted per level. Rows collected before they
carried that feature take it from their level (:data:`~mjxsysid.experiments.posterior_calibration.VIBRATION_LEVEL`);
this measures whether that is what the detector would have said.

    python benchmarks/vibration_detector.py ROWS.json.xz [...] [--out docs/runs/measurements/log-grounded/vibration-stratum]

Writes OUT/detector.json and OUT/detector.md. CPU: about a minute per piece of 32 vehicles × 7 levels.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from _bench import write_results


def detect(rec: dict) -> bool:
    """Whether ``decode --log`` finds a rotor vibration in a log record (the feature ``vibration``)."""
    from mjxsysid.identify.logdata import prepare, vibrating
    return vibrating(prepare(rec))


def check_file(path: Path) -> dict:
    """One row file's flights flown again -> per level {logs, detected, truths matching the rows'}."""
    from mjxsysid.experiments.posterior_calibration import RESUME_KEYS, VIBRATION_LEVEL, flights, read_json
    from mjxsysid.identify.coords import visible_from_theta
    d = read_json(path)
    truth = {(r["vehicle"], r["level"], r["flight"]): r["truth_v"] for r in d["rows"]}
    settings = {k: d[k] for k in RESUME_KEYS if k in d}
    out: dict = {}
    for rec, vehicle, th, lv, flight in flights(settings):
        row = truth.get((vehicle, lv, flight))
        if row is None:                                   # a log the rows lack (too short, or not yet collected)
            continue
        tv = np.asarray(visible_from_theta(np.asarray(th, np.float32)[None]), np.float64)[0]
        c = out.setdefault(lv, {"logs": 0, "detected": 0, "same_vehicle": 0, "vibrating": lv == VIBRATION_LEVEL})
        c["logs"] += 1
        c["detected"] += detect(rec)
        c["same_vehicle"] += bool(np.allclose(tv, row, atol=2e-3))
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)
    t0 = time.perf_counter()
    res = {}
    for p in a.rows:
        res[Path(p).name] = check_file(Path(p))
        print(Path(p).name, res[Path(p).name], f"{time.perf_counter() - t0:.0f} s", flush=True)
    agree = sum(c["logs"] - c["detected"] if not c["vibrating"] else c["detected"] for f in res.values() for c in f.values())
    total = sum(c["logs"] for f in res.values() for c in f.values())
    lines = ["# The vibration detector against the simulated level", "",
             f"`python benchmarks/vibration_detector.py {' '.join(a.rows)}` "
             f"({time.perf_counter() - t0:.0f} s, CPU). The detector agrees with the level on **{agree} of {total}** logs.", "",
             "| rows | level | logs | detected | the rows' vehicle |", "|---|---|---|---|---|"]
    for f, levels in res.items():
        for lv, c in levels.items():
            lines.append(f"| {f} | {lv} | {c['logs']} | {c['detected']} | {c['same_vehicle']} |")
    print("\n".join(lines))
    summary = {"files": res, "agree": agree, "logs": total}
    if a.out:
        write_results(a.out, "detector", summary, lines)
    return summary


if __name__ == "__main__":
    main()
