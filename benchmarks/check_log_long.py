"""`mjxsysid check-log` on a 10-minute flight log (issue 39 target: ≤ 5 s on 2 cores).

The log: a numpy quadrotor flight (tests/support/synthetic_log.py: 20 s airborne, 500 Hz, thrust-to-weight
2.4, a rate controller under a random rate command) repeated end to end to ``--minutes`` and written
as a CSV by write_log; then the command is timed as a user runs it (a fresh process: start-up,
reading the CSV, cutting its airborne segment, measuring its columns' rates, every check).

    python benchmarks/check_log_long.py --minutes 10 --repeats 3
"""
import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    from mjxsysid.logs.csvlog import write_log
    sys.path.insert(0, str(ROOT / "tests"))
    from support.synthetic_log import synthetic_flight
    r = synthetic_flight(seconds=20.0)
    k = int(np.ceil(a.minutes * 60 / (len(r["t"]) * 0.002)))
    cols = {c: np.concatenate([r[c]] * k)[: int(a.minutes * 60 / 0.002)] for c in ("imu", "a_cmd", "omega_cmd", "motor")}
    t = 0.002 * np.arange(len(cols["imu"]))
    with tempfile.TemporaryDirectory() as d:
        path = write_log(Path(d) / "long.csv", t, cols["imu"], cols["a_cmd"], cols["omega_cmd"], cols["motor"])
        print(f"{len(t)} rows ({len(t) * 0.002 / 60:.1f} min), {path.stat().st_size / 1e6:.1f} MB")
        times = []
        for _ in range(a.repeats):
            t0 = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "mjxsysid.cli", "check-log", str(path)], capture_output=True,
                               text=True)
            times.append(time.perf_counter() - t0)
            print(f"exit {p.returncode}, {times[-1]:.2f} s")
        print(p.stdout)
        print(f"check-log, {a.minutes:g} min log: best {min(times):.2f} s, median {np.median(times):.2f} s")


if __name__ == "__main__":
    main()
