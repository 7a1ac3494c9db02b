"""Networks of the decoder p(θ | ẑ) (paper §IV-A, DESIGN §6), flax.linen.

Both networks work in the normalised θ space (``theta_dim`` = 19) and condition on a latent
z (``z_dim`` = 8) the same way::

    c = MLP_z(z)                          3 layers, width W, SiLU between (no final act.)
    block_k(h, c):                         pre-norm residual block, k = 1..B
        x = Dense_W(LayerNorm(h))
        γ, β = Dense_2W(SiLU(c))           FiLM, zero-initialised (block starts unmodulated)
        x = SiLU(x · (1 + γ) + β)
        h = h + Dense_W(x)
    out = Dense_d(SiLU(LayerNorm(h)))

:class:`VelocityNet` v(θ_τ, τ, z): h₀ = Dense_W([MLP_θ(θ_τ), MLP_τ(sin-emb(τ))]), where the
θ and τ embeddings are 2-layer MLPs of width E (default W/2) and sin-emb is the transformer
sinusoidal embedding of 1000 τ (``time_dim`` features). LayerNorm: yes (pre-norm blocks and
before the output layer).

:class:`RegressionNet` r(z): h₀ = a learned token (W,), the same z-MLP and FiLM blocks,
one point estimate (d).

At paper size (W = 512, B = 4, E = 256, time_dim = 128, d = 19, z_dim = 8) VelocityNet has
5,179,667 parameters and RegressionNet 4,747,795.
"""
from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp


def sinusoidal_embedding(tau, dim: int, scale: float = 1000.0, max_period: float = 10_000.0):
    """τ (...) -> (..., dim): [cos(s τ f_k), sin(s τ f_k)], f_k = max_period^(−k/(dim/2))."""
    half = dim // 2
    freqs = jnp.exp(-math.log(max_period) * jnp.arange(half, dtype=jnp.float32) / half)
    args = scale * jnp.asarray(tau, jnp.float32)[..., None] * freqs
    emb = jnp.concatenate([jnp.cos(args), jnp.sin(args)], -1)
    if dim % 2:
        emb = jnp.concatenate([emb, jnp.zeros(emb.shape[:-1] + (1,), emb.dtype)], -1)
    return emb


class ZEmbedding(nn.Module):
    """z (..., z_dim) -> conditioning c (..., width): 3-layer MLP."""
    width: int

    @nn.compact
    def __call__(self, z):
        h = nn.silu(nn.Dense(self.width, name="dense_0")(z))
        h = nn.silu(nn.Dense(self.width, name="dense_1")(h))
        return nn.Dense(self.width, name="dense_2")(h)


class FiLMBlock(nn.Module):
    """Pre-norm residual block with FiLM (scale-and-shift) from the conditioning c."""
    width: int

    @nn.compact
    def __call__(self, h, c):
        x = nn.Dense(self.width, name="dense_in")(nn.LayerNorm(name="norm")(h))
        gb = nn.Dense(2 * self.width, kernel_init=nn.initializers.zeros, name="film")(nn.silu(c))
        gamma, beta = jnp.split(gb, 2, axis=-1)
        x = nn.silu(x * (1.0 + gamma) + beta)
        return h + nn.Dense(self.width, name="dense_out")(x)


class _Trunk(nn.Module):
    """z embedding + FiLM residual blocks + output head, shared by both networks."""
    out_dim: int
    width: int
    blocks: int

    @nn.compact
    def __call__(self, h, z):
        c = ZEmbedding(self.width, name="z_embed")(z)
        c = jnp.broadcast_to(c, h.shape[:-1] + c.shape[-1:])
        for k in range(self.blocks):
            h = FiLMBlock(self.width, name=f"block_{k}")(h, c)
        h = nn.silu(nn.LayerNorm(name="out_norm")(h))
        return nn.Dense(self.out_dim, name="out")(h)


class VelocityNet(nn.Module):
    """v(θ_τ (..., d), τ (...) or scalar, z (..., z_dim)) -> (..., d)."""
    theta_dim: int = 19
    width: int = 512
    blocks: int = 4
    embed_width: int = 0       # 0 -> width // 2
    time_dim: int = 128

    @nn.compact
    def __call__(self, theta, tau, z):
        e = self.embed_width or self.width // 2
        tau = jnp.broadcast_to(jnp.asarray(tau, jnp.float32), theta.shape[:-1])
        ht = nn.Dense(e, name="theta_embed_1")(nn.silu(nn.Dense(e, name="theta_embed_0")(theta)))
        hs = sinusoidal_embedding(tau, self.time_dim)
        hs = nn.Dense(e, name="tau_embed_1")(nn.silu(nn.Dense(e, name="tau_embed_0")(hs)))
        h = nn.Dense(self.width, name="proj")(jnp.concatenate([ht, hs], -1))
        return _Trunk(self.theta_dim, self.width, self.blocks, name="trunk")(h, z)


class RegressionNet(nn.Module):
    """r(z (..., z_dim)) -> point estimate (..., d) (normalised θ)."""
    theta_dim: int = 19
    width: int = 512
    blocks: int = 4

    @nn.compact
    def __call__(self, z):
        token = self.param("token", nn.initializers.normal(1.0), (self.width,))
        h = jnp.broadcast_to(token, z.shape[:-1] + (self.width,))
        return _Trunk(self.theta_dim, self.width, self.blocks, name="trunk")(h, z)


def count_params(tree) -> int:
    return int(sum(x.size for x in jax.tree_util.tree_leaves(tree)))
