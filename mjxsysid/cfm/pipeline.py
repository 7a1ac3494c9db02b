"""Train the shipped decoders from a (θ, ẑ) dataset and evaluate their calibration.

    train_decoders(pairs.npz, out)   -> out/cfm.npz, out/regression.npz (float16 weights)
    evaluate_decoders(out, pairs.npz) -> out/decoder_eval.json + figures

Weights are stored in float16 (5 M parameters: 10 MB instead of 21 MB) and evaluated *after*
that rounding, so the figures describe exactly what ships.
"""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import params as P
from mjxsysid.cfm import calibration as C
from mjxsysid.cfm.sample import Decoder, random_baseline, sample
from mjxsysid.cfm.train import CFMConfig, save_decoder, train_cfm, train_regression
from mjxsysid.policy.collect import load_pairs


def _half(params):
    return jax.tree.map(lambda a: np.asarray(a, np.float16), params)


def _usable(arrays, split):
    ok = ~arrays.get(f"failed_{split}", np.zeros(len(arrays[f"theta_{split}"]), bool))
    return arrays[f"theta_{split}"][ok], arrays[f"zhat_{split}"][ok]


def train_decoders(pairs, out, cfg: CFMConfig = CFMConfig(), *, log=print, resume: bool = True,
                   checkpoint_every: int = 10) -> dict:
    """Train CFM and Regression on the training split (validation: the held-out split).

    Interrupted runs resume (``resume``): each decoder checkpoints its training state to
    ``out/<kind>.ckpt.npz`` every ``checkpoint_every`` epochs (removed once ``out/<kind>.npz``
    is written), and a decoder already written for the same config and pairs is kept."""
    from mjxsysid.policy.checkpoint import load_meta
    out = Path(out)
    arrays, meta = load_pairs(pairs)
    out.mkdir(parents=True, exist_ok=True)
    from mjxsysid.progress import tee
    log = tee(log, out / "train_log.txt")
    norm = P.prior_normalizer(meta.get("prior", "default"))
    th, z = _usable(arrays, "train")
    tv, zv = _usable(arrays, "test")
    pairs_path = Path(pairs) / "pairs.npz" if Path(pairs).is_dir() else Path(pairs)
    data = {"pairs_sha256": hashlib.sha256(pairs_path.read_bytes()).hexdigest(), "pairs_meta": meta,
            "n_train": int(len(th)), "n_val": int(len(tv))}
    res = {}
    for kind, fit in (("cfm", train_cfm), ("regression", train_regression)):
        final, ckpt = out / f"{kind}.npz", out / f"{kind}.ckpt.npz"
        if not resume:
            ckpt.unlink(missing_ok=True)
        elif final.is_file() and not ckpt.is_file():
            try:
                done = load_meta(final)
            except ValueError:
                done = {}
            info = done.get("meta", {})
            if (done.get("config") == cfg.to_dict()
                    and info.get("data", {}).get("pairs_sha256") == data["pairs_sha256"]):
                log(f"{final} is already trained on these pairs with this config: kept")
                res[kind] = info
                continue
        log(f"training {kind} on {len(th)} pairs ({cfg.epochs} epochs, batch {cfg.batch})")
        t0 = time.time()
        params, hist = fit(np.asarray(norm.normalize(th)), z, cfg, log=log,
                           val=(np.asarray(norm.normalize(tv)), zv), checkpoint=ckpt,
                           checkpoint_every=checkpoint_every)
        wall = time.time() - t0
        info = {"data": data, "wall_s": wall, "device": str(jax.devices()[0]), "jax": jax.__version__,
                "final_train_loss": float(hist["train_loss"][-1]),
                "final_val_loss": float(hist["val_loss"][-1]) if hist.get("val_loss") else None,
                "steps_per_s": float(np.mean(hist["steps_per_s"][1:] or hist["steps_per_s"])),
                "stored_dtype": "float16"}
        save_decoder(final, kind, _half(params), cfg, norm, info)
        ckpt.unlink(missing_ok=True)
        res[kind] = info
    return res


def _nearby_theta(z_query, z_pool, theta_pool, k):
    """θ of the k pool latents nearest each query latent. (m, 8) -> (m, k, 19)."""
    d = ((z_query[:, None, :] - z_pool[None, :, :]) ** 2).sum(-1)
    idx = np.argsort(d, 1)[:, :k]
    return theta_pool[idx]


def evaluate_decoders(out, pairs, *, n_cases: int = 1000, n_samples: int = 200, seed: int = 0,
                      paper_zhat=None, log=print) -> dict:
    """Calibration of the decoders in ``out`` on held-out pairs (see the issue's list)."""
    out = Path(out)
    cfm = Decoder.load(out / "cfm.npz")
    reg = Decoder.load(out / "regression.npz")
    norm = cfm.normalizer
    arrays, _ = load_pairs(pairs)
    tv, zv = _usable(arrays, "test")
    ttr, ztr = _usable(arrays, "train")
    m = min(n_cases, len(tv))
    tv, zv = tv[:m], zv[:m]
    key = jax.random.PRNGKey(seed)
    from mjxsysid.progress import stages
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
    C.plot_rank_histograms(ranks, n_samples, out / "sbc_ranks.png", names=P.PARAM_NAMES)
    # Identifiable combinations, in log space.
    ident = lambda th: np.log(np.abs(np.asarray(P.identifiable(th))) + 1e-12)
    s_phys = np.asarray(norm.denormalize(s_norm))
    cov_id = C.coverage(ident(s_phys), ident(tv))
    rep["coverage_identifiable"] = {n: cov_id[:, j].tolist() for j, n in enumerate(P.IDENTIFIABLE_NAMES)}
    # Energy score (normalised space) against Regression and Random.
    st.start("energy score")
    reg_pt = np.asarray(reg.point_norm(zv))
    rnd = np.asarray(norm.normalize(random_baseline(jax.random.fold_in(key, 9), n_samples)))
    rep["energy_score"] = {
        "cfm": float(np.mean(C.energy_score(s_norm, t_norm))),
        "regression": float(np.mean(C.point_scores(reg_pt, t_norm)["energy"])),
        "random": float(np.mean(C.energy_score(np.broadcast_to(rnd, (m,) + rnd.shape), t_norm))),
    }
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
    inside = np.abs(cov - np.array(rep["levels"])) <= 0.05
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
    (out / "decoder_eval.json").write_text(json.dumps(rep, indent=2) + "\n")
    return rep


def plot_marginals(samples, truth, path, *, point=None, title="decoded posterior vs truth"):
    """Histograms of decoded θ samples (n, 19), truth (19,) marked; optional point estimate."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(4, 5, figsize=(17, 11))
    for j, ax in enumerate(axes.flat):
        if j >= P.N_PARAMS:
            ax.axis("off")
            continue
        x = samples[:, j]
        log = P.LOG_MASK[j] and np.all(x > 0)
        bins = np.geomspace(x.min(), x.max(), 30) if log and x.min() < x.max() else 30
        ax.hist(x, bins=bins, color="tab:blue", alpha=0.7)
        if log:
            ax.set_xscale("log")
        ax.axvline(truth[j], color="k", lw=2, label="true")
        if point is not None:
            ax.axvline(point[j], color="tab:orange", ls="--", label="regression")
        ax.set_title(f"{P.PARAM_NAMES[j]} [{P.PARAM_UNITS[j]}]", fontsize=9)
        ax.set_yticks([])
    axes.flat[0].legend(fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
