"""The flight-log checks measured (docs/decoding.md, 'Checking a log'): the shipped policy flies
held-out vehicles of the decoders' prior (wide_actuators, a seed the decoders never saw) and
vehicles outside it; every correct log must pass without a finding, every common mistake
(:data:`mjxsysid.logs.checks.MISTAKES`) must end in an error or a warning that names it,
and the out-of-prior signal's false-alarm rate (prior vehicles) and hit rate (outside) are counted.
The IMU-noise estimate is measured on flights the policy flew through known noise (white, bias,
rotor vibration; multiples of the hardware-like levels): its error and how often it warns.

    mjxsysid experiment log-checks --out docs/runs/measurements/log-checks    # 200 vehicles, 6 s
"""
from __future__ import annotations

import time
from collections import Counter
from types import SimpleNamespace

import jax
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.experiments.common import leaf_table, write_results
from mjxsysid.logs import checks as L
from mjxsysid.policy.adaptive.controller import PolicyController
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.rollout.flight import fly_vehicles, seen_imu
from mjxsysid.sim import Quadrotor, SimConfig


def out_of_prior_sets(theta, rng) -> dict:
    """Prior vehicles (n, 19) made to leave the prior one way each: thrust-to-weight 10–12 at η = 1
    (``nominal_thrust_to_weight``, as the measurement drew them; RotorPy's hummingbird is 10.2; Ω_max
    scaled), τ_m 3–10 ms (the hummingbird: 5 ms), one motor at η 0.4."""
    n = len(theta)
    tw = theta.copy()
    tw[:, P.OMEGA_MAX] *= np.sqrt(rng.uniform(10, 12, n) / np.asarray(P.nominal_thrust_to_weight(theta)))
    fast = theta.copy()
    fast[:, P.TAU_M] = rng.uniform(0.003, 0.010, n)
    weak = theta.copy()
    weak[np.arange(n), P.ETA.start + rng.integers(0, 4, n)] = 0.4
    return {"thrust_to_weight_10_12": tw, "motor_time_constant_3_10ms": fast, "one_motor_eta_0.4": weak}


NOISE_LEVELS = {  # SimConfig IMU settings: multiples of gyro 0.01 rad/s, accelerometer 0.1 m/s², biases 0.005 / 0.05
    "x0.5_white": dict(gyro_noise=0.005, accel_noise=0.05),
    "x1_white_bias": dict(gyro_noise=0.01, accel_noise=0.1, gyro_bias=0.005, accel_bias=0.05),
    "x2_white_bias": dict(gyro_noise=0.02, accel_noise=0.2, gyro_bias=0.01, accel_bias=0.1),
    "x5_white": dict(gyro_noise=0.05, accel_noise=0.5),
    "x5_bias": dict(gyro_bias=0.025, accel_bias=0.25),
    "x5_vibration": dict(gyro_vibration=0.05, accel_vibration=0.5),
    "x20_white_bias": dict(gyro_noise=0.2, accel_noise=2.0, gyro_bias=0.1, accel_bias=1.0),
}


def flights(theta, seconds, seed, sim_config=None):
    sim = Quadrotor(SimConfig(**(sim_config or {})))
    fl, m, _ = fly_vehicles(theta, controller="policy", policy=resolve_policy("mjxsysid"), reference="lemniscate",
                            period=10.0, duration=seconds, seed=seed, sim=sim)
    ok = ~np.asarray(m["failed"], bool)
    recs = [{"t": np.asarray(fl.time[i]) - L.DT, "imu": seen_imu(fl.frame.imu[i]).astype(np.float64),
             "a_cmd": np.asarray(fl.a_cmd[i]), "omega_cmd": np.asarray(fl.omega_cmd[i]),
             "motor": np.asarray(fl.frame.motor_cmd[i]), "imu_after": np.asarray(fl.frame.imu[i])}
            for i in range(len(theta)) if ok[i]]
    return recs, int((~ok).sum())


def check(pol, rec):
    rec = {k: v for k, v in rec.items() if k != "imu_after"}
    z = pol.replay(rec["imu"], rec["a_cmd"], rec["omega_cmd"], rec["motor"])
    return L.check_log(rec, policy=pol, zhat=z)


FULL = {"vehicles": 200, "outside": 50, "seconds": 6.0}
"""The committed run's sizes (``outside``: vehicles per out-of-prior set)."""
QUICK = {"vehicles": 4, "outside": 2, "seconds": 2.0}


