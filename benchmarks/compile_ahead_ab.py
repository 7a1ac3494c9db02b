"""A cold `decode --log` of a 10 s log with the posterior's programs compiled ahead and without
(``MJXSYSID_COMPILE_AHEAD`` 1 / 0, :mod:`mjxsysid.runtime.ahead`), alternated in one run on one machine.

    python benchmarks/compile_ahead_ab.py --repeats 3 --out docs/runs/measurements/benchmarks/compile_ahead_ab.json

Each run is ``mjxsysid profile --json F -- decode --log LOG --out D -q`` in a fresh process on an empty
compilation cache (:func:`decode_cost_ab.decode_once`, this checkout); the order flips from one repeat to the next.
"""
from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=3, help="cold runs of each setting (default 3)")
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON")
    a = p.parse_args(argv)
    if a.repeats < 1:
        p.error("--repeats must be ≥ 1")
    import decode_cost_ab as AB
    import decode_long_log as D
    from mjxsysid.runtime.ahead import ENV
    runs: dict = {"1": [], "0": []}
    with tempfile.TemporaryDirectory(prefix="mjxsysid_ahead_ab_") as tmp:
        tmp = Path(tmp)
        (tmp / "shim").mkdir()
        log = D.tiled_log(D.base_log(), 10.0, tmp / "log10.csv")
        for k in range(a.repeats):
            for v in ("1", "0") if k % 2 == 0 else ("0", "1"):
                os.environ[ENV] = v
                res = AB.decode_once(ROOT, tmp / "shim", log, tmp / f"dec_{v}_{k}", tmp / f"cache_{v}_{k}")
                runs[v].append(res)
                print(f"{ENV}={v} #{k}: {res['wall_s']:.1f} s (compiling {res['compile_s']:.1f} s)", file=sys.stderr,
                      flush=True)
    med = {v: statistics.median(r["wall_s"] for r in rs) for v, rs in runs.items()}
    print(f"cold, median of {a.repeats}: ahead {med['1']:.1f} s, on first call {med['0']:.1f} s, "
          f"ratio {med['1'] / med['0']:.2f}")
    if a.out:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.write_text(json.dumps({"date": datetime.date.today().isoformat(), "machine": platform.platform(),
                                     "cpus": os.cpu_count(), "runs": runs, "median_s": med,
                                     "ratio": med["1"] / med["0"]}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
