"""θ ↔ the standardised space everything learned works in: log of the positive scale
parameters ([LOG_MASK][mjxsysid.theta.layout.LOG_MASK]), then standardised. Public interfaces
keep physical units."""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.theta.layout import LOG_MASK, LOG_OFFSET
from mjxsysid.theta.priors import SizeFactorPrior, get_prior


@jax.tree_util.register_pytree_node_class
@dataclasses.dataclass(frozen=True)
class Normalizer:
    """θ ↔ learning space: y = (f(θ) − shift) / scale, f = log(θ + offset) on
    [LOG_MASK][mjxsysid.theta.layout.LOG_MASK] entries and identity elsewhere. shift, scale: (19,).
    The maps are jitted (one program each per shape, not a dozen eager operations compiled one
    by one)."""
    shift: jax.Array
    scale: jax.Array

    def tree_flatten(self):
        return (self.shift, self.scale), None

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(*children)

    @staticmethod
    def _f(theta):
        return jnp.where(LOG_MASK, jnp.log(jnp.where(LOG_MASK, theta + LOG_OFFSET, 1.0)), theta)

    @jax.jit
    def normalize(self, theta):
        """θ (..., 19) physical -> (..., 19) normalised."""
        return (self._f(jnp.asarray(theta)) - self.shift) / self.scale

    @jax.jit
    def denormalize(self, y):
        """(..., 19) normalised -> θ (..., 19) physical."""
        f = jnp.asarray(y) * self.scale + self.shift
        return jnp.where(LOG_MASK, jnp.exp(f) - LOG_OFFSET, f)

    @classmethod
    def fit(cls, theta) -> Normalizer:
        """Mean / std of f(θ) over samples θ (n, 19)."""
        f = np.asarray(cls._f(jnp.asarray(theta, jnp.float32)), np.float64)
        return cls(jnp.asarray(f.mean(0), jnp.float32),
                   jnp.asarray(np.maximum(f.std(0), 1e-6), jnp.float32))

    def to_dict(self) -> dict:
        return {"shift": np.asarray(self.shift).tolist(), "scale": np.asarray(self.scale).tolist()}

    @classmethod
    def from_dict(cls, d) -> Normalizer:
        return cls(jnp.asarray(d["shift"], jnp.float32), jnp.asarray(d["scale"], jnp.float32))


def prior_samples_for_normalizer(prior: str | SizeFactorPrior = "default", n: int = 100_000,
                                 seed: int = 0) -> jax.Array:
    """The ``n`` seeded draws of ``prior`` a normaliser is fitted to: θ (n, 19)."""
    return get_prior(prior).sample(jax.random.PRNGKey(seed), n)


def prior_normalizer(prior: str | SizeFactorPrior = "default", n: int = 100_000, seed: int = 0) -> Normalizer:
    """Normaliser fitted to ``n`` samples of a prior (seeded, deterministic)."""
    return Normalizer.fit(prior_samples_for_normalizer(prior, n, seed))
