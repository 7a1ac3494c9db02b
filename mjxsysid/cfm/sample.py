"""Sampling the decoder p(θ | ẑ) and the baselines (paper §III-B, §IV-A, DESIGN §6).

:func:`sample` integrates dθ/dτ = v(θ, τ, z) from τ = 0 (θ₀ ~ N(0, I), normalised space) to
τ = 1 with ``steps`` fixed steps of h = 1/steps, τ_k = k h::

    euler:    θ ← θ + h v(θ, τ_k)
    midpoint: θ ← θ + h v(θ + h/2 v(θ, τ_k), τ_k + h/2)
    heun:     k1 = v(θ, τ_k), k2 = v(θ + h k1, τ_k + h);  θ ← θ + h/2 (k1 + k2)

(v evaluations: steps, 2 steps, 2 steps.) Pure and jit-able; the same key gives the same
samples. θ₀ is drawn as one (m, n_samples, d) normal array from ``key``, so a latent's samples
depend on its row index and m as well as the key.

:class:`Decoder` wraps a trained decoder with its normaliser: physical units in and out.
:func:`random_baseline` is the paper's Random baseline.
"""
from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp

from mjxsysid.runtime import distributed
from mjxsysid.cfm.flow_coords import FlowNormalizer
from mjxsysid.cfm.train import CFMConfig, check_latents, load_decoder, make_network, save_decoder
from mjxsysid.theta import INERTIA, PAPER_HARDWARE

METHODS = ("euler", "midpoint", "heun")


def integrate(v, x0, steps: int, method: str):
    """Integrate dx/dτ = v(x, τ) from τ = 0 to 1 with ``steps`` fixed steps (see the module
    docstring). v: (x (..., d), τ scalar) -> (..., d); x0 (..., d) -> x(1) (..., d)."""
    h = 1.0 / steps

    def body(k, x):
        t = k * h
        if method == "euler":
            return x + h * v(x, t)
        if method == "midpoint":
            return x + h * v(x + 0.5 * h * v(x, t), t + 0.5 * h)
        k1 = v(x, t)
        k2 = v(x + h * k1, t + h)
        return x + 0.5 * h * (k1 + k2)

    return jax.lax.fori_loop(0, steps, body, x0)


@partial(jax.jit, static_argnames=("cfg", "n_samples", "steps", "method"))
def _sample(params, cfg: CFMConfig, theta0, z, n_samples: int, steps: int, method: str):
    """Integrate the flow from θ₀ (m, n_samples, d) for latents z (m, z_dim): the one vmap
    boundary of sampling (over cases)."""
    net = make_network(cfg, "cfm")

    def one(th, zi):
        zb = jnp.broadcast_to(zi, (n_samples, cfg.z_dim))
        return integrate(lambda x, t: net.apply({"params": params}, x, t, zb), th, steps, method)

    return jax.vmap(one)(theta0, z)


def sample(params, cfg: CFMConfig, z, key, n_samples: int, steps: int = 50,
           method: str = "euler") -> jax.Array:
    """Draw ``n_samples`` normalised θ per latent. z: (m, z_dim) -> (m, n_samples, theta_dim).

    Raises ValueError for z not (m, z_dim), an unknown ``method``, or steps / n_samples < 1.
    Jit-able (cfg, n_samples, steps, method static)."""
    if method not in METHODS:
        raise ValueError(f"unknown ODE method {method!r}; choose from {METHODS}")
    if int(steps) < 1 or int(n_samples) < 1:
        raise ValueError(f"steps and n_samples must be >= 1, got {steps}, {n_samples}")
    z = check_latents(z, cfg)
    m = z.shape[0]
    # Noise drawn for the m cases before the cases are sharded over the devices (and padded):
    # the samples do not depend on the device count.
    theta0 = jax.random.normal(key, (m, int(n_samples), cfg.theta_dim), jnp.float32)
    params, theta0, z = distributed.shard_batch((params, theta0, z), m, axes=(None, 0, 0))
    return distributed.unpad(_sample(params, cfg, theta0, z, int(n_samples), int(steps), method), m)


@partial(jax.jit, static_argnames=("cfg",))
def _point(params, cfg: CFMConfig, z):
    return make_network(cfg, "regression").apply({"params": params}, z)


