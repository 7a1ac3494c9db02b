"""A 10-minute flight in every log format: its reader, `check-log` and `decode --log`, each against the
CSV of the same flight (targets: `check-log` ≤ 5 s, `decode --log` no slower than the CSV).

    python benchmarks/long_logs.py --minutes 10 --repeats 3 --out docs/runs/measurements/benchmarks/long_logs.json

The flight: the shipped policy's 10 s lemniscate on the paper vehicle (MJX on the CPU, about 10 s),
its rows repeated end to end to ``--minutes`` with time continuous (flying 10 minutes in the simulator
is not needed for a reader's cost). It is written at every 2 ms row, with its attitude and velocity,
as the CSV, a PX4 ULog, a Crazyflie uSD log, an Indiflight blackbox, an ArduPilot DataFlash log, a
ROS 1 bag and a ROS 2 MCAP bag (:mod:`mjxsysid.logs.formats_write`). Each repeat runs every format in
turn, so the ratios to the CSV are taken within one pass of a noisy machine:

- ``read``: ``read_any_log`` in a fresh process, the reader alone (timed inside the process);
- ``check-log``: `mjxsysid check-log FILE` as a user runs it, a fresh process (start-up included);
- ``decode``: `mjxsysid decode --log FILE --out DIR -q`, a fresh process on the user's JAX
  compilation cache, warmed by one untimed decode first; its wall time and its CPU time (user + system:
  less moved than the wall by other work on a shared machine).

``--code DIR`` times another checkout's readers and CLI (the logs are written by this one): before
and after a change, in one command each.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

FORMATS = ("csv", "ulog", "crazyflie", "blackbox", "dataflash", "ros1", "ros2")
FILES = {"csv": "flight.csv", "ulog": "flight.ulg", "crazyflie": "flight.usd", "blackbox": "flight.bfl",
         "dataflash": "flight.bin", "ros1": "flight.bag", "ros2": "flight_ros2"}
READ = ("import sys, time; from mjxsysid.logs.csvlog import read_any_log; t = time.perf_counter(); "
        "r = read_any_log(sys.argv[1]); print('READ', time.perf_counter() - t, len(r['t']), r['source']['format'])")


def write_logs(minutes: float, folder: Path, formats) -> dict:
    """The flight tiled to ``minutes`` in each of ``formats`` under ``folder`` (kept where already written)
    -> {format: path}."""
    from decode_long_log import base_flight, tiled
    from mjxsysid.logs import formats_write as W
    from mjxsysid.logs.csvlog import write_log
    from mjxsysid.logs.grid import world_to_body
    from mjxsysid.logs.ulog_write import write_ulog
    paths = {k: folder / FILES[k] for k in formats}
    todo = [k for k in formats if not paths[k].exists()]
    if not todo:
        return paths
    f = tiled(base_flight(), 60.0 * minutes)
    arrays = tuple(f[k] for k in ("t", "imu", "a_cmd", "omega_cmd", "motor"))
    est = {"quat": f["quat"], "vel": f["vel"]}

    def ros2(p, *a, **kw):
        from rosbags.rosbag2 import StoragePlugin
        return W.write_rosbag(p, *a, **kw, storage=StoragePlugin.MCAP)

    writers = {"csv": lambda p, *a, quat, vel: write_log(p, *a, velocity_body=world_to_body(quat, vel)),
               "ulog": write_ulog, "crazyflie": W.write_crazyflie, "blackbox": W.write_blackbox,
               "dataflash": W.write_dataflash, "ros1": W.write_rosbag, "ros2": ros2}
    folder.mkdir(parents=True, exist_ok=True)
    for k in todo:
        t = time.perf_counter()
        writers[k](paths[k], *arrays, **est)
        size = sum(p.stat().st_size for p in paths[k].rglob("*")) if paths[k].is_dir() else paths[k].stat().st_size
        print(f"wrote {k:10s} {size / 1e6:6.1f} MB in {time.perf_counter() - t:5.1f} s", flush=True)
    return paths


def _run(cmd, env) -> tuple[float, float, subprocess.CompletedProcess]:
    """``cmd`` in a fresh process -> (wall s, CPU s (user + system, its children's included), the process)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=env.get("PYTHONPATH", ROOT))
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), p


def measure(paths: dict, repeats: int, decode_repeats: int, env: dict, scratch: Path) -> dict:
    """{format: {read: [s], check: [s], decode: [s], check_exit: code}}: every format in turn, ``repeats`` times."""
    py = sys.executable
    res = {k: {"read": [], "check": [], "decode": [], "decode_cpu": []} for k in paths}
    if decode_repeats:                                   # fills the compilation cache: every timed decode is warm
        first = next(iter(paths.values()))
        wall, _, _ = _run([py, "-m", "mjxsysid.cli", "decode", "--log", str(first), "--out", str(scratch / "warm"),
                           "-q"], env)
        print(f"warm-up decode {wall:.1f} s", flush=True)
    for r in range(repeats):
        for k, path in paths.items():
            _, _, p = _run([py, "-c", READ, str(path)], env)
            line = next((ln for ln in p.stdout.splitlines() if ln.startswith("READ")), None)
            if line is None:
                sys.exit(f"reading {path} failed:\n{p.stderr[-2000:]}")
            res[k]["read"].append(float(line.split()[1]))
            wall, _, p = _run([py, "-m", "mjxsysid.cli", "check-log", str(path)], env)
            res[k]["check"].append(wall)
            res[k]["check_exit"] = p.returncode
            if r < decode_repeats:
                out = scratch / f"decode_{k}"
                shutil.rmtree(out, ignore_errors=True)
                wall, cpu, p = _run([py, "-m", "mjxsysid.cli", "decode", "--log", str(path), "--out", str(out), "-q"],
                                    env)
                if p.returncode != 0:
                    sys.exit(f"decode --log {path} failed:\n{p.stderr[-2000:]}")
                res[k]["decode"].append(wall)
                res[k]["decode_cpu"].append(cpu)
            d = (f"{res[k]['decode'][-1]:6.1f} s (CPU {res[k]['decode_cpu'][-1]:6.1f} s)" if r < decode_repeats
                 else "–")
            print(f"repeat {r + 1} {k:10s} read {res[k]['read'][-1]:6.2f} s  check-log {res[k]['check'][-1]:6.2f} s "
                  f"(exit {res[k]['check_exit']})  decode {d}", flush=True)
    return res


def summary(res: dict) -> dict:
    """min / median of each time, and the median over repeats of each time's ratio to the CSV's in that repeat."""
    out = {}
    for k, v in res.items():
        row = {"check_exit": v.get("check_exit")}
        for m in ("read", "check", "decode", "decode_cpu"):
            x = np.asarray(v[m], np.float64)
            if not len(x):
                continue
            row[f"{m}_min_s"], row[f"{m}_median_s"] = float(x.min()), float(np.median(x))
            if "csv" in res and len(res["csv"][m]) == len(x):
                row[f"{m}_ratio_to_csv"] = float(np.median(x / np.asarray(res["csv"][m], np.float64)))
        out[k] = row
    return out


def table(s: dict) -> str:
    lines = ["| format | read, min / median | `check-log`, min / median | `decode --log` wall, min / median | "
             "decode CPU, min / median | decode / CSV: wall, CPU (medians of the repeats' ratios) |",
             "|---|---|---|---|---|---|"]
    for k, r in s.items():
        dec = {m: (f"{r[m + '_min_s']:.1f} / {r[m + '_median_s']:.1f} s" if m + "_min_s" in r else "–")
               for m in ("decode", "decode_cpu")}
        ratio = (f"{r['decode_ratio_to_csv']:.2f}, {r['decode_cpu_ratio_to_csv']:.2f}" if "decode_ratio_to_csv" in r
                 else "–")
        lines.append(f"| {k} | {r['read_min_s']:.2f} / {r['read_median_s']:.2f} s | {r['check_min_s']:.2f} / "
                     f"{r['check_median_s']:.2f} s | {dec['decode']} | {dec['decode_cpu']} | {ratio} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=3, help="passes over the formats (read and check-log)")
    ap.add_argument("--decode-repeats", type=int, default=None, help="passes that also decode (default --repeats)")
    ap.add_argument("--formats", default=",".join(FORMATS), help=f"comma-separated, of {','.join(FORMATS)}")
    ap.add_argument("--keep", type=Path, default=None, help="folder for the logs, kept (and reused) between runs")
    ap.add_argument("--code", type=Path, default=None, help="the checkout whose readers and CLI are timed")
    ap.add_argument("--out", type=Path, default=None, help="JSON of the times")
    a = ap.parse_args()
    formats = [k.strip() for k in a.formats.split(",")]
    bad = [k for k in formats if k not in FORMATS]
    if bad:
        raise SystemExit(f"--formats: unknown {bad}; known: {','.join(FORMATS)}")
    env = dict(os.environ, PYTHONPATH=str((a.code or ROOT).resolve()))   # the timed processes run there too
    with tempfile.TemporaryDirectory() as tmp:
        folder = a.keep or Path(tmp) / "logs"
        t0 = time.perf_counter()
        paths = write_logs(a.minutes, folder, formats)
        res = measure(paths, a.repeats, a.repeats if a.decode_repeats is None else a.decode_repeats, env, Path(tmp))
    s = summary(res)
    print(table(s))
    print(f"whole run {time.perf_counter() - t0:.0f} s")
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({
            "benchmark": "long_logs", "date": time.strftime("%Y-%m-%d"), "machine": platform.node(),
            "cpus": len(os.sched_getaffinity(0)), "minutes": a.minutes, "code": str(a.code or "this checkout"),
            "times_s": res, "summary": s}, indent=1) + "\n")
        print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
