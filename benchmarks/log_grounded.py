"""The log-grounded posterior (mjxsysid.identify) on simulated flights: coverage, widths, time.

Flies N vehicles of a prior with the lag-aware oracle (MJX simulator, 10 s lemniscate) at each IMU
noise level of :data:`mjxsysid.uses.imu_noise.LEVELS` asked for (clean, × 1 white + bias, × 5 white,
× 5 rotor vibration, × 20 white + bias: the decoders' noise study's levels), runs the
log-grounded posterior on each flight's IMU and motor commands (no decoded proposal: the prior
and the log alone), and reports per log-identifiable quantity whether the truth is inside the
90 % band and the band's width, plus the seconds per log.

    python benchmarks/log_grounded.py --vehicles 24 --levels clean,x1,x5_white,x5_vibration,x20 \
        --out docs/runs/measurements/log-grounded/calibration.json
    python benchmarks/log_grounded.py --prior weak_motor --vehicles 12 \
        --out docs/runs/measurements/log-grounded/families/weak_motor.json    # a held-out family
    python benchmarks/log_grounded.py --summarise docs/runs/measurements/log-grounded/families

Many vehicles in parallel processes (one GPU or several): ``--shard i/k`` flies and identifies
every k-th vehicle of the same draw, from the i-th on (vehicle indices, posterior seeds and
truths are those of the unsharded run; the flights' noise draws depend on the batch, so the
numbers are those of another draw of the same noise); ``--merge OUT SHARD.json ...`` joins the
shards into one run::

    for i in 0 1 2 3 4 5 6 7; do python benchmarks/log_grounded.py --vehicles 200 --shard $i/8 \
        --out /tmp/cal/$i.json & done; wait
    python benchmarks/log_grounded.py --merge calibration-200.json /tmp/cal/*.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import jax
import numpy as np
from _bench import level_flights, merge_paths, shard

from mjxsysid import theta as P
from mjxsysid.identify.coords import LOG_NAMES, log_quantities
from mjxsysid.identify.inference import log_grounded_posterior
from mjxsysid.identify.logdata import RATES
from mjxsysid.rollout.flight import flight_log
from mjxsysid.uses.imu_noise import LEVELS



def run_level(th, level: str, seed: int, index=None, rates: str = RATES) -> dict:
    """Fly ``th`` (n, 19) at noise ``level`` and identify each flight; ``index`` (n,): the
    vehicles' indices in the whole draw (default 0..n-1; the posterior's seed is the index); ``rates``:
    the posterior's rate term."""
    index = np.arange(len(th)) if index is None else np.asarray(index)
    frame, flown = level_flights(th, level, seed)
    rows = []
    for i in flown:
        rec = flight_log(frame, i)
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
        raise SystemExit(f"level {level}: no flight to identify (every vehicle failed)")
    inside = np.array([r["inside"] for r in rows])
    return {"level": level, "sim": LEVELS[level], "flown": len(rows),
            "coverage_90": dict(zip(LOG_NAMES, inside.mean(0).round(3).tolist())),
            "median_width": dict(zip(LOG_NAMES, np.median([r["width"] for r in rows], 0).round(4).tolist())),
            "median_rel_error": dict(zip(LOG_NAMES, np.median([r["rel_error_median"] for r in rows], 0).round(4).tolist())),
            "seconds_median": float(np.median([r["seconds"] for r in rows])),
            "methods": {k: sum(r["method"] == k for r in rows) for k in ("decoded_is", "laplace_is", "smc")},
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
        raise SystemExit(f"{folder}: no run JSON files (python benchmarks/log_grounded.py --prior NAME --out {folder}/NAME.json)")
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
        raise SystemExit(f"--merge: the shards are of different draws (prior, vehicles, seed): {sorted(draws)}")
    ks = {int((r.get("shard") or "0/1").split("/")[1]) for r in runs}
    if len(ks) != 1:
        raise SystemExit(f"--merge: shards of different counts K: {sorted(ks)}")
    k = ks.pop()
    by_level: dict[str, dict[str, list]] = {}
    for p, r in zip(shards, runs):
        for lv in r["levels"]:
            got = by_level.setdefault(lv["level"], {})
            shard = r.get("shard") or "0/1"
            if shard in got:
                raise SystemExit(f"--merge: {p}: level {lv['level']} of shard {shard} given twice")
            got[shard] = lv["rows"]
    want = {f"{i}/{k}" for i in range(k)}
    levels = sorted((lv for lv, got in by_level.items() if set(got) == want), key=list(LEVELS).index)
    if not levels:
        raise SystemExit(f"--merge: no noise level has all of shards 0/{k} .. {k - 1}/{k}")
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--figure-only", default=None, help="draw the figure of an earlier run's JSON and exit")
    ap.add_argument("--summarise", default=None, metavar="DIR",
                    help="one table (DIR/summary.md) and heat map (DIR/coverage.png) of the runs in DIR, and exit")
    ap.add_argument("--vehicles", type=int, default=24)
    ap.add_argument("--levels", default="clean,x1,x5_white,x5_vibration,x20")
    ap.add_argument("--prior", default="wide_actuators",
                    help="a prior or a held-out family (mjxsysid.theta.priors.HELDOUT_FAMILIES: out of the decoders' prior)")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--shard", default=None, metavar="I/K", help="identify every K-th vehicle from the I-th (parallel runs; join with --merge)")
    ap.add_argument("--merge", nargs="+", default=None, metavar=("OUT", "SHARD"),
                    help="join the JSON files of --shard runs into OUT and exit")
    ap.add_argument("--out", default=None)
    ap.add_argument("--drag", type=float, default=None, metavar="KG_PER_S",
                    help="a diagnostic: fly every vehicle with this body drag on each axis (the likelihood has no drag "
                         "term; e.g. 1e-6 to take it out of the flights)")
    ap.add_argument("--rates", default=RATES, choices=("innovations", "windows"),
                    help="the posterior's rate term (default: the library's)")
    a = ap.parse_args()
    if a.merge:
        res = merge(*merge_paths(a.merge))
        for lv in res["levels"]:
            print(json.dumps({k: v for k, v in lv.items() if k != "rows"}))
        return
    if a.summarise:
        print(summarise(Path(a.summarise)), end="")
        return
    if a.figure_only:
        figure(json.loads(Path(a.figure_only).read_text()), Path(a.figure_only).with_suffix(".png"))
        return
    prior = P.get_prior(a.prior)
    # a held-out family (out of the decoders' prior): its fixed, validated and flyable evaluation vehicles
    th = (prior.vehicles(a.vehicles) if a.prior in P.HELDOUT_FAMILIES
          else np.asarray(prior.sample(jax.random.PRNGKey(a.seed), a.vehicles)))
    if a.drag is not None:
        if not a.drag > 0:
            raise SystemExit(f"--drag must be > 0 kg/s, got {a.drag}")
        th = np.array(th, np.float32)
        th[:, P.DRAG] = a.drag
    th, index, flight_seed = shard(th, a.shard, a.seed)   # the flights' noise: another draw per shard
    res = {"command": "python benchmarks/log_grounded.py " + " ".join(f"--{k} {v}" for k, v in vars(a).items()
                                                                        if v is not None),
           "prior": a.prior, "rates": a.rates, "drag": a.drag, "vehicles": a.vehicles, "seed": a.seed, "shard": a.shard,
           "levels": []}
    for lv in a.levels.split(","):
        r = run_level(th, lv, flight_seed, index, a.rates)
        res["levels"].append(r)
        print(json.dumps({k: v for k, v in r.items() if k != "rows"}), flush=True)
        if a.out:
            Path(a.out).parent.mkdir(parents=True, exist_ok=True)
            Path(a.out).write_text(compact_json(res))
            figure(res, Path(a.out).with_suffix(".png"))


if __name__ == "__main__":
    main()
