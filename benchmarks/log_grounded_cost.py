"""The log-grounded posterior's own cost on one device (issue 38's cost target: ≤ 1 s on one GPU for a
60 s log): a 10 s and a 60 s log (the tiled RotorPy flight of ``decode_long_log.py``) with their
decoded flight-level samples as the proposal, as ``decode --log`` passes them; three calls of
``log_grounded_posterior`` in one process (the first compiles), each timed alone.

    python benchmarks/log_grounded_cost.py --prepare DIR     # on a CPU with mjxsysid's decoders: logs + samples
    python benchmarks/log_grounded_cost.py DIR               # anywhere mjxsysid.identify imports (a GPU)
"""
import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def prepare(d: Path) -> None:
    import decode_long_log as D
    d.mkdir(parents=True, exist_ok=True)
    base = D.base_log()
    for s in (10, 60):
        D.tiled_log(base, float(s), d / f"log{s}.csv")
        out = d / f"dec{s}"
        subprocess.run([sys.executable, "-m", "mjxsysid.cli", "decode", "--log", str(d / f"log{s}.csv"), "--out", str(out),
                        "--decoder-only", "-q"], check=True)
        np.save(d / f"decoded{s}.npy", np.load(out / "decoded.npz")["samples_window"][-1])


def measure(d: Path) -> dict:
    import jax
    from mjxsysid.identify.inference import log_grounded_posterior
    from mjxsysid.logs.csvlog import read_any_log
    out = {"device": str(jax.devices()[0]), "jax": jax.__version__}
    for s in (10, 60):
        rec, dec = read_any_log(d / f"log{s}.csv"), np.load(d / f"decoded{s}.npy")
        for run, seed in (("first", 0), ("second", 1), ("third", 2)):
            t = time.perf_counter()
            post = log_grounded_posterior(rec, dec, seed=seed)
            np.asarray(post["theta"])
            out[f"log{s}s_{run}"] = {"s": round(time.perf_counter() - t, 3), "method": post["method"],
                                     "stages": post.get("smc_stages")}
            print(s, run, out[f"log{s}s_{run}"], flush=True)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", type=Path)
    ap.add_argument("--prepare", action="store_true", help="write the logs and decoded samples into DIR and exit")
    a = ap.parse_args()
    if a.prepare:
        prepare(a.dir)
    else:
        print(json.dumps(measure(a.dir)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
