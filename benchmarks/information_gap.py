"""The information gap over prior vehicles: where the shipped policy's latent is under-informed.

Flies N vehicles of the decoders' prior with the shipped policy (MJX, 10 s lemniscate, IMU at the
given noise level of :data:`mjxsysid.uses.imu_noise.LEVELS`), decodes each flight's latents with
the shipped flight-level decoder (the posterior ``decode`` reports at the end of the flight), runs
the log-grounded posterior on the flight's IMU and motor commands with those samples as its
proposal, and reports per log-identifiable quantity: the median width ratio (decoder-only band /
log-grounded band), how often the decoder-only band holds the log-grounded median, both bands'
coverage of the truth, and the decoded proposal's importance-sampling ESS.

    python benchmarks/information_gap.py --vehicles 16 --level x1 --out docs/runs/measurements/log-grounded/gap_x1.json
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
from mjxsysid.identify.coords import LOG_NAMES
from mjxsysid.identify.gap import information_gap
from mjxsysid.identify.inference import log_grounded_posterior
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.rollout.flight import fly_vehicles, seen_imu
from mjxsysid.sim import Quadrotor, SimConfig
from mjxsysid.decoding import decode_posterior
from mjxsysid.uses.imu_noise import LEVELS


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicles", type=int, default=16)
    ap.add_argument("--level", default="x1")
    ap.add_argument("--prior", default="wide_actuators")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    th = np.asarray(P.get_prior(a.prior).sample(jax.random.PRNGKey(a.seed), a.vehicles))
    ref = resolve_policy("mjxsysid")
    cfm, reg = load_decoders(None, ref)
    seq = load_sequence_decoder(None, ref)
    sim = Quadrotor(SimConfig(**LEVELS[a.level]))
    fl, m, _ = fly_vehicles(th, controller="policy", policy=ref, reference="lemniscate", period=10.0, sim=sim,
                            seed=a.seed)
    rows = []
    for i in range(a.vehicles):
        if bool(np.asarray(m["failed"])[i]):
            continue
        one = jax.tree.map(lambda x: np.asarray(x[i]), fl)
        dec = decode_posterior(one.latent, one.time, th[i], decoder=cfm, regression=reg, samples=200, seed=i,
                               window="flight", seq_decoder=seq)
        final = dec["samples_window"][-1]
        rec = {"imu": seen_imu(one.frame.imu), "motor": one.frame.motor_cmd}
        t0 = time.perf_counter()
        post = log_grounded_posterior(rec, final, seed=i)
        gap = information_gap(final, post["theta"], th[i])
        rows.append({"vehicle": i, "seconds": time.perf_counter() - t0, "method": post["method"],
                     "decoded_is": post.get("decoded_is"), "gap": gap})
        print(f"vehicle {i}: {post['method']}, decoded-proposal ESS {post['decoded_is']['ess']:.3g}", flush=True)
    agg = {}
    for n in LOG_NAMES:
        g = [r["gap"][n] for r in rows]
        agg[n] = {"median_width_ratio": float(np.median([x["width_ratio"] for x in g])),
                  "decoder_holds_log_median": float(np.mean([x["decoder_holds_log_median"] for x in g])),
                  "decoder_coverage_90": float(np.mean([x["decoder_inside"] for x in g])),
                  "log_coverage_90": float(np.mean([x["log_inside"] for x in g])),
                  "seen_by_log": float(np.mean([x["seen_by_log"] for x in g]))}
    res = {"command": "python benchmarks/information_gap.py " + " ".join(f"--{k} {v}" for k, v in vars(a).items()
                                                                          if v is not None),
           "level": a.level, "sim": LEVELS[a.level], "flown": len(rows), "aggregate": agg,
           "decoded_is_ess_median": float(np.median([r["decoded_is"]["ess"] for r in rows])),
           "methods": {k: sum(r["method"] == k for r in rows) for k in ("decoded_is", "laplace_is", "smc")},
           "rows": rows}
    print(json.dumps({k: v for k, v in res.items() if k != "rows"}, indent=1))
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(res, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
