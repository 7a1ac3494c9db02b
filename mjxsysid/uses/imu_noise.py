"""Decoder calibration under IMU noise (docs/noise.md): a policy flies held-out vehicles of its
decoders' prior with white noise, a per-flight bias and rotor vibration on the IMU it reads, and
its decoders decode the latents of each flight.

Every level flies the same vehicles on the same manoeuvres (mjxsysid.dataset.collect's random
lemniscates, min-snaps and hover steps with random world forces) from the same key: only the
IMU differs. The levels are multiples of the hardware-like simulator of the tuning experiment
(gyro 0.01 rad/s and accelerometer 0.1 m/s² white per 2 ms sample, biases 0.005 rad/s and
0.05 m/s²; no latency here, as a log's rows carry none). The vehicles lost at any level are left
out of every level, so each row scores the same flights.

Per level: the policy's position RMSE; the flight-level posterior (sequence decoder, every latent
of the flight), the single-latent CFM (the last latent) and the Regression point estimate (the
last latent). For the posteriors: 90 % coverage per parameter and per identifiable combination,
how many lie within ±5 points, the mean 90 % widths (identifiable ones in natural-log units) and
their ratio to the clean level; for Regression the mean absolute error of the log identifiable
combinations. ``mjxsysid experiment noise-sensitivity`` is the command.
"""
from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.cfm.load import load_decoders, load_sequence_decoder
from mjxsysid.cfm.pipeline import _ident_log, _public, posterior_scores, prior_reference
from mjxsysid.control.high_level import Cascade
from mjxsysid.dataset.collect import random_manoeuvres, trajectory_times
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.rollout.flight import broadcast
from mjxsysid.rollout.harness import failure_mask, fly_batch
from mjxsysid.sim import Quadrotor, SimConfig

GYRO, ACCEL, GYRO_BIAS, ACCEL_BIAS = 0.01, 0.1, 0.005, 0.05   # the tuning experiment's HARDWARE_SIM (× 1)


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
    "x10": level(10, 10),
    "x20": level(20, 20),
}
"""name -> SimConfig IMU settings of each level."""
LABELS = {"clean": "clean", "x0.5_white": "× 0.5 white (the policy's training)", "x1_white": "× 1 white only",
          "x1": "× 1 (white + bias)", "x2": "× 2 (white + bias)", "x10": "× 10 (white + bias)",
          "x5_white": "× 5 white only", "x5_bias": "× 5 bias only",
          "x5_vibration": "× 5 rotor vibration only", "x20": "× 20 (white + bias)"}
DEFAULT_LEVELS = tuple(k for k in LEVELS if k not in ("x0.5_white", "x1_white", "x10"))
"""The levels of docs/runs/release/noise/noise_sensitivity.json (the two low ones have their own run)."""


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


