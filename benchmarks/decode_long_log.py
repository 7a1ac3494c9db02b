"""Decode time and peak memory of `mjxsysid decode --log` against the log's length (issue 20 §4).

    python benchmarks/decode_long_log.py --minutes 0.1667 1 10 60 --out docs/runs/measurements/benchmarks/decode_long_log.json
    python benchmarks/decode_long_log.py --minutes 1 --compare-decoder-only --out docs/runs/measurements/log-grounded/cost.json

A 10 s flight of the shipped policy on the paper vehicle (a 10 s lemniscate, MJX) is written as
a log and tiled to each length (time continuous; the IMU and commands repeat every 10 s, which
changes nothing about the cost). Each length is decoded by the CLI with its defaults (flight
window, 100 samples, 10 Hz: at most MAX_DECODES decode times) in a fresh process, timed, with
its peak resident memory (ru_maxrss of the child). ``--compare-decoder-only``: each length is
decoded four times — with ``--decoder-only`` and by default (the log-grounded posterior added),
each cold (a fresh JAX compilation cache) and then warm (the same cache again) — so the log-grounded
posterior's cost is a difference measured in one run.
"""
from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def base_flight() -> dict:
    """The shipped policy's 10 s lemniscate on the paper vehicle (MJX) as a log's arrays: t (T,) s from 0,
    imu (T, 6) the readings the policy acted on, a_cmd (T,), omega_cmd (T, 3), motor (T, 4), quat (T, 4)
    w x y z and vel (T, 3) m/s in the world (the state estimate a format may carry)."""
    from mjxsysid import theta as P
    from mjxsysid.policy.interface import resolve_policy
    from mjxsysid.rollout.flight import fly_vehicles, one_flight, seen_imu
    fl, _, _ = fly_vehicles(P.PAPER_HARDWARE, controller="policy", policy=resolve_policy("mjxsysid"),
                            reference="lemniscate", period=10.0, duration=10.0)
    f = one_flight(fl)
    return {"t": np.asarray(f.time, np.float64) - 0.002, "imu": np.asarray(seen_imu(f.frame.imu), np.float64),
            "a_cmd": np.asarray(f.a_cmd, np.float64), "omega_cmd": np.asarray(f.omega_cmd, np.float64),
            "motor": np.asarray(f.frame.motor_cmd, np.float64), "quat": np.asarray(f.frame.quat, np.float64),
            "vel": np.asarray(f.frame.vel, np.float64)}


def base_log() -> tuple:
    f = base_flight()
    return tuple(f[k] for k in ("t", "imu", "a_cmd", "omega_cmd", "motor"))


def tiled(flight: dict, seconds: float) -> dict:
    """``flight``'s arrays repeated end to end to ``seconds``, t continuous in 2 ms steps."""
    n = int(round(seconds / 0.002))
    reps = int(np.ceil(n / len(flight["t"])))
    out = {k: np.tile(x, (reps,) + (1,) * (x.ndim - 1))[:n] for k, x in flight.items() if k != "t"}
    return {"t": 0.002 * np.arange(n), **out}


def tiled_log(base, seconds: float, path: Path) -> Path:
    cols = tiled(dict(zip(("t", "imu", "a_cmd", "omega_cmd", "motor"), base)), seconds)
    arr = np.column_stack([cols[k] for k in ("t", "imu", "a_cmd", "omega_cmd", "motor")])
    n = len(arr)
    from mjxsysid.logs.csvlog import LOG_COLUMNS
    with open(path, "w") as f:
        f.write(",".join(LOG_COLUMNS) + "\n")
        for i in range(0, n, 100_000):      # chunks: the writer's memory stays small too
            np.savetxt(f, arr[i:i + 100_000], delimiter=",", fmt="%.7g")
    return path


