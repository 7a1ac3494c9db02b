"""The probability path of the CFM decoder (paper §III-B, DESIGN §6), torchcfm style.

Gaussian-smoothed linear interpolation between a base sample x0 ~ N(0, I) and a data
sample x1 (normalised θ)::

    x_τ = (1 − τ) x0 + τ x1 + σ ε,     ε ~ N(0, I),  τ ~ U[0, τ_max]
    u   = x1 − x0                                      (target velocity, independent of ε)

The smoothing σ keeps the path non-degenerate; truncating τ at τ_max < 1 avoids the
ill-conditioned end where σε is as large as the remaining (1 − τ)(x1 − x0).
Stateless and pure: every method is jit-able.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp


@dataclasses.dataclass(frozen=True)
class GaussianSmoothedLinearPath:
    sigma: float = 0.05
    tau_max: float = 0.95

    def __post_init__(self):
        if not self.sigma >= 0:
            raise ValueError(f"sigma must be >= 0, got {self.sigma}")
        if not 0 < self.tau_max <= 1:
            raise ValueError(f"tau_max must be in (0, 1], got {self.tau_max}")

    def sample_tau(self, key: jax.Array, n: int) -> jax.Array:
        """τ ~ U[0, τ_max], shape (n,) float32."""
        return jax.random.uniform(key, (n,), jnp.float32, 0.0, self.tau_max)

    def sample_location_and_flow(self, x0, x1, tau, eps):
        """x0, x1, eps: (..., d); tau: (...) or scalar -> (x_τ (..., d), u (..., d))."""
        x0, x1, eps = jnp.asarray(x0), jnp.asarray(x1), jnp.asarray(eps)
        t = jnp.asarray(tau, x1.dtype)[..., None]
        x_tau = (1.0 - t) * x0 + t * x1 + self.sigma * eps
        return x_tau, x1 - x0

    def sample(self, key: jax.Array, x1):
        """Draw x0, τ, ε for a batch x1 (n, d) -> (x_τ, τ, u). Convenience for training."""
        k0, kt, ke = jax.random.split(key, 3)
        x1 = jnp.asarray(x1)
        x0 = jax.random.normal(k0, x1.shape, x1.dtype)
        eps = jax.random.normal(ke, x1.shape, x1.dtype)
        tau = self.sample_tau(kt, x1.shape[0])
        x_tau, u = self.sample_location_and_flow(x0, x1, tau, eps)
        return x_tau, tau, u
