"""Gradient-free search of latent space for where a score is high.

Candidates are perturbations and stretches of anchor latents (e.g. the latents of prior vehicles):

    z = m + s (a_i − m) + δ ⊙ σ_z        a_i an anchor drawn uniformly, m the anchors' mean,
                                          σ_z their std per dimension, s = exp(λ) a stretch

and a cross-entropy method over x = (δ (z_dim), λ) moves a Gaussian towards the candidates with
the highest score: the search finds *regions* (a direction of δ, a stretch) rather than single
points. ``score_fn`` (N, z_dim) -> (N,) is any batched badness (:mod:`mjxsysid.probe.closed_loop`:
how much worse than the oracle the policy flies the decoded systems); the search itself is pure
numpy around it.
"""
from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np


@dataclasses.dataclass(frozen=True)
class SearchConfig:
    """population: candidates per iteration; iterations; elite: the fraction refitted to;
    sigma0: initial std of δ (in units of the anchors' std); stretch_max: s at most this (≥ 1;
    ``λ`` starts at log 1 = 0, std log(stretch_max) / 2, clipped to [−log stretch_max, log stretch_max]);
    keep: how many of the best candidates (all iterations) are returned; seed."""
    population: int = 64
    iterations: int = 4
    elite: float = 0.25
    sigma0: float = 0.5
    stretch_max: float = 2.0
    keep: int = 16
    seed: int = 0

    def __post_init__(self):
        if self.population < 2 or self.iterations < 1 or self.keep < 1:
            raise ValueError("SearchConfig: population >= 2, iterations >= 1 and keep >= 1 required")
        if not 0.0 < self.elite <= 1.0:
            raise ValueError(f"SearchConfig.elite must be in (0, 1], got {self.elite}")
        if not (self.sigma0 > 0 and self.stretch_max >= 1.0):
            raise ValueError("SearchConfig: sigma0 > 0 and stretch_max >= 1 required")


def candidates(x, anchors, pick, mean, scale):
    """Latents (N, z_dim) of search points x (N, z_dim + 1) = (δ, λ) on anchors[pick] (N,)."""
    return mean + np.exp(x[:, -1:]) * (anchors[pick] - mean) + x[:, :-1] * scale


def latent_search(score_fn: Callable[[np.ndarray], np.ndarray], anchors, cfg: SearchConfig = SearchConfig(),
                  progress: Callable[[int, float], None] | None = None) -> dict:
    """Search around ``anchors`` (m, z_dim) for latents of high ``score_fn``. Returns dict with z
    (keep, z_dim) and score (keep,) of the best candidates seen (highest first), the final
    Gaussian (mu, std over (δ, λ)) and per-iteration mean / best scores."""
    anchors = np.asarray(anchors, np.float64)
    if anchors.ndim != 2 or len(anchors) < 1 or not np.isfinite(anchors).all():
        raise ValueError(f"anchors must be finite latents of shape (m, z_dim), m >= 1; got {anchors.shape}")
    d = anchors.shape[1]
    mean = anchors.mean(0)
    scale = anchors.std(0) + 1e-6 if len(anchors) > 1 else np.ones(d)
    lmax = float(np.log(cfg.stretch_max))
    mu = np.zeros(d + 1)
    std = np.concatenate([np.full(d, cfg.sigma0), [max(lmax / 2, 1e-6)]])
    rng = np.random.default_rng(cfg.seed)
    n_elite = max(int(round(cfg.elite * cfg.population)), 1)
    all_z, all_s, hist = [], [], []
    for it in range(cfg.iterations):
        x = mu + std * rng.standard_normal((cfg.population, d + 1))
        x[:, -1] = np.clip(x[:, -1], -lmax, lmax)
        z = candidates(x, anchors, rng.integers(0, len(anchors), cfg.population), mean, scale)
        s = np.asarray(score_fn(z.astype(np.float32)), np.float64)
        if s.shape != (cfg.population,):
            raise ValueError(f"score_fn must return ({cfg.population},) scores; got {s.shape}")
        s = np.where(np.isfinite(s), s, -np.inf)
        top = np.argsort(-s)[:n_elite]
        mu, std = x[top].mean(0), np.maximum(x[top].std(0), 0.05 * np.concatenate([np.full(d, cfg.sigma0), [1.0]]))
        all_z.append(z)
        all_s.append(s)
        hist.append({"iteration": it, "mean_score": float(np.mean(s[np.isfinite(s)])) if np.isfinite(s).any() else None,
                     "best_score": float(s.max())})
        if progress is not None:
            progress(it, float(s.max()))
    z, s = np.concatenate(all_z), np.concatenate(all_s)
    best = np.argsort(-s)[:cfg.keep]
    return {"z": z[best].astype(np.float32), "score": s[best], "mu": mu, "std": std, "history": hist,
            "anchor_mean": mean, "anchor_scale": scale}
