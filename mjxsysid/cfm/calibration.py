"""Calibration and scoring of a conditional sampler p(θ | z) (host side: numpy / scipy).

Conventions: ``samples`` (m, S, d) — S posterior samples for each of m held-out cases;
``truths`` (m, d) — the true θ of each case. Use normalised θ (``Normalizer.normalize``) for
the multivariate scores so that the dimensions are commensurate; coverage and SBC ranks are
invariant to monotone per-dimension maps, so physical or normalised units give the same.

- :func:`coverage`: fraction of cases whose truth lies in the central ``level`` interval of
  its samples, [q_{(1−level)/2}, q_{(1+level)/2}] (empirical quantiles, linear interpolation),
  per dimension -> (L, d). A calibrated sampler gives ≈ level; lower = over-confident.
- :func:`sbc_ranks`: rank of the truth among its S samples, r = #{s : x_s < y} (+ a uniform
  draw among ties), per dimension, in {0, ..., S} -> (m, d). Calibrated ⇒ r ~ U{0..S}
  (Talts et al. 2018).
- :func:`sbc_uniformity`: KS-test p-values (d,) of u = (r + U[0, 1)) / (S + 1) against U(0, 1)
  (the jitter makes u exactly U(0, 1) under calibration).
- :func:`c2st`: classifier two-sample test — k-fold held-out accuracy of a classifier (small
  numpy MLP or logistic regression, L-BFGS, L2) telling set A from set B (balanced by
  subsampling, features standardised on the training folds). 0.5 = indistinguishable, 1 =
  separable.
- :func:`energy_score`: ES(P, y) = E‖X − y‖ − ½ E‖X − X'‖ (X, X' ~ P independent), estimated
  with (1/S) Σ_s ‖x_s − y‖ − ½ · 2/(S(S−1)) Σ_{s<t} ‖x_s − x_t‖ (unbiased: the spread term
  averages over the S(S−1)/2 distinct pairs). Strictly proper; lower is better.
- :func:`crps`: the 1-d energy score per dimension, E|X − y| − ½ E|X − X'| -> (m, d).
- :func:`point_scores`: a point estimate p is the degenerate distribution δ_p, whose energy
  score is ‖p − y‖ (the spread term is 0; per-dimension CRPS = |p − y|); reported with the
  MAE and RMSE per dimension.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np


def _check(samples, truths):
    s = np.asarray(samples, np.float64)
    t = np.asarray(truths, np.float64)
    if s.ndim != 3:
        raise ValueError(f"samples must have shape (m, S, d); got {s.shape}")
    if t.shape != (s.shape[0], s.shape[2]):
        raise ValueError(f"truths must have shape (m, d) = {(s.shape[0], s.shape[2])}; got {t.shape}")
    return s, t


# ----------------------------------------------------------------------------------------
# Coverage and SBC
# ----------------------------------------------------------------------------------------

def central_intervals(samples, level: float):
    """Empirical central interval per case and dimension: (lo (m, d), hi (m, d))."""
    s = np.asarray(samples, np.float64)
    if not 0 < level < 1:
        raise ValueError(f"level must be in (0, 1), got {level}")
    lo, hi = np.quantile(s, [(1 - level) / 2, (1 + level) / 2], axis=1)
    return lo, hi


def coverage(samples, truths, levels: Sequence[float] = (0.5, 0.9)) -> np.ndarray:
    """Empirical coverage of central intervals: (len(levels), d)."""
    s, t = _check(samples, truths)
    out = []
    for lv in levels:
        lo, hi = central_intervals(s, lv)
        out.append(np.mean((t >= lo) & (t <= hi), axis=0))
    return np.stack(out)


def sbc_ranks(samples, truths, seed: int = 0) -> np.ndarray:
    """Rank of each truth among its samples, per dimension: (m, d) ints in [0, S]."""
    s, t = _check(samples, truths)
    below = np.sum(s < t[:, None, :], axis=1)
    ties = np.sum(s == t[:, None, :], axis=1)
    if ties.any():
        rng = np.random.default_rng(seed)
        below = below + np.floor(rng.random(ties.shape) * (ties + 1)).astype(below.dtype)
    return below.astype(np.int64)


def sbc_uniformity(ranks, n_samples: int, seed: int = 0) -> np.ndarray:
    """KS p-values (d,) of the jittered normalised ranks against U(0, 1)."""
    from scipy import stats

    r = np.asarray(ranks)
    if r.ndim != 2:
        raise ValueError(f"ranks must have shape (m, d); got {r.shape}")
    if r.min() < 0 or r.max() > n_samples:
        raise ValueError(f"ranks must lie in [0, {n_samples}]")
    rng = np.random.default_rng(seed)
    u = (r + rng.random(r.shape)) / (n_samples + 1)
    return np.array([stats.kstest(u[:, j], "uniform").pvalue for j in range(r.shape[1])])


# ----------------------------------------------------------------------------------------
# C2ST
# ----------------------------------------------------------------------------------------

def _mlp_fit(x, y, hidden: int, l2: float, rng, maxiter: int):
    from scipy.optimize import minimize

    n, d = x.shape
    if hidden == 0:  # logistic regression
        shapes = [(d,), (1,)]
    else:
        shapes = [(d, hidden), (hidden,), (hidden,), (1,)]
    sizes = [int(np.prod(s)) for s in shapes]

    def unpack(w):
        out, i = [], 0
        for s, k in zip(shapes, sizes):
            out.append(w[i:i + k].reshape(s))
            i += k
        return out

    def f(w):
        ps = unpack(w)
        if hidden == 0:
            a, b = ps
            logit = x @ a + b[0]
        else:
            w1, b1, w2, b2 = ps
            h = np.tanh(x @ w1 + b1)
            logit = h @ w2 + b2[0]
        # mean BCE with logits, stable
        loss = np.mean(np.logaddexp(0.0, logit) - y * logit)
        g_logit = (1.0 / (1.0 + np.exp(-logit)) - y) / n
        if hidden == 0:
            grads = [x.T @ g_logit + 2 * l2 * a, np.array([g_logit.sum()])]
            loss += l2 * np.sum(a ** 2)
        else:
            g_h = np.outer(g_logit, w2) * (1 - h ** 2)
            grads = [x.T @ g_h + 2 * l2 * w1, g_h.sum(0), h.T @ g_logit + 2 * l2 * w2,
                     np.array([g_logit.sum()])]
            loss += l2 * (np.sum(w1 ** 2) + np.sum(w2 ** 2))
        return loss, np.concatenate([g.ravel() for g in grads])

    if hidden == 0:
        w0 = np.zeros(sum(sizes))
    else:
        w0 = np.concatenate([rng.standard_normal(d * hidden) / np.sqrt(d), np.zeros(hidden),
                             rng.standard_normal(hidden) / np.sqrt(hidden), np.zeros(1)])
    res = minimize(f, w0, jac=True, method="L-BFGS-B", options={"maxiter": maxiter})
    ps = unpack(res.x)

    def predict(xt):
        if hidden == 0:
            return xt @ ps[0] + ps[1][0]
        return np.tanh(xt @ ps[0] + ps[1]) @ ps[2] + ps[3][0]

    return predict


def c2st(a, b, folds: int = 5, seed: int = 0, classifier: str = "mlp", hidden: int = 32,
         l2: float = 1e-3, maxiter: int = 500, return_folds: bool = False):
    """Classifier two-sample test between sample sets a (n_a, d) and b (n_b, d).

    Returns the mean held-out accuracy over ``folds`` stratified folds (and the per-fold
    accuracies if ``return_folds``). ``classifier``: "mlp" (one tanh hidden layer of
    ``hidden`` units) or "logistic". 0.5 = indistinguishable, 1.0 = perfectly separable."""
    if classifier not in ("mlp", "logistic"):
        raise ValueError(f"unknown classifier {classifier!r}; choose 'mlp' or 'logistic'")
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if b.ndim == 1:
        b = b[:, None]
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1]:
        raise ValueError(f"a and b must be (n, d) with the same d; got {a.shape}, {b.shape}")
    rng = np.random.default_rng(seed)
    n = min(len(a), len(b))
    if n < 2 * folds:
        raise ValueError(f"need at least {2 * folds} samples per set for {folds}-fold C2ST; got {n}")
    a = a[rng.permutation(len(a))[:n]]
    b = b[rng.permutation(len(b))[:n]]
    fold_of = np.arange(n) % folds
    accs = []
    for k in range(folds):
        tr, te = fold_of != k, fold_of == k
        xtr = np.concatenate([a[tr], b[tr]])
        ytr = np.concatenate([np.zeros(tr.sum()), np.ones(tr.sum())])
        xte = np.concatenate([a[te], b[te]])
        yte = np.concatenate([np.zeros(te.sum()), np.ones(te.sum())])
        mu, sd = xtr.mean(0), xtr.std(0) + 1e-12
        pred = _mlp_fit((xtr - mu) / sd, ytr, hidden if classifier == "mlp" else 0, l2, rng, maxiter)
        accs.append(float(np.mean((pred((xte - mu) / sd) > 0) == yte)))
    acc = float(np.mean(accs))
    return (acc, np.array(accs)) if return_folds else acc


# ----------------------------------------------------------------------------------------
# Scores
# ----------------------------------------------------------------------------------------

def energy_score(samples, truths) -> np.ndarray:
    """Energy score per case (lower is better). samples (m, S, d) with truths (m, d) -> (m,);
    samples (S, d) with truth (d,) -> scalar. Needs S >= 2."""
    s = np.asarray(samples, np.float64)
    t = np.asarray(truths, np.float64)
    single = s.ndim == 2
    if single:
        s, t = s[None], t[None]
    s, t = _check(s, t)
    S = s.shape[1]
    if S < 2:
        raise ValueError("energy_score needs at least 2 samples per case")
    from scipy.spatial.distance import pdist
    out = np.empty(s.shape[0])
    for i in range(s.shape[0]):
        e1 = np.mean(np.linalg.norm(s[i] - t[i], axis=-1))
        e2 = np.mean(pdist(s[i]))  # mean over S(S−1)/2 distinct pairs = E‖X − X'‖
        out[i] = e1 - 0.5 * e2
    return out[0] if single else out


def crps(samples, truths) -> np.ndarray:
    """Per-dimension CRPS (1-d energy score), (m, S, d) & (m, d) -> (m, d). Uses the sorted
    form E|X − X'| = 2/(S(S−1)) Σ_i (2i − S − 1) x_(i) (unbiased, O(S log S))."""
    s, t = _check(samples, truths)
    S = s.shape[1]
    if S < 2:
        raise ValueError("crps needs at least 2 samples per case")
    e1 = np.mean(np.abs(s - t[:, None, :]), axis=1)
    xs = np.sort(s, axis=1)
    w = (2 * np.arange(1, S + 1) - S - 1)[None, :, None]
    e2 = 2.0 * np.sum(w * xs, axis=1) / (S * (S - 1))
    return e1 - 0.5 * e2