def run(out, *, quick=False, policy=None, seed=12345, progress=True) -> dict:
    """The log checks measured (see the module doc) into OUT/results.json; ``seed`` draws the
    held-out vehicles (the decoders' pairs used 0 and 1). The shipped policy flies (``policy``
    is not used: the checks are the shipped policy's)."""
    t0 = time.time()
    a = SimpleNamespace(**(QUICK if quick else FULL), seed=seed)
    pol = PolicyController.load()
    theta = np.asarray(P.WIDE_ACTUATOR_PRIOR.sample(jax.random.PRNGKey(a.seed), a.vehicles))
    recs, lost = flights(theta, a.seconds, a.seed)
    res = {"prior": "wide_actuators", "seconds": a.seconds, "prior_flights": len(recs), "prior_lost": lost}
    # Correct logs: no finding of any kind; the out-of-prior signal's false alarms.
    clean = [check(pol, r) for r in recs]
    res["correct_logs_with_a_finding"] = sum(bool(f) for f in clean)
    res["correct_log_findings"] = [str(f) for fs in clean for f in fs][:20]
    est = [L.estimate_vehicle({k: v for k, v in r.items() if k != "imu_after"}) for r in recs]
    fa = [bool(L.prior_check(r, est=e)) for r, e in zip(recs, est)]
    res["out_of_prior_false_alarm_rate"] = float(np.mean(fa))
    res["prior_estimates"] = {k: [float(np.percentile([e[k] for e in est], q)) for q in (0, 1, 50, 99, 100)]
                              for k in est[0]}
    # Every mistake on every prior flight: what it ended in.
    mist = {}
    for kind in L.MISTAKES:
        if kind in ("time_in_ms", "motor_pwm"):
            continue  # caught on reading (read_log): tested on CSV files in tests/logs/test_logcheck.py
        levels, named = Counter(), []
        for r in recs:
            bad = L.make_mistake({k: v for k, v in r.items() if k != "imu_after"}, kind, imu_after=r["imu_after"])
            fs = check(pol, bad)
            levels["error" if any(f.level == "error" for f in fs) else "warning" if fs else "nothing"] += 1
            named.append(str(fs[0]) if fs else "")
        mist[kind] = {"levels": dict(levels), "caught": 1 - levels["nothing"] / len(recs), "example": named[0]}
    res["mistakes"] = mist
    # Vehicles outside the prior.
    rng = np.random.default_rng(a.seed)
    sets = out_of_prior_sets(theta[: a.outside], rng)
    res["outside"] = {}
    for name, th in sets.items():
        rs, lost_o = flights(th, a.seconds, a.seed)
        hits = [bool(L.prior_check({k: v for k, v in r.items() if k != "imu_after"})) for r in rs]
        other = [[f for f in check(pol, r)] for r in rs]
        res["outside"][name] = {"flown": len(rs), "lost": lost_o, "hit_rate": float(np.mean(hits)) if rs else None,
                                "other_findings": sum(bool(f) for f in other),
                                "example": str(L.prior_check({k: v for k, v in rs[0].items() if k != "imu_after"})[0])
                                if rs and hits[0] else ""}
    # IMU noise the policy flew through: the estimate against the injected std, and the warning.
    res["imu_noise"] = {"limit": L.IMU_NOISE_LIMIT, "correct_logs_estimates": {
        k: [float(np.percentile([e[k] for e in est], q)) for q in (50, 99, 100)] for k in ("gyro_noise", "accel_noise")}}
    for name, cfg in NOISE_LEVELS.items():
        rs, lost_n = flights(theta[: a.outside], a.seconds, a.seed, cfg)
        e = [L.estimate_imu_noise({k: v for k, v in r.items() if k != "imu_after"}) for r in rs]
        warned = [bool(L.check_imu_noise({k: v for k, v in r.items() if k != "imu_after"}, est=x)) for r, x in zip(rs, e)]
        res["imu_noise"][name] = {
            "sim": cfg, "flown": len(rs), "lost": lost_n, "warning_rate": float(np.mean(warned)) if rs else None,
            **{f"{k}_estimate_median": float(np.median([x[k] for x in e])) if rs else None for k in ("gyro_noise", "accel_noise")},
            **{f"{k}_estimate_range": [float(np.min([x[k] for x in e])), float(np.max([x[k] for x in e]))] if rs else None
               for k in ("gyro_noise", "accel_noise")}}
        if progress:
            print(name, res["imu_noise"][name], flush=True)
    if progress:
        print(jsonout.dumps({k: v for k, v in res.items() if k not in ("correct_log_findings",)}, indent=1))
    numbers = {**res, "headline": {"correct_logs_with_a_finding": res["correct_logs_with_a_finding"],
                                   "out_of_prior_false_alarm_rate": res["out_of_prior_false_alarm_rate"]}}
    return write_results(out, "log-checks", config={"quick": quick, **vars(a)}, seeds={"seed": seed},
                         numbers=numbers, table_md=leaf_table(res), t0=t0)
