"""The log-grounded posterior and ``mujoco.sysid`` side by side on the same simulated logs.

Flies vehicles of a prior with the lag-aware oracle (MJX simulator, 10 s lemniscate; the
vehicles, flights and noise of ``benchmarks/log_grounded.py`` with the same arguments) at each IMU
noise level asked for, and identifies every flight twice from its IMU and motor commands:

- the log-grounded posterior (:func:`mjxsysid.identify.log_grounded_posterior`, no decoded
  proposal), its 5–95 % band;
- ``mujoco.sysid`` (:mod:`mjxsysid.identify.mujoco_sysid`: Gauss–Newton on MuJoCo rollouts of
  0.1 s chunks started from the flight's state, the 90 % s²(JᵀJ)⁻¹ interval). Gauss–Newton needs a
  start in the optimum's basin: it runs from the paper vehicle and from the log-grounded median and
  keeps the lower cost (the row says which won and whether the paper start alone got there).

Per quantity of :data:`mjxsysid.identify.coords.LOG_NAMES`: truth inside each band, the bands'
widths, the estimates' errors, and where the two bands do not overlap, which one holds the truth.

    python benchmarks/sysid_side_by_side.py --vehicles 12 --levels clean,x5_white,x20 \\
        --out docs/runs/measurements/log-grounded/sysid/side_by_side.json
    # parallel processes (the GPU machine's 16 cores), joined afterwards:
    for i in 0 1 2 3 4 5 6 7; do python benchmarks/sysid_side_by_side.py --shard $i/8 --out /tmp/s/$i.json & done; wait
    python benchmarks/sysid_side_by_side.py --merge side_by_side.json /tmp/s/*.json

Needs ``pip install "mjxsysid[sysid]"`` (mujoco.sysid's dependencies).
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
from mjxsysid.identify import mujoco_sysid as MS
from mjxsysid.identify.coords import (
    LOG_NAMES,
    hidden_from_theta,
    log_quantities,
    theta_from,
    visible_from_theta,
)
from mjxsysid.identify.inference import log_grounded_posterior
from mjxsysid.identify.logdata import RATES
from mjxsysid.rollout.flight import flight_log
from mjxsysid.uses.imu_noise import LEVELS

RHO4 = LOG_NAMES.index("relative_effectiveness[3]")



def seen_states(frame, i: int) -> tuple[np.ndarray, np.ndarray]:
    """The state at the start of each control step (the one the row's IMU reading belongs to, as
    :func:`mjxsysid.rollout.flight.seen_imu`): qpos (T, 7) [position, quaternion], qvel (T, 6)
    [world velocity, body rates] of vehicle ``i``; a Frame row is the state after its step."""
    qpos = np.concatenate([np.asarray(frame.pos[i]), np.asarray(frame.quat[i])], -1).astype(np.float64)
    qvel = np.concatenate([np.asarray(frame.vel[i]), np.asarray(frame.omega[i])], -1).astype(np.float64)
    shift = lambda a: np.concatenate([a[:1], a[:-1]], 0)
    return shift(qpos), shift(qvel)


def _width(lo, hi):
    pos = (lo > 0) & (hi > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(pos, np.log(np.maximum(hi, 1e-30) / np.maximum(lo, 1e-30)), hi - lo)


def identify_both(rec, qpos, qvel, truth, seed: int, rates: str = RATES) -> dict:
    """One log through both methods -> a row of per-quantity results."""
    tq = log_quantities(truth)
    t0 = time.perf_counter()
    post = log_grounded_posterior(rec, None, seed=seed, rates=rates)
    lg_sec = time.perf_counter() - t0
    q = log_quantities(post["theta"])
    lo, med, hi = np.percentile(q, [5, 50, 95], 0)
    paper = np.asarray(P.paper_hardware(), np.float32)
    v_med = np.median(visible_from_theta(np.asarray(post["theta"], np.float32)), 0)
    lg_start = np.asarray(theta_from(v_med, hidden_from_theta(paper)))
    fits = {}
    for name, start in (("paper", paper), ("log_grounded", lg_start)):
        try:
            fits[name] = MS.identify(rec["imu"], rec["motor"], qpos, qvel, start_theta=start)
        except (ValueError, RuntimeError, np.linalg.LinAlgError) as e:   # a start that fails: said, the other kept
            print(f"mujoco.sysid from the {name} start failed: {e}", file=sys.stderr)
    if not fits:
        raise RuntimeError("mujoco.sysid failed from both starts")
    best = min(fits, key=lambda k: fits[k].s2)
    fit = fits[best]
    sq = fit.quantities()
    slo, shi = sq["q05"], sq["q95"]
    inside_lg = (lo <= tq) & (tq <= hi)
    inside_sy = (slo <= tq) & (tq <= shi)
    overlap = (slo <= hi) & (lo <= shi)
    return {"truth": tq.tolist(), "lg": [lo.tolist(), med.tolist(), hi.tolist()],
            "sysid": [slo.tolist(), sq["estimate"].tolist(), shi.tolist()],
            "inside_lg": inside_lg.tolist(), "inside_sysid": inside_sy.tolist(), "overlap": overlap.tolist(),
            "width_lg": _width(lo, hi).tolist(), "width_sysid": _width(slo, shi).tolist(),
            "rel_error_lg": np.abs(med / tq - 1).tolist(), "rel_error_sysid": np.abs(sq["estimate"] / tq - 1).tolist(),
            "sysid_start": best, "sysid_s2": {k: f.s2 for k, f in fits.items()},
            "paper_start_reached": bool("paper" in fits and fits["paper"].s2 <= 1.05 * fit.s2),
            "seconds": {"log_grounded": lg_sec, "sysid": {k: f.seconds for k, f in fits.items()}},
            "method": post["method"]}


def run_level(th, level: str, seed: int, index, rates: str = RATES) -> dict:
    frame, flown = level_flights(th, level, seed)
    rows = []
    for i in flown:
        qpos, qvel = seen_states(frame, i)
        row = identify_both(flight_log(frame, i), qpos, qvel, th[i], int(index[i]), rates)
        row["vehicle"] = int(index[i])
        rows.append(row)
        print(f"{level} vehicle {index[i]}: inside log-grounded {sum(row['inside_lg'])}/13, "
              f"mujoco.sysid {sum(row['inside_sysid'])}/13 (start {row['sysid_start']})", file=sys.stderr, flush=True)
    return {"level": level, "rows": rows}


def summary(level: dict) -> dict:
    """Per quantity: coverage of both 90 % bands, median widths and errors, and over the logs where
    the bands do not overlap, the share where the log-grounded band holds the truth."""
    rows = level["rows"]
    if not rows:
        return {"level": level["level"], "flown": 0}
    arr = lambda k: np.array([r[k] for r in rows], np.float64)
    lg_in, sy_in, ov = arr("inside_lg"), arr("inside_sysid"), arr("overlap")
    apart = 1 - ov
    n_apart = apart.sum(0)
    lg_right = np.where(n_apart > 0, (apart * lg_in).sum(0) / np.maximum(n_apart, 1), np.nan)
    sy_right = np.where(n_apart > 0, (apart * sy_in).sum(0) / np.maximum(n_apart, 1), np.nan)
    rd = lambda a: dict(zip(LOG_NAMES, np.round(a, 4).tolist()))
    return {"level": level["level"], "flown": len(rows),
            "coverage_lg": rd(lg_in.mean(0)), "coverage_sysid": rd(sy_in.mean(0)),
            "median_width_lg": rd(np.median(arr("width_lg"), 0)), "median_width_sysid": rd(np.median(arr("width_sysid"), 0)),
            "median_rel_error_lg": rd(np.median(arr("rel_error_lg"), 0)),
            "median_rel_error_sysid": rd(np.median(arr("rel_error_sysid"), 0)),
            "apart": rd(n_apart), "apart_lg_holds_truth": rd(lg_right), "apart_sysid_holds_truth": rd(sy_right),
            "sysid_start": {k: sum(r["sysid_start"] == k for r in rows) for k in ("paper", "log_grounded")},
            "paper_start_reached": int(sum(r["paper_start_reached"] for r in rows)),
            "seconds_median": {"log_grounded": float(np.median([r["seconds"]["log_grounded"] for r in rows])),
                               "sysid_per_start": float(np.median([s for r in rows for s in r["seconds"]["sysid"].values()]))}}


def table(res: dict) -> str:
    """Markdown: per level and quantity, coverage and median relative error of both methods."""
    short = lambda n: n.replace("_total", "").replace("relative_effectiveness", "ρ").replace("authority", "auth")
    out = []
    for lv in res["levels"]:
        s = summary(lv)
        if not s["flown"]:
            continue
        out += [(f"**{s['level']}** ({s['flown']} logs; mujoco.sysid's lower-cost start: {s['sysid_start']}, "
                f"the paper start alone reached it on {s['paper_start_reached']}; seconds per log: "
                f"log-grounded {s['seconds_median']['log_grounded']:.1f}, mujoco.sysid "
                f"{s['seconds_median']['sysid_per_start']:.1f} per start)"), "",
                "| quantity | inside, log-grounded | inside, mujoco.sysid | median error, log-grounded | median error, mujoco.sysid | median 90 % width (log), log-grounded | mujoco.sysid | bands apart | of those, truth in log-grounded / mujoco.sysid |",
                "|---|---|---|---|---|---|---|---|---|"]
        for n in LOG_NAMES:
            a = s["apart"][n]
            held = (f"{s['apart_lg_holds_truth'][n]:.2f} / {s['apart_sysid_holds_truth'][n]:.2f}" if a else "–")
            out.append(f"| {short(n)} | {s['coverage_lg'][n]:.2f} | {s['coverage_sysid'][n]:.2f} | "
                       f"{s['median_rel_error_lg'][n]:.3f} | {s['median_rel_error_sysid'][n]:.3f} | "
                       f"{s['median_width_lg'][n]:.3g} | {s['median_width_sysid'][n]:.3g} | {int(a)} | {held} |")
        out.append("")
    return "\n".join(out)


def figure(res: dict, path) -> None:
    """Coverage of the 90 % bands per quantity, both methods, one panel per level."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    levels = [summary(lv) for lv in res["levels"] if lv["rows"]]
    names = list(LOG_NAMES)
    x = np.arange(len(names))
    fig, axes = plt.subplots(len(levels), 1, figsize=(12, 2.6 * len(levels)), sharex=True, squeeze=False)
    for ax, s in zip(axes[:, 0], levels):
        ax.axhspan(0.85, 0.95, color="0.88")
        ax.bar(x - 0.2, [s["coverage_lg"][n] for n in names], 0.4, label="log-grounded posterior")
        ax.bar(x + 0.2, [s["coverage_sysid"][n] for n in names], 0.4, label="mujoco.sysid, s²(JᵀJ)⁻¹")
        ax.set_ylim(0, 1.02)
        ax.set_ylabel(f"{s['level']}\ninside 90 %", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    axes[0, 0].set_title(f"truth inside the 90 % band, {res['prior']} prior, oracle, 10 s lemniscate", fontsize=10)
    axes[-1, 0].set_xticks(x, [n.replace("_total", "").replace("relative_effectiveness", "ρ") for n in names],
                           rotation=35, ha="right", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write(res: dict, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    res = dict(res, summary=[summary(lv) for lv in res["levels"]])
    out.write_text(json.dumps(res, separators=(",", ":")) + "\n")
    out.with_suffix(".md").write_text(table(res) + "\n")
    figure(res, out.with_suffix(".png"))


def merge(out: Path, shards: list[Path]) -> dict:
    parts = [json.loads(p.read_text()) for p in shards]
    res = {k: parts[0][k] for k in ("command", "prior", "vehicles", "seed")}
    res["shards"] = [p.get("shard") for p in parts]
    names = [lv["level"] for lv in parts[0]["levels"]]
    res["levels"] = [{"level": n, "rows": sorted((r for p in parts for lv in p["levels"] if lv["level"] == n
                                                  for r in lv["rows"]), key=lambda r: r["vehicle"])} for n in names]
    write(res, out)
    return res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, default=12)
    ap.add_argument("--levels", default="clean,x5_white,x20")
    ap.add_argument("--prior", default="wide_actuators")
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--shard", default=None, metavar="I/K")
    ap.add_argument("--merge", nargs="+", default=None, metavar=("OUT", "SHARD"))
    ap.add_argument("--out", default=None)
    ap.add_argument("--rates", default=RATES, choices=("innovations", "windows"),
                    help="the posterior's rate term (default: the library's)")
    a = ap.parse_args()
    if a.merge:
        res = merge(*merge_paths(a.merge))
        print(table(res))
        return
    unknown = [lv for lv in a.levels.split(",") if lv not in LEVELS]
    if unknown:
        raise SystemExit(f"--levels: unknown {unknown}; choose from {sorted(LEVELS)}")
    th = np.asarray(P.get_prior(a.prior).sample(jax.random.PRNGKey(a.seed), a.vehicles))
    th, index, flight_seed = shard(th, a.shard, a.seed)   # the flights' noise: another draw per shard
    res = {"command": "python benchmarks/sysid_side_by_side.py " + " ".join(
        f"--{k} {v}" for k, v in vars(a).items() if v is not None and k != "merge"),
           "prior": a.prior, "rates": a.rates, "vehicles": a.vehicles, "seed": a.seed, "shard": a.shard, "levels": []}
    for lv in a.levels.split(","):
        res["levels"].append(run_level(th, lv, flight_seed, index, a.rates))
        if a.out:
            write(res, Path(a.out))
    print(table(res))


if __name__ == "__main__":
    main()
