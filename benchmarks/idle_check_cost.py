"""The motor-map check's cost per log (:func:`mjxsysid.identify.idlecheck.run`): its maps
(:data:`~mjxsysid.identify.idlecheck.MAPS`) against the four linear ones alone, on the same logs in one run
(alternated, the best of ``--repeats``).

    python benchmarks/idle_check_cost.py --vehicles 8

Flies ``--vehicles`` vehicles of the prior with the lag-aware oracle (MJX, a 10 s lemniscate, × 1 noise),
finds each log's mode as the posterior does, then times the check on the logs one by one (as ``decode --log``
runs it) with each set of maps. Prints seconds per log and the ratio.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def logs_and_modes(vehicles: int, seed: int):
    """Simulated logs (:class:`~mjxsysid.identify.logdata.LogData`) and their modes."""
    import jax
    from mjxsysid import theta as P
    from mjxsysid.experiments.posterior_calibration import parse_reference
    from mjxsysid.identify.coords import PHYSICAL_PRIOR
    from mjxsysid.identify.batched import _Logs
    from mjxsysid.identify.inference import _starts
    from mjxsysid.identify.logdata import prepare
    from mjxsysid.identify.mode import find_modes
    from mjxsysid.identify.posterior_config import DEFAULT
    from mjxsysid.rollout.flight import flight_log, fly_vehicles
    from mjxsysid.sim import Quadrotor, SimConfig
    from mjxsysid.uses.imu_noise import LEVELS as NOISE
    th = np.asarray(P.get_prior("wide_actuators").sample(jax.random.PRNGKey(seed), vehicles))
    fl, m, _ = fly_vehicles(th, controller="oracle", sim=Quadrotor(SimConfig(**NOISE["x1"])), seed=seed,
                            **parse_reference("lemniscate:10"))
    out = []
    for i in np.flatnonzero(~np.asarray(m["failed"], bool)):
        d = prepare(flight_log(fl.frame, int(i)))
        st = _starts(d, None, np.random.default_rng(seed + int(i)), PHYSICAL_PRIOR, DEFAULT.starts)
        out.append((d, find_modes(_Logs([d]), st[None].astype(np.float32), PHYSICAL_PRIOR)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vehicles", type=int, default=8)
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    from mjxsysid.identify import idlecheck as I
    from mjxsysid.identify.batched import _Logs
    logs = logs_and_modes(a.vehicles, a.seed)
    sets = {"every map (shipped)": I.MAPS, "four linear maps": tuple(m for m in I.MAPS if m[1] == 1.0)}
    shipped = I.MAPS
    best = {k: np.inf for k in sets}
    I.run(_Logs, [logs[0][0]], logs[0][1])                      # compiles (the mode's least squares) once
    for _ in range(a.repeats):
        for name, maps in sets.items():
            I.MAPS = maps
            t0 = time.perf_counter()
            for d, modes in logs:
                I.run(_Logs, [d], modes)
            best[name] = min(best[name], (time.perf_counter() - t0) / len(logs))
    I.MAPS = shipped
    for name, s in best.items():
        print(f"{name}: {s:.3f} s a log ({len(logs)} logs, the best of {a.repeats})")
    print(f"ratio: {best['every map (shipped)'] / best['four linear maps']:.2f}")


if __name__ == "__main__":
    main()
