"""The log-grounded posterior's coverage on simulated flights: N vehicles of a prior flown by the
lag-aware oracle (10 s lemniscate) at each IMU noise level of :data:`mjxsysid.uses.imu_noise.LEVELS`,
each flight identified from its IMU and motor commands alone; per log-identifiable quantity, whether
the truth is inside the 90 % band, the band's width and the seconds per log.

Run by ``python benchmarks/log_grounded.py`` (its docstring gives the commands): shards of one draw
(:func:`shard`) in parallel processes, joined by :func:`merge`; :func:`summarise` tables a folder of
runs (one per prior or held-out family).
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from mjxsysid.identify.coords import LOG_NAMES, log_quantities
from mjxsysid.identify.inference import log_grounded_posterior
from mjxsysid.identify.logdata import RATES
from mjxsysid.rollout.flight import flight_log, fly_vehicles
from mjxsysid.sim import Quadrotor, SimConfig
from mjxsysid.uses.imu_noise import LEVELS


def shard(theta, spec: str | None, seed: int):
    """Every K-th vehicle from the I-th of ``theta`` (n, 19) for ``spec`` "I/K" (parallel runs of one draw,
    joined afterwards; None: all) -> (θ of the shard, their indices in the draw, the flights' seed: another
    noise draw per shard, ``seed + 1000 I``). A malformed spec is a ValueError naming it."""
    index = np.arange(len(theta))
    if spec is None:
        return theta, index, seed
    try:
        i, k = (int(x) for x in spec.split("/"))
        if not 0 <= i < k:
            raise ValueError
    except ValueError:
        raise ValueError(f"--shard {spec!r}: expected I/K with 0 <= I < K, e.g. 0/8") from None
    index = index[i::k]
    return theta[index], index, seed + 1000 * i


def level_flights(theta, level: str, seed: int):
    """Fly θ (n, 19) with the lag-aware oracle on a 10 s lemniscate at the IMU noise ``level`` of
    :data:`mjxsysid.uses.imu_noise.LEVELS` -> (the flights' Frame (n, T, ...), the indices of those
    that did not fail)."""
    fl, m, _ = fly_vehicles(theta, controller="oracle", reference="lemniscate", period=10.0,
                            sim=Quadrotor(SimConfig(**LEVELS[level])), seed=seed)
    return fl.frame, np.flatnonzero(~np.asarray(m["failed"], bool))


def run_level(th, level: str, seed: int, index=None, rates: str = RATES, velocity: bool = True) -> dict:
    """Fly ``th`` (n, 19) at noise ``level`` and identify each flight; ``index`` (n,): the
    vehicles' indices in the whole draw (default 0..n-1; the posterior's seed is the index); ``rates``:
    the posterior's rate term; ``velocity``: whether the logs carry the body velocity (the drag's term)."""
    index = np.arange(len(th)) if index is None else np.asarray(index)
    frame, flown = level_flights(th, level, seed)
    rows = []
    for i in flown:
        rec = flight_log(frame, i)
        if not velocity:
            rec.pop("velocity_body")
        t0 = time.perf_counter()
        post = log_grounded_posterior(rec, None, seed=int(index[i]), rates=rates)
        sec = time.perf_counter() - t0
        q, tq = log_quantities(post["theta"]), log_quantities(th[i])
        lo, med, hi = np.percentile(q, [5, 50, 95], 0)
        pos = np.all(q > 0, 0) & (tq > 0)
        width = np.where(pos, np.log(np.maximum(hi, 1e-30) / np.maximum(lo, 1e-30)), hi - lo)
        rows.append({"vehicle": int(index[i]), "seconds": sec, "method": post["method"],
                     "inside": ((lo <= tq) & (tq <= hi)).tolist(), "width": width.tolist(),
                     "rel_error_median": np.abs(med / tq - 1).tolist()})
    return level_summary(level, rows)


def level_summary(level: str, rows: list) -> dict:
    """One noise level's coverage, median widths, errors and seconds from its per-flight rows."""
    if not rows:
        raise ValueError(f"level {level}: no flight to identify (every vehicle failed)")
    inside = np.array([r["inside"] for r in rows])
    return {"level": level, "sim": LEVELS[level], "flown": len(rows),
            "coverage_90": dict(zip(LOG_NAMES, inside.mean(0).round(3).tolist())),
            "median_width": dict(zip(LOG_NAMES, np.median([r["width"] for r in rows], 0).round(4).tolist())),
            "median_rel_error": dict(zip(LOG_NAMES, np.median([r["rel_error_median"] for r in rows], 0).round(4).tolist())),
            "seconds_median": float(np.median([r["seconds"] for r in rows])),
            "methods": {k: sum(r["method"] == k for r in rows) for k in ("decoded_is", "laplace_is", "smc", "smc_nuts")},
            "rows": rows}


