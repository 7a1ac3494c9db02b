"""The cross-entropy method over high-level gains, in a bounded, log-scaled space.

A Gaussian search distribution N(mean, diag(std²)) lives in y = log(g + offset) (the
``offset`` keeps the integral gains, whose lower bound is 0, finite), clipped to the image of
:data:`~mjxsysid.control.high_level.GAIN_BOUNDS`. One CEM iteration draws ``n`` candidates
(candidate 0 is the current mean itself, so an iteration never loses the incumbent), scores
them with a cost function, and refits mean and std to the ``elite`` best. Everything is pure
and jit-able; the cost function is traced once.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.control.high_level import GAIN_BOUNDS, GAIN_NAMES

GAIN_OFFSET = np.where(GAIN_BOUNDS[:, 0] > 0, 0.0, 0.1).astype(np.float32)
"""(8,) offset of the log transform: 0.1 for gains whose lower bound is 0 (ki_xy, ki_z)."""


def to_search(g) -> jax.Array:
    """Gains (..., 8) -> search coordinates y = log(g + offset) (..., 8)."""
    return jnp.log(jnp.asarray(g, jnp.float32) + GAIN_OFFSET)


def from_search(y) -> jax.Array:
    """Search coordinates (..., 8) -> gains (..., 8), clipped to GAIN_BOUNDS."""
    g = jnp.exp(jnp.asarray(y, jnp.float32)) - GAIN_OFFSET
    return jnp.clip(g, GAIN_BOUNDS[:, 0], GAIN_BOUNDS[:, 1])


SEARCH_LO = np.log(GAIN_BOUNDS[:, 0] + GAIN_OFFSET).astype(np.float32)
SEARCH_HI = np.log(GAIN_BOUNDS[:, 1] + GAIN_OFFSET).astype(np.float32)
SEARCH_RANGE = SEARCH_HI - SEARCH_LO
"""(8,) bounds and width of the search box in y."""


@dataclasses.dataclass(frozen=True)
class CEMConfig:
    """CEM settings (static).

    candidates: N gain vectors per iteration. iterations: CEM iterations per update.
    elite_frac: fraction of candidates refitted to (at least 2). init_std / warm_std: std of
    the search distribution, as a fraction of the log-box width per gain, at the first update
    and after warm-starting from the previous solution. min_std: floor of the refitted std
    (same units). smoothing: weight of the old mean/std in the refit (0 = plain CEM).
    """
    candidates: int = 32
    iterations: int = 2
    elite_frac: float = 0.125
    init_std: float = 0.3
    warm_std: float = 0.12
    min_std: float = 0.02
    smoothing: float = 0.0

    def __post_init__(self):
        if int(self.candidates) != self.candidates or self.candidates < 1:
            raise ValueError(f"CEM candidates (N) must be an integer >= 1, got {self.candidates}")
        if int(self.iterations) != self.iterations or self.iterations < 1:
            raise ValueError(f"CEM iterations must be an integer >= 1, got {self.iterations}")
        if not 0.0 < self.elite_frac <= 1.0:
            raise ValueError(f"CEM elite_frac must be in (0, 1], got {self.elite_frac}")
        for f in ("init_std", "warm_std", "min_std"):
            if not getattr(self, f) > 0:
                raise ValueError(f"CEM {f} must be > 0, got {getattr(self, f)}")
        if not 0.0 <= self.smoothing < 1.0:
            raise ValueError(f"CEM smoothing must be in [0, 1), got {self.smoothing}")

    @property
    def n_elite(self) -> int:
        return max(2, min(self.candidates, int(round(self.elite_frac * self.candidates))))


class CEMState(NamedTuple):
    """Search distribution in y-space: mean (8,), std (8,); best_cost (): cost of the mean's
    last evaluation (inf before any)."""
    mean: jax.Array
    std: jax.Array
    best_cost: jax.Array


def cem_init(gains0, cfg: CEMConfig) -> CEMState:
    """Initial distribution centred on ``gains0`` (8,) with std ``init_std`` × box width."""
    return CEMState(to_search(gains0), jnp.asarray(cfg.init_std * SEARCH_RANGE, jnp.float32),
                    jnp.float32(jnp.inf))


def cem_warm(state: CEMState, cfg: CEMConfig) -> CEMState:
    """Warm start for the next update: keep the mean, reset the std to ``warm_std`` × width
    (so the search can follow a changing problem). Works on a batch of states too."""
    return state._replace(std=jnp.broadcast_to(jnp.asarray(cfg.warm_std * SEARCH_RANGE, jnp.float32),
                                               state.std.shape))


def cem_candidates(state: CEMState, key, n: int) -> jax.Array:
    """n candidate gain vectors (n, 8); row 0 is the mean itself."""
    eps = jax.random.normal(key, (n, len(GAIN_NAMES)))
    eps = eps.at[0].set(0.0)
    y = jnp.clip(state.mean + state.std * eps, SEARCH_LO, SEARCH_HI)
    return from_search(y)


def cem_refit(state: CEMState, gains, costs, cfg: CEMConfig) -> CEMState:
    """Refit to the elite: gains (n, 8), costs (n,) (non-finite costs count as +inf)."""
    costs = jnp.where(jnp.isfinite(costs), costs, jnp.inf)
    order = jnp.argsort(costs)
    elite = to_search(gains[order[: cfg.n_elite]])
    mean = elite.mean(0)
    std = jnp.maximum(elite.std(0), cfg.min_std * SEARCH_RANGE)
    a = cfg.smoothing
    return CEMState(a * state.mean + (1 - a) * mean, a * state.std + (1 - a) * std, costs[order[0]])


def cem_minimize(cost_fn: Callable[[jax.Array, jax.Array], jax.Array], state: CEMState, key,
                 cfg: CEMConfig, candidates: bool = False):
    """Run ``cfg.iterations`` CEM iterations. cost_fn(gains (N, 8), key) -> costs (N,).

    Returns the final state and the cost history (iterations, N) — with ``candidates`` also the
    candidates scored (iterations, N, 8). The gains of the distribution's mean are
    ``from_search(state.mean)``.
    """
    def body(st, k):
        k_c, k_e = jax.random.split(k)
        g = cem_candidates(st, k_c, cfg.candidates)
        c = cost_fn(g, k_e)
        return cem_refit(st, g, c, cfg), (c, g)

    state, (costs, gains) = jax.lax.scan(body, state, jax.random.split(key, cfg.iterations))
    return (state, costs, gains) if candidates else (state, costs)


def mean_gains(state: CEMState) -> jax.Array:
    """The gains of the distribution's mean (8,)."""
    return from_search(state.mean)
