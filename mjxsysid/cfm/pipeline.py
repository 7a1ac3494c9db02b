"""Train the shipped decoders from a (θ, ẑ) dataset and evaluate their calibration.

    train_decoders(pairs.npz, out)   -> out/cfm.npz, out/regression.npz (float16 weights)
    evaluate_decoders(out, pairs.npz) -> out/decoder_eval.json + figures

Weights are stored in float16 (5 M parameters: 10 MB instead of 21 MB) and evaluated *after*
that rounding, so the figures describe exactly what ships.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid.runtime import jsonout
from mjxsysid import theta as P
from mjxsysid.cfm import calibration as C
from mjxsysid.cfm.flow_coords import decoder_normalizer
from mjxsysid.cfm.posterior import summarize_posterior
from mjxsysid.cfm.sample import Decoder, random_baseline
from mjxsysid.cfm.sequence import SeqCFMConfig, SequenceDecoder, save_seq_decoder, train_seq_cfm
from mjxsysid.cfm.train import CFMConfig, save_decoder, train_cfm, train_regression
from mjxsysid.runtime.checkpoint import load_meta
from mjxsysid.dataset.collect import MANOEUVRES, load_pairs
from mjxsysid.runtime.progress import progress, stages, tee
from mjxsysid.render.posterior import plot_marginals, plot_rank_histograms

WITHIN_5_POINTS = 0.05 + 1e-9
"""A coverage is calibrated when within ±5 points of its level; the slack keeps a coverage of
exactly 0.850 or 0.950 (850 of 1,000) inside despite float round-off (0.85 − 0.9 = −0.05000000000000004)."""


def _half(params):
    return jax.tree.map(lambda a: np.asarray(a, np.float16), params)


def _usable(arrays, split):
    ok = ~arrays.get(f"failed_{split}", np.zeros(len(arrays[f"theta_{split}"]), bool))
    return arrays[f"theta_{split}"][ok], arrays[f"zhat_{split}"][ok]


KINDS = ("cfm", "regression", "cfm_seq")


def _usable_traj(arrays, split):
    ok = ~arrays.get(f"failed_{split}", np.zeros(len(arrays[f"theta_{split}"]), bool))
    return arrays[f"theta_{split}"][ok], arrays[f"zhat_traj_{split}"][ok]


def _already_trained(final: Path, ckpt: Path, cfg_dict: dict, pairs_sha256: str, resume: bool):
    """The meta of ``final`` when it was written for this config and these pairs (and no
    checkpoint of an unfinished run lies beside it); None otherwise. Without ``resume`` the
    checkpoint is deleted and None returned."""
    if not resume:
        ckpt.unlink(missing_ok=True)
        return None
    if not final.is_file() or ckpt.is_file():
        return None
    try:
        done = load_meta(final)
    except ValueError:
        return None
    info = done.get("meta", {})
    cfg_dict = json.loads(json.dumps(cfg_dict))  # as it reads back from the file (tuples -> lists)
    if done.get("config") == cfg_dict and info.get("data", {}).get("pairs_sha256") == pairs_sha256:
        return info
    return None


def train_decoders(pairs, out, cfg: CFMConfig = CFMConfig(), *, kinds=None, seq_cfg: dict | None = None,
                   log=print, resume: bool = True, checkpoint_every: int = 10) -> dict:
    """Train the decoders ``kinds`` (default: CFM and Regression, plus the sequence CFM
    "cfm_seq" when the pairs hold latent trajectories) on the training split (validation: the
    held-out split). ``seq_cfg``: overrides of :class:`~mjxsysid.cfm.sequence.SeqCFMConfig`
    (its velocity field and optimiser are ``cfg``'s).

    Interrupted runs resume (``resume``): each decoder checkpoints its training state to
    ``out/<kind>.ckpt.npz`` every ``checkpoint_every`` epochs (removed once ``out/<kind>.npz``
    is written), and a decoder already written for the same config and pairs is kept."""
    out = Path(out)
    arrays, meta = load_pairs(pairs)
    has_traj = "zhat_traj_train" in arrays
    if kinds is None:
        kinds = KINDS if has_traj else ("cfm", "regression")
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise ValueError(f"unknown decoder kind(s) {bad}; choose from {KINDS}")
    if "cfm_seq" in kinds and not has_traj:
        raise ValueError(f"{pairs}: no latent trajectories (zhat_traj_train) for the sequence decoder: "
                         f"collect them with `mjxsysid collect --seconds S`")
    out.mkdir(parents=True, exist_ok=True)
    log = tee(log, out / "train_log.txt")
    norm = decoder_normalizer(meta.get("prior", "default"), coords=cfg.coords)
    flow = lambda theta: np.asarray(norm.to_flow(norm.normalize(theta)))   # what the networks learn
    th, z = _usable(arrays, "train")
    tv, zv = _usable(arrays, "test")
    if len(th) < 2 or len(tv) < 1:
        raise ValueError(f"{pairs}: only {len(th)} training and {len(tv)} held-out pairs come from flights the "
                         f"policy did not lose ({len(arrays['theta_train'])} + {len(arrays['theta_test'])} collected): "
                         f"too few to train decoders on")
    pairs_path = Path(pairs) / "pairs.npz" if Path(pairs).is_dir() else Path(pairs)
    data = {"pairs_sha256": hashlib.sha256(pairs_path.read_bytes()).hexdigest(), "pairs_meta": meta,
            "n_train": int(len(th)), "n_val": int(len(tv))}
    res = {}
    if "cfm_seq" in kinds:
        ths, zts = _usable_traj(arrays, "train")
        tvs, zvs = _usable_traj(arrays, "test")
        flat = zts.reshape(-1, zts.shape[-1])
        scfg = SeqCFMConfig.from_single(cfg, max_len=int(zts.shape[1]), z_dim=int(zts.shape[2]),
                                        z_shift=tuple(float(x) for x in flat.mean(0)),
                                        z_scale=tuple(float(x) for x in flat.std(0) + 1e-6))
        if seq_cfg:
            scfg = dataclasses.replace(scfg, **seq_cfg)
        final, ckpt = out / "cfm_seq.npz", out / "cfm_seq.ckpt.npz"
        kept = _already_trained(final, ckpt, scfg.to_dict(), data["pairs_sha256"], resume)
        if kept is not None:
            log(f"{final} is already trained on these pairs with this config: kept")
            res["cfm_seq"] = kept
        else:
            log(f"training cfm_seq on {len(ths)} flights × {zts.shape[1]} latents ({scfg.epochs} epochs, batch {scfg.batch})")
            t0 = time.time()
            params, hist = train_seq_cfm(flow(ths), zts, scfg, log=log,
                                         val=(flow(tvs), zvs), checkpoint=ckpt,
                                         checkpoint_every=checkpoint_every)
            wall = time.time() - t0
            info = {"data": data, "wall_s": wall, "device": str(jax.devices()[0]), "jax": jax.__version__,
                    "final_train_loss": float(hist["train_loss"][-1]),
                    "final_val_loss": float(hist["val_loss"][-1]),
                    "val_loss_min": float(np.min(hist["val_loss"])),
                    "val_loss_argmin_epoch": int(np.argmin(hist["val_loss"]) + 1),
                    "steps_per_s": float(np.mean(hist["steps_per_s"][1:] or hist["steps_per_s"])),
                    "n_params": int(sum(np.size(a) for a in jax.tree.leaves(params))),
                    "traj_times": [float(x) for x in arrays["traj_times"]],
                    "traj_rate_hz": float(meta.get("traj_rate_hz", 10.0)), "stored_dtype": "float16"}
            save_seq_decoder(final, _half(params), scfg, norm, info)
            ckpt.unlink(missing_ok=True)
            res["cfm_seq"] = info
    for kind in ("cfm", "regression"):
        if kind not in kinds:
            continue
        final, ckpt = out / f"{kind}.npz", out / f"{kind}.ckpt.npz"
        kept = _already_trained(final, ckpt, cfg.to_dict(), data["pairs_sha256"], resume)
        if kept is not None and (kind == "cfm" or "early_stopping" in kept):
            log(f"{final} is already trained on these pairs with this config: kept")
            res[kind] = kept
            continue
        extra = {}
        if kind == "regression":  # early stopping on a split of the training pairs, never on the held-out ones
            tr, va = validation_split(len(th), cfg.seed)
            log(f"training regression on {len(tr)} pairs, early stopping on {len(va)} more "
                f"({VAL_FRACTION:.0%} of the training pairs; {cfg.epochs} epochs at most, batch {cfg.batch})")
            t0 = time.time()
            params, hist = train_regression(flow(th[tr]), z[tr], cfg, log=log, val=(flow(th[va]), z[va]),
                                            checkpoint=ckpt, checkpoint_every=checkpoint_every)
            extra = {"early_stopping": {"best_epoch": int(hist["best_epoch"]),
                                        "best_val_loss": float(hist["best_val_loss"]),
                                        "validation": f"{len(va)} of the {len(th)} training pairs "
                                                      f"({VAL_FRACTION:.0%}, seed {cfg.seed})"},
                     "val_loss_curve": [float(v) for v in hist["val_loss"]]}
        else:
            log(f"training {kind} on {len(th)} pairs ({cfg.epochs} epochs, batch {cfg.batch})")
            t0 = time.time()
            params, hist = train_cfm(flow(th), z, cfg, log=log, val=(flow(tv), zv), checkpoint=ckpt,
                                     checkpoint_every=checkpoint_every)
        wall = time.time() - t0
        info = {"data": data, "wall_s": wall, "device": str(jax.devices()[0]), "jax": jax.__version__,
                "final_train_loss": float(hist["train_loss"][-1]),
                "final_val_loss": float(hist["val_loss"][-1]) if hist.get("val_loss") else None,
                "steps_per_s": float(np.mean(hist["steps_per_s"][1:] or hist["steps_per_s"])),
                "stored_dtype": "float16", **extra}
        save_decoder(final, kind, _half(params), cfg, norm, info)
        ckpt.unlink(missing_ok=True)
        res[kind] = info
    return res


VAL_FRACTION = 0.1
"""Share of the training pairs the Regression baseline validates on for early stopping."""


def validation_split(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(train, validation) indices of ``n`` training pairs: a seeded permutation's last
    :data:`VAL_FRACTION` (at least one pair) for validation, sorted."""
    if n < 2:
        raise ValueError(f"early stopping needs at least 2 training pairs, got {n}")
    perm = np.random.default_rng(seed).permutation(n)
    n_val = max(1, int(round(VAL_FRACTION * n)))
    return np.sort(perm[:-n_val]), np.sort(perm[-n_val:])


def _nearby_theta(z_query, z_pool, theta_pool, k):
    """θ of the k pool latents nearest each query latent. (m, 8) -> (m, k, 19)."""
    d = ((z_query[:, None, :] - z_pool[None, :, :]) ** 2).sum(-1)
    idx = np.argsort(d, 1)[:, :k]
    return theta_pool[idx]


def _ident_log(theta):
    """Identifiable combinations of physical θ (..., 19), in log space -> (..., 5)."""
    return np.log(np.abs(np.asarray(P.identifiable(theta))) + 1e-12)


def posterior_scores(s_norm, t_norm, norm) -> dict:
    """Scores of normalised samples (m, S, 19) against normalised truths (m, 19): energy score,
    coverage of central 50 / 90 % intervals and mean 90 % widths (normalised θ; identifiable
    combinations in log space), and how many 90 % coverages lie within ±5 points."""
    s_norm = np.asarray(s_norm, np.float32)
    t_norm = np.asarray(t_norm, np.float32)
    cov = C.coverage(s_norm, t_norm, (0.5, 0.9))                           # (2, 19)
    lo, hi = C.central_intervals(s_norm, 0.9)
    si = _ident_log(np.asarray(norm.denormalize(s_norm)))
    ti = _ident_log(np.asarray(norm.denormalize(t_norm)))
    cov_id = C.coverage(si, ti, (0.5, 0.9))
    ilo, ihi = C.central_intervals(si, 0.9)
    es = C.energy_score(s_norm, t_norm)
    return {
        "n_cases": int(len(t_norm)), "n_samples": int(s_norm.shape[1]),
        "energy_score": float(np.mean(es)),
        "coverage_50": {n: float(cov[0, j]) for j, n in enumerate(P.PARAM_NAMES)},
        "coverage_90": {n: float(cov[1, j]) for j, n in enumerate(P.PARAM_NAMES)},
        "coverage_90_identifiable": {n: float(cov_id[1, j]) for j, n in enumerate(P.IDENTIFIABLE_NAMES)},
        "coverage_50_identifiable": {n: float(cov_id[0, j]) for j, n in enumerate(P.IDENTIFIABLE_NAMES)},
        "width_90_norm": {n: float(np.mean(hi[:, j] - lo[:, j])) for j, n in enumerate(P.PARAM_NAMES)},
        "width_90_norm_mean": float(np.mean(hi - lo)),
        "width_90_identifiable_log": {n: float(np.mean(ihi[:, j] - ilo[:, j]))
                                      for j, n in enumerate(P.IDENTIFIABLE_NAMES)},
        "coverage_90_within_5_points": int(np.sum(np.abs(cov[1] - 0.9) <= WITHIN_5_POINTS)),
        "identifiable_90_within_5_points": int(np.sum(np.abs(cov_id[1] - 0.9) <= WITHIN_5_POINTS)),
        "_energy_per_case": es,
    }


def _public(scores: dict) -> dict:
    return {k: v for k, v in scores.items() if not k.startswith("_")}


def prior_reference(t_norm, norm, prior: str, key, n_samples: int) -> dict:
    """Scores of samples drawn from the prior itself (the same for every case): what a decoder
    that ignores the latent achieves. t_norm (m, 19) normalised truths."""
    ps = np.asarray(norm.normalize(P.get_prior(prior).sample(key, n_samples)), np.float32)
    return posterior_scores(np.broadcast_to(ps, (len(t_norm),) + ps.shape), t_norm, norm)


def evaluate_sequence(seq, pairs, *, cfm=None, n_cases: int = 1000, n_samples: int = 200, seed: int = 0,
                      at_s: float = 4.0, paper_traj=None, log=print) -> dict:
    """Flight-level vs single-latent decoding on held-out flights.

    For each held-out flight: the sequence decoder given all latents recorded up to ``at_s`` s
    (flight-level), given the one latent at ``at_s`` s (single latent, same model) and given the
    whole flight; the single-latent CFM ``cfm`` (if given) on that latent; the prior. Each:
    :func:`posterior_scores`. ``paper_traj`` = (ẑ (L, 8), times (L,)) of the paper vehicle
    flying a lemniscate: its flight-level posterior at the end and the relative 5–95 % widths
    of thrust-to-weight and the angular authorities."""
    arrays, meta = load_pairs(pairs)
    if "zhat_traj_test" not in arrays:
        raise ValueError(f"{pairs}: no latent trajectories (zhat_traj_test): collect with `mjxsysid collect --seconds S`")
    norm = seq.normalizer
    tv, zt = _usable_traj(arrays, "test")
    kind_all = arrays.get("manoeuvre_test")
    ok = ~arrays.get("failed_test", np.zeros(len(arrays["theta_test"]), bool))
    kinds = kind_all[ok] if kind_all is not None else None
    m = min(n_cases, len(tv))
    tv, zt = tv[:m], zt[:m]
    times = np.asarray(arrays["traj_times"])
    L = len(times)
    upto = np.flatnonzero(times <= at_s + 1e-6)
    if len(upto) == 0:
        raise ValueError(f"no latent recorded by {at_s} s (first at {times[0]:.2f} s)")
    i_at = int(upto[-1])
    t_norm = np.asarray(norm.normalize(tv))
    key = jax.random.PRNGKey(seed)
    res = {"at_s": float(times[i_at]), "n_latents_flight": int(i_at + 1), "flight_s": float(times[-1]),
           "n_latents_whole_flight": L, "windows": {}}
    windows = {
        "single_latent": np.arange(L) == i_at,
        f"flight_{at_s:g}s": np.arange(L) <= i_at,
        "whole_flight": np.ones(L, bool),
    }
    t0 = time.time()
    per_case = {}
    for j, (name, msk) in enumerate(progress(windows.items(), desc="evaluate sequence decoder", unit="window")):
        s_norm = np.asarray(seq.sample_norm(zt, jax.random.fold_in(key, j), n_samples,
                                            mask=np.broadcast_to(msk, (m, L))))
        sc = posterior_scores(s_norm, t_norm, norm)
        per_case[name] = sc["_energy_per_case"]
        res["windows"][name] = _public(sc)
    if cfm is not None:
        s_norm = np.asarray(cfm.sample_norm(zt[:, i_at], jax.random.fold_in(key, 7), n_samples))
        sc = posterior_scores(s_norm, t_norm, norm)
        res["windows"]["single_latent_cfm"] = _public(sc)
        per_case["single_latent_cfm"] = sc["_energy_per_case"]
    res["windows"]["prior"] = _public(prior_reference(t_norm, norm, meta.get("prior", "default"),
                                                      jax.random.fold_in(key, 8), n_samples))
    log(f"sequence decoder: {m} flights × {len(windows)} windows × {n_samples} samples in {time.time() - t0:.1f} s")
    fl, single = f"flight_{at_s:g}s", "single_latent"
    es = {k: v["energy_score"] for k, v in res["windows"].items()}
    res["energy_ratio_flight_vs_single"] = es[fl] / es[single]
    if "single_latent_cfm" in es:
        res["energy_ratio_flight_vs_single_cfm"] = es[fl] / es["single_latent_cfm"]
    if kinds is not None:
        names = meta.get("manoeuvres", list(MANOEUVRES))
        res["energy_by_manoeuvre"] = {
            names[k]: {w: float(np.mean(per_case[w][kinds[:m] == k])) for w in per_case}
            for k in np.unique(kinds[:m])}
    f = res["windows"][fl]
    res["targets"] = {
        "energy_ratio_le_0.6": bool(res["energy_ratio_flight_vs_single"] <= 0.6),
        "params_cov90_within_5_points": f["coverage_90_within_5_points"],
        "params_cov90_target_17_of_19": bool(f["coverage_90_within_5_points"] >= 17),
        "identifiable_cov90_all_within_5_points": bool(f["identifiable_90_within_5_points"] == len(P.IDENTIFIABLE_NAMES)),
    }
    if paper_traj is not None:
        res["paper_vehicle"] = paper_vehicle_widths(seq, *paper_traj, cfm=cfm, seed=seed)
    return res


def paper_vehicle_widths(seq, zhat, times, *, cfm=None, n_samples: int = 1000, seed: int = 0) -> dict:
    """The paper vehicle's flight-level posterior given all its latents (L, 8) at 10 Hz:
    per parameter / identifiable combination mean, q05, q95, truth inside, and
    (q95 − q05) / true; the single-latent CFM on the last latent for comparison."""
    key = jax.random.PRNGKey(seed + 11)
    zhat = np.asarray(zhat, np.float32)
    out = {"flight_s": float(times[-1]), "n_latents": int(len(zhat))}
    post = {"flight": np.asarray(seq.sample_theta(zhat, key, n_samples))}
    if cfm is not None:
        post["single_latent_cfm"] = np.asarray(cfm.sample_theta(zhat[-1], key, n_samples))
    post["single_latent_seq"] = np.asarray(seq.sample_theta(zhat[-1:], key, n_samples))
    for name, s in post.items():
        summ = summarize_posterior(s, P.PAPER_HARDWARE)
        for v in summ.values():
            v["rel_width_90"] = float((v["q95"] - v["q05"]) / v["true"]) if v["true"] != 0 else None
        out[name] = summ
        out[f"{name}_inside"] = int(sum(summ[n]["inside"] for n in P.PARAM_NAMES))
    f = out["flight"]
    aa = [f"angular_authority[{i}]" for i in range(3)]
    out["targets"] = {
        "thrust_to_weight_rel_width_le_0.25": bool(f["thrust_to_weight"]["rel_width_90"] <= 0.25
                                                   and f["thrust_to_weight"]["inside"]),
        "angular_authority_rel_width_le_0.30": bool(all(f[a]["rel_width_90"] <= 0.30 and f[a]["inside"] for a in aa)),
    }
    return out


def evaluate_decoders(out, pairs, *, n_cases: int = 1000, n_samples: int = 200, seed: int = 0,
                      paper_zhat=None, paper_traj=None, log=print) -> dict:
    """Calibration of the decoders in ``out`` on held-out pairs (see the issue's list), with the
    prior as a reference; the sequence decoder (``cfm_seq.npz``, if present) flight-level vs
    single-latent (:func:`evaluate_sequence`, key ``sequence``). Writes out/decoder_eval.json."""
    out = Path(out)
    have_single = (out / "cfm.npz").is_file() and (out / "regression.npz").is_file()
    have_seq = (out / "cfm_seq.npz").is_file()
    if not (have_single or have_seq):
        raise FileNotFoundError(f"no decoders in {out}: need cfm.npz and regression.npz and/or cfm_seq.npz")
    rep = {}
    cfm = Decoder.load(out / "cfm.npz") if (out / "cfm.npz").is_file() else None
    if have_single:
        rep = _evaluate_single(out, pairs, n_cases=n_cases, n_samples=n_samples, seed=seed,
                               paper_zhat=paper_zhat, log=log)
    if have_seq:
        seq = SequenceDecoder.load(out / "cfm_seq.npz")
        rep["sequence"] = evaluate_sequence(seq, pairs, cfm=cfm, n_cases=n_cases, n_samples=n_samples,
                                            seed=seed, paper_traj=paper_traj, log=log)
    (out / "decoder_eval.json").write_text(jsonout.dumps(rep, indent=2) + "\n")
    return rep


def _evaluate_single(out, pairs, *, n_cases, n_samples, seed, paper_zhat, log) -> dict:
    cfm = Decoder.load(out / "cfm.npz")
    reg = Decoder.load(out / "regression.npz")
    norm = cfm.normalizer
    arrays, meta = load_pairs(pairs)
    tv, zv = _usable(arrays, "test")
    ttr, ztr = _usable(arrays, "train")
    m = min(n_cases, len(tv))
    tv, zv = tv[:m], zv[:m]
    key = jax.random.PRNGKey(seed)
    st = stages(["sampling", "coverage and SBC", "energy score", "C2ST", "paper vehicle"],
                desc="evaluate-decoder")
    st.start("sampling")
    t0 = time.time()
    s_norm = np.asarray(cfm.sample_norm(zv, key, n_samples))           # (m, S, 19)
    t_norm = np.asarray(norm.normalize(tv))                             # (m, 19)
    log(f"sampled {m} × {n_samples} in {time.time() - t0:.1f} s")
    st.start("coverage and SBC")
    rep = C.calibration_report(s_norm, t_norm, names=P.PARAM_NAMES, seed=seed)
    ranks = C.sbc_ranks(s_norm, t_norm, seed)
    plot_rank_histograms(ranks, n_samples, out / "sbc_ranks.png", pvalues=C.sbc_uniformity(ranks, n_samples),
                         names=P.PARAM_NAMES)
    # Identifiable combinations, in log space.
    s_phys = np.asarray(norm.denormalize(s_norm))
    cov_id = C.coverage(_ident_log(s_phys), _ident_log(tv))
    rep["coverage_identifiable"] = {n: cov_id[:, j].tolist() for j, n in enumerate(P.IDENTIFIABLE_NAMES)}
    # Energy score (normalised space) against Regression and Random.
    st.start("energy score")
    reg_pt = np.asarray(reg.point_norm(zv))
    rnd = np.asarray(norm.normalize(random_baseline(jax.random.fold_in(key, 9), n_samples)))
    prior_ref = prior_reference(t_norm, norm, meta.get("prior", "default"), jax.random.fold_in(key, 8), n_samples)
    rep["energy_score"] = {
        "cfm": float(np.mean(C.energy_score(s_norm, t_norm))),
        "regression": float(np.mean(C.point_scores(reg_pt, t_norm)["energy"])),
        "random": float(np.mean(C.energy_score(np.broadcast_to(rnd, (m,) + rnd.shape), t_norm))),
        "prior": prior_ref["energy_score"],
    }
    rep["prior_reference"] = _public(prior_ref)
    rep["cfm_scores"] = _public(posterior_scores(s_norm, t_norm, norm))
    rep["rmse_norm"] = {"cfm_mean": float(np.sqrt(((s_norm.mean(1) - t_norm) ** 2).mean())),
                        "regression": float(np.sqrt(((reg_pt - t_norm) ** 2).mean()))}
    # C2ST: CFM samples for a latent vs the true θ of the 50 training pairs with the nearest latents.
    st.start("C2ST")
    q = min(20, m)
    near = _nearby_theta(zv[:q], ztr, np.asarray(norm.normalize(ttr)), 50)
    acc = [C.c2st(s_norm[i, :50], near[i], seed=seed) for i in range(q)]
    rep["c2st_nearby_latents"] = {"mean_accuracy": float(np.mean(acc)), "n_latents": q, "k": 50}
    # Calibration bands: nominal level ± 5 points.
    cov = np.array([rep["coverage"][n] for n in P.PARAM_NAMES])        # (19, 2)
    inside = np.abs(cov - np.array(rep["levels"])) <= WITHIN_5_POINTS
    rep["calibrated_within_5_points"] = {"50%": int(inside[:, 0].sum()), "90%": int(inside[:, 1].sum()),
                                         "of": len(P.PARAM_NAMES)}
    st.start("paper vehicle")
    if paper_zhat is not None:
        ps = np.asarray(cfm.sample_theta(np.asarray(paper_zhat, np.float32), jax.random.fold_in(key, 3), 1000))
        plot_marginals(ps, P.PAPER_HARDWARE, out / "paper_vehicle_posterior.png",
                       point=np.asarray(reg.point(np.asarray(paper_zhat, np.float32))))
        q05, q95 = np.percentile(ps, [5, 95], 0)
        rep["paper_vehicle"] = {n: {"mean": float(ps[:, j].mean()), "q05": float(q05[j]), "q95": float(q95[j]),
                                    "true": float(P.PAPER_HARDWARE[j]),
                                    "inside": bool(q05[j] <= P.PAPER_HARDWARE[j] <= q95[j])}
                                for j, n in enumerate(P.PARAM_NAMES)}
    st.close()
    return rep