def figure(res: dict, path) -> None:
    """Coverage of each log-identifiable quantity's 90 % band at each noise level (bars), the
    ±5-point band around 0.90 shaded; median widths (log units) as text below."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    levels = res["levels"]
    names = list(LOG_NAMES)
    x = np.arange(len(names))
    wbar = 0.8 / len(levels)
    fig, ax = plt.subplots(figsize=(14, 4.8))
    ax.axhspan(0.85, 0.95, color="0.85", label="0.90 ± 5 points")
    for i, lv in enumerate(levels):
        ax.bar(x + (i - (len(levels) - 1) / 2) * wbar, [lv["coverage_90"][n] for n in names], wbar,
               label=f"{lv['level']} ({lv['flown']} flights)")
    ax.set_xticks(x, [n.replace("_total", "").replace("relative_effectiveness", "ρ").replace("authority", "auth")
                      for n in names], rotation=35, ha="right", fontsize=8)
    ax.set_ylim(0, 1.02)
    ax.set_ylabel("truth inside the 90 % band")
    ax.set_title(f"log-grounded posterior on MJX flights ({res['prior']} prior, oracle, 10 s lemniscate; rates: {res.get('rates', 'windows')})", fontsize=10)
    ax.legend(fontsize=7, ncol=3, loc="lower left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def summarise(folder: Path) -> str:
    """The runs of a folder (one JSON per prior or held-out family) as one markdown table of coverage per
    quantity, family and noise level, and ``coverage.png`` beside them (a heat map of the same)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    runs = [json.loads(p.read_text()) for p in sorted(folder.glob("*.json"))]
    if not runs:
        raise ValueError(f"{folder}: no run JSON files (python benchmarks/log_grounded.py --prior NAME --out {folder}/NAME.json)")
    names = list(LOG_NAMES)
    short = [n.replace("_total", "").replace("relative_effectiveness", "ρ").replace("authority", "auth")
             .replace("external_acc", "τ_ext/J") for n in names]
    rows, labels = [], []
    lines = ["| prior | level | flights | " + " | ".join(short) + " | mean |", "|---" * (len(names) + 4) + "|"]
    for r in runs:
        for lv in r["levels"]:
            cov = [lv["coverage_90"][n] for n in names]
            rows.append(cov)
            labels.append(f"{r['prior']} {lv['level']}")
            lines.append(f"| {r['prior']} | {lv['level']} | {lv['flown']} | " + " | ".join(f"{c:.2f}" for c in cov)
                         + f" | {np.mean(cov):.2f} |")
    fig, ax = plt.subplots(figsize=(12, 0.28 * len(rows) + 1.6))
    im = ax.imshow(np.array(rows), vmin=0, vmax=1, cmap="RdYlGn", aspect="auto")
    ax.set_xticks(np.arange(len(names)), short, rotation=35, ha="right", fontsize=8)
    ax.set_yticks(np.arange(len(rows)), labels, fontsize=7)
    fig.colorbar(im, ax=ax, label="truth inside the 90 % band", fraction=0.03)
    ax.set_title("log-grounded posterior, truth inside the 90 % band (0.85-0.95 is calibrated)", fontsize=10)
    fig.tight_layout()
    fig.savefig(folder / "coverage.png", dpi=110)
    plt.close(fig)
    table = "\n".join(lines) + "\n"
    (folder / "summary.md").write_text(table)
    return table


def compact_json(res: dict) -> str:
    """A run as compact JSON: floats to 4 significant digits, "inside" as 0/1 (docs/runs stays small)."""
    def rnd(x, key=None):
        if isinstance(x, bool):
            return int(x) if key == "inside" else x
        if isinstance(x, float):
            return float(f"{x:.4g}")
        if isinstance(x, list):
            return [rnd(v, key) for v in x]
        if isinstance(x, dict):
            return {k: rnd(v, k) for k, v in x.items()}
        return x
    return json.dumps(rnd(res), separators=(",", ":")) + "\n"


ROW_KEYS = ("vehicle", "inside", "width")
"""What a merged run keeps per flight (the errors, seconds and methods are summarised per level)."""


def merge(out: Path, shards: list[Path]) -> dict:
    """Join ``--shard`` runs of one draw into one run: per noise level, the rows of every shard 0..K-1
    (from one run or several, e.g. the levels split over two runs), ordered by vehicle index; a level
    some shard lacks is left out, and said so. Rows keep :data:`ROW_KEYS`."""
    runs = [json.loads(p.read_text()) for p in shards]
    draws = {(r["prior"], r["vehicles"], r.get("seed")) for r in runs}
    if len(draws) != 1:
        raise ValueError(f"--merge: the shards are of different draws (prior, vehicles, seed): {sorted(draws)}")
    ks = {int((r.get("shard") or "0/1").split("/")[1]) for r in runs}
    if len(ks) != 1:
        raise ValueError(f"--merge: shards of different counts K: {sorted(ks)}")
    k = ks.pop()
    by_level: dict[str, dict[str, list]] = {}
    for p, r in zip(shards, runs):
        for lv in r["levels"]:
            got = by_level.setdefault(lv["level"], {})
            shard = r.get("shard") or "0/1"
            if shard in got:
                raise ValueError(f"--merge: {p}: level {lv['level']} of shard {shard} given twice")
            got[shard] = lv["rows"]
    want = {f"{i}/{k}" for i in range(k)}
    levels = sorted((lv for lv, got in by_level.items() if set(got) == want), key=list(LEVELS).index)
    if not levels:
        raise ValueError(f"--merge: no noise level has all of shards 0/{k} .. {k - 1}/{k}")
    if len(levels) < len(by_level):
        print(f"--merge: only {levels} have every shard; {sorted(set(by_level) - set(levels))} are left out",
              file=sys.stderr)
    res = {"command": runs[0]["command"].replace(f"--shard {runs[0].get('shard')}", f"--shard i/{k}")
           + f" (shards merged: {k})", "prior": runs[0]["prior"], "vehicles": runs[0]["vehicles"],
           "seed": runs[0].get("seed"), "rows_kept": "per flight: " + ", ".join(ROW_KEYS), "levels": []}
    for name in levels:
        rows = sorted((row for got in by_level[name].values() for row in got), key=lambda row: row["vehicle"])
        lv = level_summary(name, rows)
        lv["rows"] = [{key: row[key] for key in ROW_KEYS} for row in rows]
        res["levels"].append(lv)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(compact_json(res))
    figure(res, out.with_suffix(".png"))
    return res
