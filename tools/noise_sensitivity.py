"""Decoder calibration under IMU noise (docs/noise.md): the shipped policy (or ``--policy``) flies
held-out vehicles of the decoders' prior with white noise, a per-flight bias and rotor vibration
on the IMU it reads, and its decoders (or ``--decoders``) decode the latents of each flight.

    python tools/noise_sensitivity.py --vehicles 150 --seconds 4 --samples 200 \\
        --out docs/runs/noise_sensitivity.json --figure docs/noise_sensitivity.png

Every level flies the same vehicles on the same manoeuvres (mjxsysid.dataset.collect's random
lemniscates, min-snaps and hover steps with random world forces) from the same key: only the
IMU differs. The levels are multiples of the hardware-like simulator of the tuning experiment
(``HARDWARE_SIM``: gyro 0.01 rad/s and accelerometer 0.1 m/s² white per 2 ms sample, biases
0.005 rad/s and 0.05 m/s²; no latency here, as a log's rows carry none). The vehicles lost at any
level are left out of every level, so each row scores the same flights.

Per level: the policy's position RMSE; the flight-level posterior (sequence decoder, every latent
of the flight), the single-latent CFM (the last latent) and the Regression point estimate (the
last latent). For the posteriors: 90 % coverage per parameter and per identifiable combination,
how many lie within ±5 points, the mean 90 % widths (identifiable ones in natural-log units) and
their ratio to the clean level; for Regression the mean absolute error of the log identifiable
combinations.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import params as P
from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
from mjxsysid.cfm.pipeline import _ident_log, _public, posterior_scores, prior_reference
from mjxsysid.control.high_level import Cascade
from mjxsysid.dataset.collect import random_manoeuvres, trajectory_times
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.rollout.flight import broadcast
from mjxsysid.rollout.harness import failure_mask, fly_batch
from mjxsysid.sim import Quadrotor, SimConfig

GYRO, ACCEL, GYRO_BIAS, ACCEL_BIAS = 0.01, 0.1, 0.005, 0.05   # HARDWARE_SIM's levels (× 1)


def level(white: float = 0.0, bias: float = 0.0, vibration: float = 0.0) -> dict:
    """SimConfig settings of a noise level: multiples of the hardware-like levels for the white
    noise, the bias and the rotor vibration (its std as the white noise's at the same multiple)."""
    return {"gyro_noise": GYRO * white, "accel_noise": ACCEL * white, "gyro_bias": GYRO_BIAS * bias,
            "accel_bias": ACCEL_BIAS * bias, "gyro_vibration": GYRO * vibration, "accel_vibration": ACCEL * vibration}


LEVELS = {
    "clean": level(),
    "x0.5_white": level(white=0.5),
    "x1_white": level(white=1),
    "x1": level(1, 1),
    "x2": level(2, 2),
    "x5_white": level(white=5),
    "x5_bias": level(bias=5),
    "x5_vibration": level(vibration=5),
    "x20": level(20, 20),
}
LABELS = {"clean": "clean", "x0.5_white": "× 0.5 white (the policy's training)", "x1_white": "× 1 white only",
          "x1": "× 1 (white + bias)", "x2": "× 2 (white + bias)",
          "x5_white": "× 5 white only", "x5_bias": "× 5 bias only",
          "x5_vibration": "× 5 rotor vibration only", "x20": "× 20 (white + bias)"}


def fly_level(cfg: dict, theta, ref, dist, key, steps, idx, policy):
    """Latents at the decode indices (n, L, 8), failed (n,), position RMSE (n,) m of one level."""
    sim = Quadrotor(SimConfig(**cfg))
    n = len(theta)
    fl = fly_batch(sim, theta, policy.batched(n), broadcast(Cascade.make("baseline"), n), ref, dist, key, steps)
    failed = np.asarray(jax.vmap(failure_mask)(fl))[:, -1]
    err = np.asarray(fl.frame.pos) - np.asarray(fl.ref_pos)
    rmse = np.sqrt(np.mean(np.sum(err ** 2, -1), 1))
    return np.asarray(fl.latent[:, idx]), failed, rmse


def regression_error(point_norm, t_norm, norm) -> dict:
    """Mean absolute error of the log identifiable combinations of point estimates (m, 19)."""
    e = np.abs(_ident_log(np.asarray(norm.denormalize(point_norm))) - _ident_log(np.asarray(norm.denormalize(t_norm))))
    return {n: float(e[:, j].mean()) for j, n in enumerate(P.IDENTIFIABLE_NAMES)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vehicles", type=int, default=150)
    ap.add_argument("--seconds", type=float, default=4.0)
    ap.add_argument("--samples", type=int, default=200)
    ap.add_argument("--seed", type=int, default=4242, help="held-out vehicles (the pairs used seeds 0 and 1)")
    ap.add_argument("--levels", nargs="+", default=[k for k in LEVELS if k not in ("x0.5_white", "x1_white")],
                    choices=list(LEVELS))
    ap.add_argument("--policy", default="mjxsysid", help="policy name or policy.npz (default: the shipped one)")
    ap.add_argument("--decoders", type=Path, default=None,
                    help="folder with cfm.npz, regression.npz, cfm_seq.npz (default: the policy's shipped ones)")
    ap.add_argument("--out", type=Path, default=Path("docs/runs/noise_sensitivity.json"))
    ap.add_argument("--figure", type=Path, default=None)
    ap.add_argument("--replot", type=Path, default=None,
                    help="only draw --figure and print the table from this result JSON")
    a = ap.parse_args(argv)
    if a.replot is not None:
        if a.figure is None:
            raise SystemExit("--replot needs --figure")
        res = json.loads(a.replot.read_text())
        print(f"wrote {figure(res, a.figure)}")
        print(table(res))
        return 0
    if a.vehicles < 10 or a.samples < 20:
        raise SystemExit("--vehicles must be >= 10 and --samples >= 20 for a coverage to mean anything")
    t0 = time.time()
    ref_pol = resolve_policy(a.policy)
    cfm, reg = load_decoders(a.decoders, policy=ref_pol)
    seq = load_sequence_decoder(a.decoders, policy=ref_pol)
    if seq is None:
        raise SystemExit(f"no sequence decoder (cfm_seq.npz) in {a.decoders or ref_pol.decoders_dir}")
    norm = cfm.normalizer
    theta = np.asarray(P.get_prior(ref_pol.decoder_prior).sample(jax.random.PRNGKey(a.seed), a.vehicles))
    times, idx, steps = trajectory_times(a.seconds)
    k_man, k_fly = jax.random.split(jax.random.PRNGKey(a.seed + 1))
    ref, dist, _ = random_manoeuvres(k_man, theta, a.seconds, seed=a.seed)
    flown = {}
    for name in a.levels:
        t1 = time.time()
        flown[name] = fly_level(LEVELS[name], theta, ref, dist, k_fly, steps, idx, ref_pol)
        print(f"{name:14s} flown in {time.time() - t1:.0f} s, lost {int(flown[name][1].sum())}", flush=True)
    ok = ~np.any([f[1] for f in flown.values()], 0)
    t_norm = np.asarray(norm.normalize(theta[ok]))
    key = jax.random.PRNGKey(a.seed + 2)
    res = {"command": "python tools/noise_sensitivity.py " + " ".join(
               f"--{k} {' '.join(v) if isinstance(v, list) else v}" for k, v in vars(a).items()
               if v is not None and k != "replot"),
           "policy": ref_pol.to_dict(),
           "prior": ref_pol.decoder_prior, "seconds": a.seconds, "latents_per_flight": int(len(idx)),
           "vehicles": a.vehicles, "scored": int(ok.sum()), "samples": a.samples, "device": str(jax.devices()[0]),
           "levels": {}}
    res["prior_reference"] = _public(prior_reference(t_norm, norm, ref_pol.decoder_prior, key, a.samples))
    for j, name in enumerate(a.levels):
        z, failed, rmse = flown[name]
        z = z[ok]
        t1 = time.time()
        flight = posterior_scores(seq.sample_norm(z, jax.random.fold_in(key, 10 * j), a.samples,
                                                  mask=np.ones(z.shape[:2], bool)), t_norm, seq.normalizer)
        single = posterior_scores(cfm.sample_norm(z[:, -1], jax.random.fold_in(key, 10 * j + 1), a.samples),
                                  t_norm, norm)
        res["levels"][name] = {
            "label": LABELS[name], "sim": LEVELS[name], "lost": int(failed.sum()),
            "pos_rmse_m": {"mean": float(rmse[ok].mean()), "median": float(np.median(rmse[ok]))},
            "flight_level": _public(flight), "single_latent_cfm": _public(single),
            "regression_abs_log_error": regression_error(np.asarray(reg.point_norm(z[:, -1])), t_norm, norm)}
        print(f"{name:14s} decoded in {time.time() - t1:.0f} s: flight-level identifiable within ±5: "
              f"{flight['identifiable_90_within_5_points']}/5, params {flight['coverage_90_within_5_points']}/19; "
              f"single CFM {single['identifiable_90_within_5_points']}/5, {single['coverage_90_within_5_points']}/19",
              flush=True)
    if "clean" in res["levels"]:
        for kind in ("flight_level", "single_latent_cfm"):
            w0 = res["levels"]["clean"][kind]["width_90_identifiable_log"]
            for lv in res["levels"].values():
                lv[kind]["width_ratio_to_clean"] = {n: lv[kind]["width_90_identifiable_log"][n] / w0[n] for n in w0}
    res["wall_s"] = round(time.time() - t0, 1)
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(json.dumps(res, indent=1) + "\n")
    print(f"wrote {a.out} ({res['wall_s']} s)")
    print(table(res))
    if a.figure is not None:
        print(f"wrote {figure(res, a.figure)}")
    return 0


def table(res: dict) -> str:
    """The Markdown table of a result (docs/noise.md)."""
    names = list(P.IDENTIFIABLE_NAMES)
    rows = ["| IMU | policy RMSE (median) | decoder | 90 % within ±5 points: parameters / identifiable "
            "| identifiable 90 % coverage (T/W; κ; authorities) | 90 % width log T/W; authorities (× clean) "
            "| Regression abs. log error T/W; authorities |",
            "|---|---|---|---|---|---|---|"]
    for v in res["levels"].values():
        for kind, label in (("flight_level", "flight-level"), ("single_latent_cfm", "single-latent CFM")):
            d = v[kind]
            c = [d["coverage_90_identifiable"][n] for n in names]
            w = [d["width_90_identifiable_log"][n] for n in names]
            r = d.get("width_ratio_to_clean", {})
            ratio = (f" ({r[names[0]]:.2f}; {min(r[n] for n in names[2:]):.2f}–{max(r[n] for n in names[2:]):.2f})"
                     if r else "")
            e = v["regression_abs_log_error"]
            first = kind == "flight_level"
            rows.append(f"| {v['label'] if first else ''} | {100 * v['pos_rmse_m']['median']:.1f} cm |"
                        if first else "| | |")
            rows[-1] += (f" {label} | {d['coverage_90_within_5_points']} / 19, {d['identifiable_90_within_5_points']} / 5 "
                         f"| {c[0]:.2f}; {c[1]:.2f}; {min(c[2:]):.2f}–{max(c[2:]):.2f} "
                         f"| {w[0]:.2f}; {min(w[2:]):.2f}–{max(w[2:]):.2f}{ratio} |"
                         + (f" {e[names[0]]:.2f}; {min(e[n] for n in names[2:]):.2f}–{max(e[n] for n in names[2:]):.2f} |"
                            if first else " |"))
    return "\n".join(rows)


def figure(res: dict, path) -> Path:
    """The coverage and width figure of a result of :func:`main` (its JSON)."""
    from mjxsysid.render.plots import plot_noise_sensitivity
    lv = list(res["levels"].values())
    names = list(P.IDENTIFIABLE_NAMES)
    kinds = {"flight-level (sequence decoder)": "flight_level", "single-latent CFM": "single_latent_cfm"}
    cov = {k: np.array([[v[kk]["coverage_90_identifiable"][n] for n in names] for v in lv]) for k, kk in kinds.items()}
    wid = {k: np.array([[v[kk]["width_90_identifiable_log"][n] for n in names] for v in lv]) for k, kk in kinds.items()}
    return plot_noise_sensitivity([v["label"] for v in lv], cov, wid, path, names=names,
                                  title=f"shipped decoders under IMU noise: {res['scored']} held-out vehicles, "
                                        f"{res['seconds']:g} s flights")


if __name__ == "__main__":
    raise SystemExit(main())
