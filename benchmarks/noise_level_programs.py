"""Flights at every noise level: one compiled program with the IMU's magnitudes as data, against one per level.

    python benchmarks/noise_level_programs.py            # both ways, a fresh process each, no persistent cache

Each process flies 2 prior vehicles 2 s (a hover, the oracle) at the seven noise levels the posterior's
calibration flies (mjxsysid.experiments.posterior_calibration: five to fit, two held out) with XLA's
optimisations on, as a user's command compiles. ``data``: the package as it is (``fly_batch`` flies
:meth:`Quadrotor.imu_as_data`'s simulator, the magnitudes passed in). ``per_level``: ``imu_as_data`` patched to
keep each level's own simulator, so that every level compiles its own flight, as a static configuration
did. It reports wall and CPU seconds, the flight programs compiled and a hash of every frame: the two
ways must fly the same noise to the bit.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

CHILD = r"""
import hashlib, json, os, resource, time
os.environ["MJXSYSID_JAX_CACHE"] = "0"
import jax
import numpy as np
from mjxsysid import theta as P
from mjxsysid.rollout import harness
from mjxsysid.rollout.flight import fly_vehicles
from mjxsysid.sim import Quadrotor, SimConfig
from mjxsysid.uses.imu_noise import LEVELS

if os.environ["MODE"] == "per_level":
    Quadrotor.imu_as_data = lambda self: (self, self.imu_std())
levels = ("clean", "x1", "x2", "x5_white", "x5_vibration", "x10", "x20")
th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(3), 2))
h = hashlib.sha256()
t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF).ru_utime
for lv in levels:
    fl, _, _ = fly_vehicles(th, controller="oracle", reference="hover", duration=2.0, seed=5,
                            sim=Quadrotor(SimConfig(**LEVELS[lv])))
    for leaf in jax.tree.leaves(fl.frame):
        h.update(np.asarray(leaf).tobytes())
print(json.dumps({"mode": os.environ["MODE"], "levels": len(levels),
                  "programs": harness._fly_batch.cache_info().misses,
                  "wall_s": round(time.perf_counter() - t0, 1),
                  "cpu_s": round(resource.getrusage(resource.RUSAGE_SELF).ru_utime - c0, 1),
                  "frames_sha256": h.hexdigest()[:16]}))
"""


def run(mode: str) -> dict:
    env = dict(os.environ, MODE=mode)
    out = subprocess.run([sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="write the result JSON here")
    args = ap.parse_args(argv)
    res = {"runs": [run(m) for m in ("per_level", "data")]}
    a, b = res["runs"]
    res["same_frames"] = a["frames_sha256"] == b["frames_sha256"]
    res["wall_ratio"] = round(b["wall_s"] / a["wall_s"], 2)
    print(json.dumps(res, indent=1))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(res, indent=1) + "\n")
    return res


if __name__ == "__main__":
    main()