def point_scores(pred, truths) -> dict:
    """Scores of a point estimate (m, d) against truths (m, d): ``energy`` (m,) = ‖p − y‖
    (energy score of δ_p), ``mae`` (d,), ``rmse`` (d,)."""
    p = np.asarray(pred, np.float64)
    t = np.asarray(truths, np.float64)
    if p.ndim != 2 or p.shape != t.shape:
        raise ValueError(f"pred and truths must both be (m, d); got {p.shape}, {t.shape}")
    err = p - t
    return {"energy": np.linalg.norm(err, axis=-1), "mae": np.mean(np.abs(err), 0),
            "rmse": np.sqrt(np.mean(err ** 2, 0))}


def calibration_report(samples, truths, levels: Sequence[float] = (0.5, 0.9),
                       names: Sequence[str] | None = None, seed: int = 0) -> dict:
    """Coverage, SBC KS p-values, mean energy score and mean CRPS in one JSON-able dict."""
    s, t = _check(samples, truths)
    d = s.shape[2]
    names = list(names) if names is not None else [f"dim {j}" for j in range(d)]
    cov = coverage(s, t, levels)
    pv = sbc_uniformity(sbc_ranks(s, t, seed), s.shape[1], seed)
    cr = crps(s, t).mean(0)
    return {
        "n_cases": int(s.shape[0]), "n_samples": int(s.shape[1]),
        "levels": [float(x) for x in levels],
        "coverage": {n: [float(c) for c in cov[:, j]] for j, n in enumerate(names)},
        "coverage_mean": [float(x) for x in cov.mean(1)],
        "sbc_ks_p": {n: float(pv[j]) for j, n in enumerate(names)},
        "crps": {n: float(cr[j]) for j, n in enumerate(names)},
        "energy_score": float(np.mean(energy_score(s, t))),
    }
