"""Logs whose NUTS chains did not mix: the SMC's narrow bands against the prior's. Vehicles of a prior, the
lag-aware oracle, a clean IMU, each flight of ``--flights``; per log the default posterior (the SMC refined by
NUTS, the shipped calibration); per quantity the share of logs whose final 90 % band holds the truth and the
share reported seen, against the same posterior with the unmixed coordinates left at the SMC's calibrated
draws (before :func:`mjxsysid.identify.nuts.unmixed_not_seen` drew them from the prior).

    python benchmarks/unmixed_bands.py --vehicles 6 --flights hover:8,lemniscate:10 --out out/unmixed
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

QUANTITIES = {"T/W": 0, "τ_m": 4, "A_x": 5, "A_y": 6, "A_z": 7, "yaw": 8}


def bands(v) -> np.ndarray:
    """Draws (S, 12) -> their 5 and 95 % quantiles (2, 12)."""
    return np.percentile(np.asarray(v, np.float64), [5, 95], 0)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=6)
    ap.add_argument("--prior", default="wide_actuators")
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--flights", default="hover:8,lemniscate:10")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args(argv)
    import jax
    from mjxsysid import theta as P
    from mjxsysid.experiments.posterior_calibration import parse_reference
    from mjxsysid.identify.calibrate import calibrate, for_method, load
    from mjxsysid.identify.coords import PHYSICAL_PRIOR, visible_from_theta
    from mjxsysid.identify.inference import log_grounded_posterior
    from mjxsysid.identify.logdata import prepare
    from mjxsysid.rollout.flight import flight_log, fly_vehicles
    th = np.asarray(P.get_prior(a.prior).sample(jax.random.PRNGKey(a.seed), a.vehicles))
    truth = np.asarray(visible_from_theta(th.astype(np.float32)), np.float64)
    table, res = load(), {"vehicles": a.vehicles, "prior": a.prior, "seed": a.seed, "logs": []}
    for fl in a.flights.split(","):
        flights, m, _ = fly_vehicles(th, controller="oracle", seed=a.seed, **parse_reference(fl))
        for i in np.flatnonzero(~np.asarray(m["failed"], bool)):
            t0 = time.perf_counter()
            post = log_grounded_posterior(prepare(flight_log(flights.frame, int(i))), seed=int(i))
            before, _ = calibrate(post["v_raw"], post["features"], post["weights"], for_method(table, post["method"]),
                                  PHYSICAL_PRIOR, rng=int(i))
            rec = {"flight": fl, "vehicle": int(i), "method": post["method"], "seconds": round(time.perf_counter() - t0, 1),
                   "rhat_v": post.get("nuts", {}).get("rhat_v")}
            for name, v in (("after", post["v"]), ("before", before)):
                q = bands(v)
                rec[name] = {k: {"inside": bool(q[0, j] <= truth[i, j] <= q[1, j]), "log_width": float(q[1, j] - q[0, j])}
                             for k, j in QUANTITIES.items()}
            rec["seen"] = {k: bool(post["calibration"]["seen"][j]) for k, j in QUANTITIES.items()}
            res["logs"].append(rec)
            print(json.dumps({k: rec[k] for k in ("flight", "vehicle", "method", "seconds")}), flush=True)
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "results.json").write_text(json.dumps(res, indent=1) + "\n")
    md = ["| flight | logs (mixed) | quantity | inside, before | inside, now | seen, now | median log width, before → now |",
          "|---|---|---|---|---|---|---|"]
    for fl in a.flights.split(","):
        rs = [r for r in res["logs"] if r["flight"] == fl]
        mixed = sum(r["method"] == "smc_nuts" for r in rs)
        for k in QUANTITIES:
            b, n = (sum(r[w][k]["inside"] for r in rs) for w in ("before", "after"))
            wb, wn = (np.median([r[w][k]["log_width"] for r in rs]) for w in ("before", "after"))
            md.append(f"| {fl} | {len(rs)} ({mixed}) | {k} | {b}/{len(rs)} | {n}/{len(rs)} | "
                      f"{sum(r['seen'][k] for r in rs)}/{len(rs)} | {wb:.3f} → {wn:.3f} |")
    (a.out / "results.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))
    return res


if __name__ == "__main__":
    main()