def _decode(log: Path, out: Path, extra: list = (), cache: Path | None = None) -> tuple[float, float]:
    """`mjxsysid decode --log LOG` in a fresh process (``cache``: its JAX compilation cache, default
    the user's) -> (wall s, peak resident GB)."""
    import os
    env = dict(os.environ) if cache is None else dict(os.environ, MJXSYSID_JAX_CACHE=str(cache))
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-c", (
        "import resource, sys; from mjxsysid.cli import main; rc = main(sys.argv[1:]); "
        "print('MAXRSS', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); sys.exit(rc)"),
        "decode", "--log", str(log), "--out", str(out), "-q", *extra], capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        sys.exit(f"decode of {log} failed:\n{r.stderr[-2000:]}")
    rss = next(int(ln.split()[1]) for ln in r.stderr.splitlines() if ln.startswith("MAXRSS"))
    return wall, rss * 1024 / 1e9


def _tiled_logs(minutes):
    """(minutes, log path, scratch folder) per length, the logs tiled from one base flight in a
    temporary folder (each log removed once the caller moves on)."""
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        base = base_log()
        for mins in minutes:
            log = tiled_log(base, 60.0 * mins, tmp / f"log_{mins:g}.csv")
            yield mins, log, tmp
            log.unlink()


def compare(args):
    rows = []
    for mins, log, tmp in _tiled_logs(args.minutes):
        row = {"minutes": mins}
        for mode, extra in (("decoder_only", ["--decoder-only"]), ("log_grounded", [])):
            cache = tmp / f"cache_{mode}_{mins:g}"
            for temp in ("cold", "warm"):
                wall, gb = _decode(log, tmp / f"dec_{mode}_{temp}", extra, cache)
                row[f"{mode}_{temp}_s"], row[f"{mode}_{temp}_gb"] = wall, gb
                print(f"{mins:6.3g} min {mode:13s} {temp}: {wall:6.1f} s, {gb:.2f} GB", flush=True)
        for temp in ("cold", "warm"):
            row[f"added_{temp}_s"] = row[f"log_grounded_{temp}_s"] - row[f"decoder_only_{temp}_s"]
        rows.append(row)
    res = {"benchmark": "decode_long_log --compare-decoder-only", "date": time.strftime("%Y-%m-%d"),
           "machine": platform.node(), "cpus": len(__import__("os").sched_getaffinity(0)), "rows": rows}
    print(json.dumps(res, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=1) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, nargs="+", default=[1 / 6, 1, 10])
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--compare-decoder-only", action="store_true")
    args = ap.parse_args()
    if args.compare_decoder_only:
        return compare(args)
    rows = []
    for mins, log, tmp in _tiled_logs(args.minutes):
        out = tmp / f"dec_{mins:g}"
        wall, gb = _decode(log, out)
        s = json.loads((out / "summary.json").read_text())
        row = {"minutes": mins, "rows": int(round(60.0 * mins / 0.002)), "csv_mb": log.stat().st_size / 1e6,
               "wall_s": wall, "peak_rss_gb": gb, "n_decodes": s["_window"]["n_decodes"],
               "decode_rate_hz": s["_window"]["decode_rate_hz"], "n_latents": s["_window"]["n_latents"]}
        rows.append(row)
        print(f"{mins:7.3g} min  {row['rows']:>9,} rows  {row['csv_mb']:7.1f} MB  {wall:7.1f} s  "
              f"{row['peak_rss_gb']:5.2f} GB  {row['n_decodes']} decodes at {row['decode_rate_hz']:.3g} Hz, "
              f"{row['n_latents']} latents", flush=True)
    res = {"benchmark": "decode_long_log", "date": time.strftime("%Y-%m-%d"), "machine": platform.node(),
           "cpus": len(__import__("os").sched_getaffinity(0)), "python": platform.python_version(), "rows": rows}
    if args.out:
        args.out.write_text(json.dumps(res, indent=1) + "\n")
        print(f"wrote {args.out}")


if __name__ == "__main__":
    resource.setrlimit  # (ru_maxrss of each child is read inside it)
    main()
