"""τ_m under IMU noise with each rate term: the windows, the innovations with and without their vibration whitening.

Flies N vehicles of the wide_actuators prior with the lag-aware oracle (MJX, 10 s lemniscate, as
``benchmarks/log_grounded.py``) at each noise level asked for, and runs the log-grounded posterior on
each flight three ways: ``windows``,
``innovations`` (with the vibration whitening of :mod:`mjxsysid.identify.vibration`) and
``innovations_white`` (the white-noise filter alone, ``prepare(..., vibration=False)``; only where a
vibration was detected, elsewhere it is the same computation). Per level and way: τ_m's median ratio to
the truth and median absolute error, its 90 % coverage and median band width (log units), the roll
authority's error and coverage — of the calibrated draws (the shipped table, fitted on the windows'
rows) and of the raw ones — the logs whose gyro showed a vibration, and the seconds ``prepare`` took.

    python benchmarks/vibration_rates.py --vehicles 8 --levels x5_white,x5_vibration,x20 --out out/vibration_rates.json
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.experiments.log_grounded_coverage import level_flights
from mjxsysid.identify import logdata as LD
from mjxsysid.identify import logspace as L
from mjxsysid.identify.coords import visible_from_theta
from mjxsysid.identify.inference import log_grounded_posteriors
from mjxsysid.identify.vibration import gyro_whiteners
from mjxsysid.rollout.flight import flight_log

WAYS = {"windows": dict(rates="windows"), "innovations": dict(rates="innovations"),
        "innovations_white": dict(rates="innovations", vibration=False)}
QUANTITIES = {"tau_m": L.LOG_TAU_M, "roll_auth": L.LOG_AUTH_X, "a_z": L.LOG_AUTH_Z}


def score(posts, truths) -> dict:
    """τ_m's, the roll authority's and A_z's (authority_total[2]) median ratio, median error, 90 % coverage and band width (log units),
    for the raw draws and the calibrated ones (the shipped table, fitted on the windows' rows)."""
    v_true = np.asarray(visible_from_theta(np.asarray(truths, np.float32)), np.float64)
    out = {}
    for draws in ("v_raw", "v"):
        for name, k in QUANTITIES.items():
            q = np.stack([np.percentile(np.asarray(p[draws], np.float64)[:, k], [5, 50, 95]) for p in posts])
            ratio = np.exp(q[:, 1] - v_true[:, k])
            inside = (q[:, 0] <= v_true[:, k]) & (v_true[:, k] <= q[:, 2])
            out[f"{name}{'_raw' if draws == 'v_raw' else ''}"] = {
                "median_ratio": float(np.median(ratio)), "median_error": float(np.median(np.abs(ratio - 1))),
                "coverage_90": float(inside.mean()), "median_width": float(np.median(q[:, 2] - q[:, 0])),
                "ratios": ratio.round(4).tolist()}
    return out


def _line(lv: str, w: str, s: dict) -> str:
    t, tr, r = s["tau_m"], s["tau_m_raw"], s["roll_auth"]
    return (f"{lv:13s} {w:18s} τ_m ratio {t['median_ratio']:.3f} error {t['median_error']:.3f} inside {t['coverage_90']:.2f} "
            f"(raw {tr['coverage_90']:.2f}) width {t['median_width']:.3f} (raw {tr['median_width']:.3f}) | roll error "
            f"{r['median_error']:.3f} inside {r['coverage_90']:.2f} | A_z raw ratio {s['a_z_raw']['median_ratio']:.3f} "
            f"inside {s['a_z_raw']['coverage_90']:.2f} | vibration {sum(s['vibration'])}/{len(s['vibration'])} "
            f"| NUTS mixed {s['methods'].count('smc_nuts')}/{len(s['methods'])} | prepare {s['prepare_s']:.2f} s, "
            f"posterior {s['posterior_s']:.1f} s")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, default=8)
    ap.add_argument("--levels", default="x5_white,x5_vibration,x20")
    ap.add_argument("--ways", default=",".join(WAYS))
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    ways = a.ways.split(",")
    bad = [w for w in ways if w not in WAYS]
    if bad:
        raise SystemExit(f"--ways: unknown {bad}; choose from {list(WAYS)}")
    th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(a.seed), a.vehicles))
    res = {"command": "python benchmarks/vibration_rates.py " + " ".join(f"--{k} {v}" for k, v in vars(a).items() if v),
           "calibration": None, "levels": []}
    for lv in a.levels.split(","):
        frame, flown = level_flights(th, lv, a.seed)
        recs = [flight_log(frame, i) for i in flown]
        row = {"level": lv, "flown": len(flown), "ways": {}}
        found = [bool(gyro_whiteners(r["imu"][LD.first_row(len(r["motor"])):, :3], LD.DT)[2].any()) for r in recs]
        for w in ways:
            if w == "innovations_white" and not any(found):
                continue                     # no vibration: the same computation as "innovations"
            t0 = time.perf_counter()
            datas = [LD.prepare(r, **WAYS[w]) for r in recs]
            prep = (time.perf_counter() - t0) / len(recs)
            t0 = time.perf_counter()
            posts = log_grounded_posteriors(datas, seeds=[int(i) for i in flown])
            row["ways"][w] = {**score(posts, th[flown]), "vibration": found, "prepare_s": prep,
                              "methods": [p["method"] for p in posts],
                              "posterior_s": (time.perf_counter() - t0) / len(recs)}
            print(_line(lv, w, row["ways"][w]), flush=True)
        res["levels"].append(row)
        if a.out:
            Path(a.out).parent.mkdir(parents=True, exist_ok=True)
            Path(a.out).write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
