"""Another motor model: the raw and calibrated log-grounded posterior on MJX flights whose static motor map
has an idle offset (``SimConfig.motor_idle``, ``motor_kappa``) against the same flights with the map θ
describes. Vehicles of a prior, the lag-aware oracle, a clean IMU, each flight of ``--flights``; per map and
flight: the median ratio of the posterior median to the truth (T/W, τ_m, the roll/pitch authorities, the yaw
authority) and the share of logs whose calibrated (shipped table) and raw 90 % bands hold the truth.

    python benchmarks/motor_map.py --vehicles 6 --maps 0.1/1 --out out/motor_map [--refine]
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

QUANTITIES = {"T/W": 0, "τ_m": 4, "A_x": 5, "A_y": 6, "yaw": 8}
"""Reported quantity -> its visible coordinate (all logarithms: a ratio to the truth is exp of the difference)."""


def summarise(rows: list[dict], table: dict | None) -> dict:
    """Per quantity: the median ratio to the truth over ``rows``, and the share of the rows whose
    band (``table``'s; None: raw) holds the truth among those that report it seen."""
    from mjxsysid.experiments.posterior_calibration import calibrated_bands
    tv = np.array([r["truth_v"] for r in rows])
    med = np.array([r["bands"][1] for r in rows])
    band, ok = zip(*(calibrated_bands(r, table) for r in rows))
    band, ok = np.array(band), np.array(ok)
    inside = (band[:, 0] <= tv) & (tv <= band[:, 1])
    out = {}
    for name, j in QUANTITIES.items():
        seen = ok[:, j]
        out[name] = {"ratio": float(np.exp(np.median(med[:, j] - tv[:, j]))),
                     "held": int((inside[:, j] & seen).sum()), "seen": int(seen.sum())}
    return out


def markdown(res: dict) -> list[str]:
    """The table: a row per map × flight; per quantity 'median ratio (held/seen calibrated, raw held)'."""
    head = "| motor map | flight | logs | " + " | ".join(QUANTITIES) + " |"
    lines = [head, "|---" * (3 + len(QUANTITIES)) + "|"]
    for key, r in res["groups"].items():
        mp, fl = key.split(" | ")
        cells = [f"{r['cal'][q]['ratio']:.2f} ({r['cal'][q]['held']}/{r['cal'][q]['seen']}, raw {r['raw'][q]['held']})"
                 for q in QUANTITIES]
        lines.append(f"| {mp} | {fl} | {r['logs']} | " + " | ".join(cells) + " |")
    return lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=6)
    ap.add_argument("--prior", default="wide_actuators")
    ap.add_argument("--seed", type=int, default=12)
    ap.add_argument("--flights", default="hover:8,lemniscate:10")
    ap.add_argument("--maps", default="0.1/1", help="the other maps, comma-separated IDLE/KAPPA "
                    "(SimConfig.motor_idle / motor_kappa); θ's map (0/1) is always flown first")
    ap.add_argument("--particles", type=int, default=None, help="SMC particles (default the posterior's)")
    ap.add_argument("--refine", action="store_true", help="refine the SMC's draws by NUTS (slow on a CPU)")
    ap.add_argument("--out", type=Path, required=True)
    a = ap.parse_args()
    from mjxsysid.experiments.posterior_calibration import collect
    from mjxsysid.identify import posterior_config as pc
    from mjxsysid.identify.calibrate import load
    pc.DEFAULT = pc.DEFAULT.replace(refine=a.refine, **({"particles": a.particles} if a.particles else {}))
    maps = {"θ's (off)": (0.0, 1.0)}
    for m in a.maps.split(","):
        idle, kappa = (float(x) for x in m.split("/"))
        maps[f"idle {idle:g}, κ {kappa:g}"] = (idle, kappa)
    table = load(None)
    res = {"vehicles": a.vehicles, "prior": a.prior, "seed": a.seed, "flights": a.flights,
           "posterior": {"refine": a.refine, "particles": pc.DEFAULT.particles}, "groups": {}}
    for label, (idle, kappa) in maps.items():
        t0 = time.perf_counter()
        name = "off" if idle == 0.0 and kappa == 1.0 else f"idle{idle:g}_kappa{kappa:g}"
        got = collect(prior=a.prior, vehicles=a.vehicles, levels=("clean",), seed=a.seed, out=a.out / f"{name}.json",
                      references=tuple(a.flights.split(",")), motor_idle=idle, motor_kappa=kappa)
        for fl in a.flights.split(","):
            rows = [r for r in got["rows"] if r["flight"].split(" ")[0] == fl]
            res["groups"][f"{label} | {fl}"] = {"logs": len(rows), "cal": summarise(rows, table),
                                                "raw": summarise(rows, None)}
        res[f"seconds {label}"] = round(time.perf_counter() - t0, 1)
    (a.out / "summary.json").write_text(json.dumps(res, indent=1) + "\n")
    print("\n".join(markdown(res)))


if __name__ == "__main__":
    main()
