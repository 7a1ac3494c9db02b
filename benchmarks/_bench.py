"""Helpers shared by the benchmark scripts (run as ``python benchmarks/NAME.py``: this folder is
on ``sys.path``)."""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path


def wall_times(fn, repeats: int) -> list[float]:
    """Wall times (s) of ``repeats`` calls of ``fn()`` (which blocks on its result)."""
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def write_json(path: Path, res: dict) -> None:
    """Write a benchmark's result JSON (creating its folder) and say so on stderr."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(res, indent=2) + "\n")
    print(f"wrote {path}", file=sys.stderr)


def config_overrides(pairs: list[str]) -> dict:
    """``KEY=VALUE`` strings (``--set``) -> a dict of TrainConfig overrides, values read as JSON
    (``true``, ``2``, ``0.1``) or else kept as strings."""
    out = {}
    for p in pairs:
        key, sep, value = p.partition("=")
        if not sep or not key:
            raise SystemExit(f"--set: expected KEY=VALUE, got {p!r}")
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    return out


def shard(theta, spec: str | None, seed: int):
    """Every K-th vehicle from the I-th of ``theta`` (n, 19) for ``spec`` "I/K" (parallel runs of one draw,
    joined afterwards; None: all) -> (θ of the shard, their indices in the draw, the flights' seed: another
    noise draw per shard, ``seed + 1000 I``). A malformed spec exits with a message naming it."""
    import numpy as np
    index = np.arange(len(theta))
    if spec is None:
        return theta, index, seed
    try:
        i, k = (int(x) for x in spec.split("/"))
        if not 0 <= i < k:
            raise ValueError
    except ValueError:
        raise SystemExit(f"--shard {spec!r}: expected I/K with 0 <= I < K, e.g. 0/8") from None
    index = index[i::k]
    return theta[index], index, seed + 1000 * i


def level_flights(theta, level: str, seed: int):
    """Fly θ (n, 19) with the lag-aware oracle on a 10 s lemniscate at the IMU noise ``level`` of
    :data:`mjxsysid.uses.imu_noise.LEVELS` -> (the flights' Frame (n, T, ...), the indices of those
    that did not fail)."""
    import numpy as np

    from mjxsysid.rollout.flight import fly_vehicles
    from mjxsysid.sim import Quadrotor, SimConfig
    from mjxsysid.uses.imu_noise import LEVELS
    fl, m, _ = fly_vehicles(theta, controller="oracle", reference="lemniscate", period=10.0,
                            sim=Quadrotor(SimConfig(**LEVELS[level])), seed=seed)
    return fl.frame, np.flatnonzero(~np.asarray(m["failed"], bool))


def merge_paths(merge: list[str]):
    """``--merge OUT SHARD.json ...`` -> (OUT, [SHARD, ...]) as paths; fewer than two exit with the usage."""
    if len(merge) < 2:
        raise SystemExit("--merge OUT SHARD.json [SHARD.json ...]")
    return Path(merge[0]), [Path(p) for p in merge[1:]]
