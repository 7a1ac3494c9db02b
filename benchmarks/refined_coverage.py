"""The log-grounded posterior's sampler, the SMC alone against the SMC refined by NUTS
(:mod:`mjxsysid.identify.nuts`): coverage of the shipped calibration's 90 % bands and of the raw
bands, their widths, NUTS's convergence and the time, per IMU noise level, on fresh simulated logs
(wide_actuators vehicles, the lag-aware oracle's 10 s lemniscate, body velocity in the log; seed 41 + the
level's place in ``--levels``), batched over the logs.

    OUT=/tmp/cover python benchmarks/refined_coverage.py run 48 clean,x5_white,x1,x20     # one GPU
    python benchmarks/refined_coverage.py summarise /tmp/cover \\
        docs/runs/measurements/log-grounded/nuts-refined

``run`` writes OUT/cover_<level>.json (each log's truth and 5/50/95 % bands, both samplers) after each level;
``summarise`` turns them into summary.json and results.md.
"""
from __future__ import annotations

import glob
import json
import os
import sys
import time
from pathlib import Path

import numpy as np


def _bands(p):
    return (np.percentile(p["v"], [5, 50, 95], 0).round(5).tolist(),
            np.percentile(p["v_raw"], [5, 50, 95], 0).round(5).tolist())


def run(n: int, levels: list[str], out: str) -> None:
    import batched_posterior as B
    from mjxsysid.identify.coords import visible_from_theta
    from mjxsysid.identify.inference import log_grounded_posteriors
    B.timed_phases()
    for k, lv in enumerate(levels):
        t0 = time.perf_counter()
        recs, truth, _ = B.flights(n, [lv], 41 + k)
        tv = np.asarray(visible_from_theta(np.asarray(truth, np.float32)), np.float64).round(5).tolist()
        res = {"level": lv, "truth_v": tv}
        for label, kw in (("smc", {"refine": False}), ("smc_nuts", {})):
            B.PHASES.clear()
            t1 = time.perf_counter()
            posts = log_grounded_posteriors(recs, seeds=list(range(len(recs))), batch=len(recs), workers=8, **kw)
            res[label] = {"seconds": round(time.perf_counter() - t1, 1),
                          "phases": {a: round(b, 1) for a, b in B.PHASES.items()},
                          "methods": [p["method"] for p in posts], "bands": [_bands(p)[0] for p in posts],
                          "raw": [_bands(p)[1] for p in posts], "nuts": [p.get("nuts") for p in posts]}
            cov = np.mean([[lo <= t <= hi for lo, t, hi in zip(b[0], tt, b[2])] for b, tt in zip(res[label]["bands"], tv)])
            B.say(f"{lv} {label}: {len(posts)} logs in {res[label]['seconds']} s, calibrated coverage {cov:.3f}")
        Path(out, f"cover_{lv}.json").write_text(json.dumps(res))
        B.say(f"{lv} done in {time.perf_counter() - t0:.0f} s")


def summarise(src: str, dst: str) -> dict:
    """OUT/cover_*.json -> DST/summary.json and results.md."""
    from mjxsysid.identify.coords import V_NAMES
    levels = {}
    for f in sorted(glob.glob(os.path.join(src, "cover_*.json"))):
        d = json.loads(Path(f).read_text())
        t = np.array(d["truth_v"])
        row = {"logs": len(t)}
        for lab in ("smc", "smc_nuts"):
            b, r = np.array(d[lab]["bands"]), np.array(d[lab]["raw"])
            ins, insr = (b[:, 0] <= t) & (t <= b[:, 2]), (r[:, 0] <= t) & (t <= r[:, 2])
            nu = [x for x in d[lab]["nuts"] if x]
            row[lab] = {"calibrated": round(float(ins.mean()), 3), "raw": round(float(insr.mean()), 3),
                        "calibrated_per_coordinate": dict(zip(V_NAMES, ins.mean(0).round(2).tolist())),
                        "width_calibrated": (b[:, 2] - b[:, 0]).tolist(), "width_raw": (r[:, 2] - r[:, 0]).tolist(),
                        "seconds": d[lab]["seconds"], "phases": d[lab]["phases"],
                        "nuts_reruns": sum(x["thin"] > 1 for x in nu), "nuts_not_mixed": sum(not x["converged"] for x in nu)}
        for kind in ("calibrated", "raw"):
            ratio = np.array(row["smc_nuts"]["width_" + kind]) / np.array(row["smc"]["width_" + kind])
            row["width_ratio_" + kind] = dict(zip(V_NAMES, np.median(ratio, 0).round(2).tolist()))
        for lab in ("smc", "smc_nuts"):
            del row[lab]["width_calibrated"], row[lab]["width_raw"]
        levels[d["level"]] = row
    head = ["level", "logs", "calibrated coverage: SMC → SMC + NUTS", "raw coverage: SMC → SMC + NUTS",
            "band width, SMC + NUTS over SMC (median over coordinates), calibrated / raw", "seconds (GPU, batched): SMC / SMC + NUTS",
            "NUTS run longer / not mixed"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for lv, r in levels.items():
        a, b = r["smc"], r["smc_nuts"]
        lines.append(f"| {lv} | {r['logs']} | {a['calibrated']:.3f} → {b['calibrated']:.3f} | {a['raw']:.3f} → {b['raw']:.3f} | "
                     f"{np.median(list(r['width_ratio_calibrated'].values())):.2f} / {np.median(list(r['width_ratio_raw'].values())):.2f} | "
                     f"{a['seconds']:.0f} / {b['seconds']:.0f} | {b['nuts_reruns']} / {b['nuts_not_mixed']} |")
    cols = ["level", "sampler"] + list(V_NAMES)
    per = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    for lv, r in levels.items():
        for lab in ("smc", "smc_nuts"):
            per.append(f"| {lv} | {lab} | " + " | ".join(f"{x:.2f}" for x in r[lab]["calibrated_per_coordinate"].values()) + " |")
    Path(dst).mkdir(parents=True, exist_ok=True)
    Path(dst, "summary.json").write_text(json.dumps(levels, indent=1) + "\n")
    Path(dst, "results.md").write_text("# The SMC alone against the SMC refined by NUTS\n\n"
                                       "Truth inside the 90 % bands (shipped calibration table; raw: none), fresh simulated logs.\n\n"
                                       + "\n".join(lines) + "\n\n## Calibrated coverage per coordinate\n\n" + "\n".join(per) + "\n")
    return levels


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    if sys.argv[1] == "run":
        run(int(sys.argv[2]), sys.argv[3].split(","), os.environ["OUT"])
    else:
        summarise(sys.argv[2], sys.argv[3])