def point(params, cfg: CFMConfig, z) -> jax.Array:
    """Regression point estimate, normalised. z: (m, z_dim) -> (m, theta_dim)."""
    return _point(params, cfg, check_latents(z, cfg))


@dataclasses.dataclass(frozen=True)
class Decoder:
    """A trained decoder with its normaliser. Physical θ at the interface.

    ``kind`` "cfm" (:meth:`sample_theta`) or "regression" (:meth:`point`). z may be one latent
    (z_dim,) or a batch (m, z_dim); outputs drop the batch axis for a single latent.
    """
    kind: str
    params: dict
    cfg: CFMConfig
    normalizer: object = None
    meta: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "normalizer", FlowNormalizer.of(self.normalizer))

    @classmethod
    def load(cls, path) -> "Decoder":
        return cls(*load_decoder(path))

    def save(self, path, meta: dict | None = None):
        return save_decoder(path, self.kind, self.params, self.cfg, self.normalizer,
                            self.meta if meta is None else meta)

    def _z(self, z):
        z = jnp.asarray(z, jnp.float32)
        if z.ndim == 1:
            return check_latents(z[None], self.cfg, "z (single latent)"), True
        return check_latents(z, self.cfg), False

    def _unflow(self, v):
        """The network's outputs (its flow coordinates) -> normalised θ."""
        return v if self.normalizer is None else self.normalizer.from_flow(v)

    def _denorm(self, y):
        if self.normalizer is None:
            raise ValueError("this decoder has no normaliser; use sample_norm / point_norm")
        return self.normalizer.denormalize(y)

    def sample_norm(self, z, key, n: int, steps: int = 50, method: str = "euler"):
        """Normalised samples: (n, d) for z (z_dim,), (m, n, d) for z (m, z_dim)."""
        if self.kind != "cfm":
            raise ValueError(f"sample_theta needs a 'cfm' decoder, this one is {self.kind!r} (use .point)")
        zz, single = self._z(z)
        out = self._unflow(sample(self.params, self.cfg, zz, key, n, steps, method))
        return out[0] if single else out

    def sample_theta(self, z, key, n: int, steps: int = 50, method: str = "euler"):
        """Physical θ samples: (n, 19) for z (8,), (m, n, 19) for z (m, 8)."""
        return self._denorm(self.sample_norm(z, key, n, steps, method))

    def point_norm(self, z):
        if self.kind != "regression":
            raise ValueError(f"point needs a 'regression' decoder, this one is {self.kind!r} "
                             "(use .sample_theta)")
        zz, single = self._z(z)
        out = self._unflow(point(self.params, self.cfg, zz))
        return out[0] if single else out

    def point(self, z):
        """Physical point estimate: (19,) for z (8,), (m, 19) for z (m, 8)."""
        return self._denorm(self.point_norm(z))


def random_baseline(key, n: int, nominal=None, *, spread: float = 0.5,
                    fix_inertia: bool = True) -> jax.Array:
    """The Random baseline: θ = θ_nom ⊙ (1 + U(−spread, +spread)), independently per entry.
    Returns (n, 19) physical θ (float32). Pure in ``key``: pass a fresh key per call for fresh
    draws.

    ``nominal`` defaults to :data:`mjxsysid.theta.PAPER_HARDWARE`. The perturbation is
    multiplicative, so entries that are 0 in the nominal (the external torque of the paper
    vehicle) stay 0. With ``fix_inertia`` (default) an inertia that violates the triangle
    inequality after perturbation (J_a > J_b + J_c; 47 % of draws for the paper vehicle,
    whose J_zz ≈ J_xx + J_yy) is clipped to J_b + J_c so the vehicle passes
    ``theta.validate_theta`` / MuJoCo; ``fix_inertia=False`` gives the literal paper baseline.
    """
    nom = jnp.asarray(PAPER_HARDWARE if nominal is None else nominal, jnp.float32)
    if nom.shape != (PAPER_HARDWARE.shape[0],):
        raise ValueError(f"nominal must have shape ({PAPER_HARDWARE.shape[0]},); got {nom.shape}")
    u = jax.random.uniform(key, (n, nom.shape[0]), jnp.float32, -spread, spread)
    theta = nom * (1.0 + u)
    if fix_inertia:
        j = theta[:, INERTIA]
        others = jnp.sum(j, -1, keepdims=True) - j
        theta = theta.at[:, INERTIA].set(jnp.minimum(j, others))
    return theta