def noise_sensitivity(*, policy="mjxsysid", decoders=None, vehicles: int = 150, seconds: float = 4.0,
                      samples: int = 200, seed: int = 4242, levels=DEFAULT_LEVELS, log=None) -> dict:
    """The measurement of the module doc: ``policy`` (a name, path or PolicyRef) flies ``vehicles``
    draws of its decoders' prior (key ``seed``; the pairs used seeds 0 and 1) for ``seconds`` at
    each of ``levels`` (names of :data:`LEVELS`); its decoders (the folder ``decoders`` with
    cfm.npz, regression.npz and cfm_seq.npz, checked against the policy; default its shipped ones)
    draw ``samples`` per flight. Returns the result dict (see mjxsysid experiment noise-sensitivity's JSON);
    ``log`` is told the progress."""
    log = log or (lambda m: None)
    if vehicles < 2 or samples < 2:
        raise ValueError("vehicles and samples must be >= 2")
    bad = [lv for lv in levels if lv not in LEVELS]
    if bad or not levels:
        raise ValueError(f"unknown noise level(s) {bad or levels}; choose from {', '.join(LEVELS)}")
    t0 = time.time()
    ref_pol = resolve_policy(policy)
    cfm, reg = load_decoders(decoders, policy=ref_pol)
    seq = load_sequence_decoder(decoders, policy=ref_pol)
    if seq is None:
        raise FileNotFoundError(f"no sequence decoder (cfm_seq.npz) in {decoders or ref_pol.decoders_dir}")
    norm = cfm.normalizer
    theta = np.asarray(P.get_prior(ref_pol.decoder_prior).sample(jax.random.PRNGKey(seed), vehicles))
    times, idx, steps = trajectory_times(seconds)
    k_man, k_fly = jax.random.split(jax.random.PRNGKey(seed + 1))
    ref, dist, _ = random_manoeuvres(k_man, theta, seconds, seed=seed)
    flown = {}
    for name in levels:
        t1 = time.time()
        flown[name] = fly_level(LEVELS[name], theta, ref, dist, k_fly, steps, idx, ref_pol)
        log(f"{name:14s} flown in {time.time() - t1:.0f} s, lost {int(flown[name][1].sum())}")
    ok = ~np.any([f[1] for f in flown.values()], 0)
    if not ok.any():
        raise ValueError("every vehicle was lost at some noise level: nothing to score")
    t_norm = np.asarray(norm.normalize(theta[ok]))
    key = jax.random.PRNGKey(seed + 2)
    res = {"policy": ref_pol.to_dict(), "decoders": str(decoders or ref_pol.decoders_dir),
           "prior": ref_pol.decoder_prior, "seconds": seconds, "latents_per_flight": int(len(idx)),
           "vehicles": vehicles, "scored": int(ok.sum()), "samples": samples, "device": str(jax.devices()[0]),
           "levels": {}}
    res["prior_reference"] = _public(prior_reference(t_norm, norm, ref_pol.decoder_prior, key, samples))
    for j, name in enumerate(levels):
        z, failed, rmse = flown[name]
        z = z[ok]
        t1 = time.time()
        flight = posterior_scores(seq.sample_norm(z, jax.random.fold_in(key, 10 * j), samples,
                                                  mask=np.ones(z.shape[:2], bool)), t_norm, seq.normalizer)
        single = posterior_scores(cfm.sample_norm(z[:, -1], jax.random.fold_in(key, 10 * j + 1), samples),
                                  t_norm, norm)
        res["levels"][name] = {
            "label": LABELS[name], "sim": LEVELS[name], "lost": int(failed.sum()),
            "pos_rmse_m": {"mean": float(rmse[ok].mean()), "median": float(np.median(rmse[ok]))},
            "flight_level": _public(flight), "single_latent_cfm": _public(single),
            "regression_abs_log_error": regression_error(np.asarray(reg.point_norm(z[:, -1])), t_norm, norm)}
        log(f"{name:14s} decoded in {time.time() - t1:.0f} s: flight-level identifiable within ±5: "
            f"{flight['identifiable_90_within_5_points']}/5, params {flight['coverage_90_within_5_points']}/19; "
            f"single CFM {single['identifiable_90_within_5_points']}/5, {single['coverage_90_within_5_points']}/19")
    if "clean" in res["levels"]:
        for kind in ("flight_level", "single_latent_cfm"):
            w0 = res["levels"]["clean"][kind]["width_90_identifiable_log"]
            for lv in res["levels"].values():
                lv[kind]["width_ratio_to_clean"] = {n: lv[kind]["width_90_identifiable_log"][n] / w0[n] for n in w0}
    res["wall_s"] = round(time.time() - t0, 1)
    return res


def _ident_names(res: dict) -> list[str]:
    """The identifiable combinations' names as a result names them (the record's own keys: a record
    written before the nominal thrust-to-weight was named so calls it "thrust_to_weight")."""
    first = next(iter(res["levels"].values()))
    return list(first["flight_level"]["coverage_90_identifiable"])


def table(res: dict) -> str:
    """The Markdown table of a result (docs/noise.md)."""
    names = _ident_names(res)
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
    """The coverage and width figure of a result of :func:`noise_sensitivity` (its JSON)."""
    from mjxsysid.render.plots import plot_noise_sensitivity
    lv = list(res["levels"].values())
    names = _ident_names(res)
    kinds = {"flight-level (sequence decoder)": "flight_level", "single-latent CFM": "single_latent_cfm"}
    cov = {k: np.array([[v[kk]["coverage_90_identifiable"][n] for n in names] for v in lv]) for k, kk in kinds.items()}
    wid = {k: np.array([[v[kk]["width_90_identifiable_log"][n] for n in names] for v in lv]) for k, kk in kinds.items()}
    return plot_noise_sensitivity([v["label"] for v in lv], cov, wid, path, names=names,
                                  title=f"{_whose(res)} under IMU noise: {res['scored']} held-out vehicles, "
                                        f"{res['seconds']:g} s flights")


def _whose(res: dict) -> str:
    """'shipped decoders', or the decoders' folder (e.g. a release's decoder set)."""
    dec = res.get("decoders")
    if not dec or "pretrained" in str(dec):
        return "shipped decoders"
    parts = Path(str(dec)).parts
    return f"decoders of {parts[-2] if parts[-1] == 'decoder_set' and len(parts) > 1 else parts[-1]}"


def replace_tables(page: str, results: dict) -> str:
    """``page`` (docs/noise.md's text) with each block between ``<!-- BEGIN noise table RUN ... -->``
    and ``<!-- END noise table -->`` rewritten as :func:`table` of ``results[RUN]`` (a result dict
    per run path named in the markers; blocks of other runs are left as they are)."""
    out, rest = [], page
    begin, end = "<!-- BEGIN noise table ", "<!-- END noise table -->"
    while begin in rest:
        head, tail = rest.split(begin, 1)
        marker, tail = tail.split("-->", 1)
        body, rest = tail.split(end, 1)
        run = marker.split(" ", 1)[0]
        new = f"\n{table(results[run])}\n" if run in results else body
        out.append(head + begin + marker + "-->" + new + end)
    return "".join(out) + rest
