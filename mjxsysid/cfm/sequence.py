"""Flight-level decoding: p(θ | ẑ_1..ẑ_W), one model for one latent up to a whole flight.

The vehicle is constant over a flight, but one latent is a noisy, manoeuvre-dependent view of
it. The sequence decoder learns the conditional given a *set* of latents of one flight (those
recorded at 10 Hz in a window), instead of multiplying per-latent posteriors (the latents of one
flight are not independent). Architecture::

    ẑ_i (standardised with the training latents' mean / std)       i = 1..L, mask m_i
    h_i = MLP(ẑ_i)                                   3 layers, width E (set_width), SiLU
    mean = Σ m_i h_i / W                             DeepSets mean pooling, W = Σ m_i
    att  = Σ_i softmax_i(score_k(h_i)) h_i^(k)       attention pooling, ``heads`` heads of E/heads
    n    = [log W / log L_max, 1 / √W]               count feature (W clipped to [1, L_max])
    c    = MLP([mean, att, n]) ∈ R^cond_dim          the conditioning vector
    v(θ_τ, τ, c)                                     the *same* FiLM velocity field as the
                                                     single-latent decoder (networks.VelocityNet,
                                                     with c in place of ẑ)

Permutation invariant in the latents of the window (no time stamps enter). Training: the CFM
loss of :mod:`mjxsysid.cfm.train` with, per example and per step, a random window of one
training flight: length W log-uniform on {1..L} (P(W = 1) = log 2 / log(L + 1)) and a uniform
start, so one model serves single-latent (W = 1) and flight-level decoding. Sampling: the
encoder runs once per window, then the ODE of :func:`mjxsysid.cfm.sample.integrate`.

Saved like the other decoders (npz + JSON meta, format ``mjxsysid.cfm.decoder/1``) with kind
``"cfm_seq"``; :class:`SequenceDecoder` loads it (physical θ at the interface).
"""
from __future__ import annotations

import dataclasses
import math
from functools import lru_cache, partial
from typing import Callable, Mapping

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.cfm.networks import VelocityNet
from mjxsysid.cfm.sample import METHODS, integrate
from mjxsysid.cfm.train import FORMAT, CFMConfig, _normalizer_dict, _optimizer, fit_epochs, make_epoch
from mjxsysid.runtime.checkpoint import load_meta, load_tree, save_tree
from mjxsysid.cfm.flow_coords import FlowNormalizer

KIND = "cfm_seq"


@dataclasses.dataclass(frozen=True)
class SeqCFMConfig(CFMConfig):
    """CFMConfig (the velocity field and optimiser) plus the latent-set encoder.

    set_width: per-latent embedding width E; heads: attention-pooling heads (E % heads == 0);
    cond_dim: size of the pooled conditioning c; max_len: latents per training flight L (the
    count feature saturates there); z_shift / z_scale: latent standardisation (z_dim each, from
    the training latents; empty = none)."""
    set_width: int = 128
    heads: int = 4
    cond_dim: int = 64
    max_len: int = 99
    z_shift: tuple = ()
    z_scale: tuple = ()

    def __post_init__(self):
        super().__post_init__()
        for k in ("set_width", "heads", "cond_dim", "max_len"):
            if int(getattr(self, k)) < 1:
                raise ValueError(f"SeqCFMConfig.{k} must be >= 1, got {getattr(self, k)}")
        if self.set_width % self.heads:
            raise ValueError(f"SeqCFMConfig.set_width ({self.set_width}) must be a multiple of heads ({self.heads})")
        for k in ("z_shift", "z_scale"):
            v = getattr(self, k)
            if len(v) not in (0, self.z_dim):
                raise ValueError(f"SeqCFMConfig.{k} must have 0 or z_dim = {self.z_dim} entries, got {len(v)}")
        if self.z_scale and not all(s > 0 for s in self.z_scale):
            raise ValueError(f"SeqCFMConfig.z_scale must be > 0, got {self.z_scale}")

    @classmethod
    def from_dict(cls, d: Mapping) -> "SeqCFMConfig":
        d = dict(d)
        for k in ("z_shift", "z_scale"):
            if k in d:
                d[k] = tuple(float(x) for x in d[k])
        return super().from_dict(d)

    @classmethod
    def from_single(cls, cfg: CFMConfig, **kw) -> "SeqCFMConfig":
        """The sequence config that shares ``cfg``'s velocity field and optimiser."""
        base = {f.name: getattr(cfg, f.name) for f in dataclasses.fields(CFMConfig)}
        return cls(**{**base, **kw})


class LatentSetEncoder(nn.Module):
    """A masked set of latents zs (..., L, z_dim), mask (..., L) -> conditioning (..., out_dim).

    Three stages, each usable alone (streaming decoding of long flights,
    :meth:`SequenceDecoder.encode_flight`): :meth:`embed` per latent, :func:`masked_pool` over a
    window, :meth:`head` on the pooled features."""
    width: int
    out_dim: int
    heads: int
    max_len: int

    def setup(self):
        self.embed_0 = nn.Dense(self.width)
        self.embed_1 = nn.Dense(self.width)
        self.embed_2 = nn.Dense(self.width)
        self.attn_score = nn.Dense(self.heads)
        self.pool_0 = nn.Dense(self.width)
        self.pool_1 = nn.Dense(self.out_dim)

    def embed(self, zs):
        """zs (..., L, z_dim) -> h (..., L, E), attention scores (..., L, heads)."""
        h = self.embed_2(nn.silu(self.embed_1(nn.silu(self.embed_0(zs)))))
        return h, self.attn_score(nn.silu(h))

    def head(self, mean, att, n):
        """Pooled mean (..., E), attention (..., E) and window size n (..., 1) -> c (..., out_dim)."""
        nc = jnp.clip(n, 1.0, float(self.max_len))
        count = jnp.concatenate([jnp.log(nc) / math.log(max(self.max_len, 2)), 1.0 / jnp.sqrt(nc)], -1)
        return self.pool_1(nn.silu(self.pool_0(jnp.concatenate([mean, att, count], -1))))

    def __call__(self, zs, mask):
        h, score = self.embed(zs)
        return self.head(*masked_pool(h, score, mask, self.heads))


def masked_pool(h, score, mask, heads: int):
    """DeepSets mean and attention pooling of h (..., L, E) with scores (..., L, H) over the
    latents where mask (..., L) -> mean (..., E), att (..., E), n (..., 1)."""
    m = jnp.asarray(mask, jnp.float32)[..., None]                          # (..., L, 1)
    n = jnp.sum(m, -2)                                                     # (..., 1)
    mean = jnp.sum(h * m, -2) / jnp.maximum(n, 1.0)
    a = jax.nn.softmax(jnp.where(m > 0, score, -1e9), axis=-2)
    hv = h.reshape(h.shape[:-1] + (heads, h.shape[-1] // heads))
    att = jnp.einsum("...lh,...lhc->...hc", a, hv).reshape(h.shape[:-2] + (h.shape[-1],))
    return mean, att, n


def prefix_pool(h, score, heads: int):
    """:func:`masked_pool` of every prefix 1..l of one flight at once, in O(L): running sums for
    the mean and an online softmax (running max, rescaled sums) for the attention.
    h (L, E), score (L, H) -> mean (L, E), att (L, E), n (L, 1) (row l: the first l + 1 latents)."""
    L, E = h.shape
    hv = h.reshape(L, heads, E // heads)

    def step(c, x):
        mx, sm, acc = c
        sc, v = x
        new = jnp.maximum(mx, sc)
        old_w, w = jnp.exp(mx - new), jnp.exp(sc - new)
        sm, acc = sm * old_w + w, acc * old_w[:, None] + w[:, None] * v
        return (new, sm, acc), acc / sm[:, None]

    init = (jnp.full((heads,), -jnp.inf, h.dtype), jnp.zeros((heads,), h.dtype), jnp.zeros((heads, E // heads), h.dtype))
    _, att = jax.lax.scan(step, init, (score, hv))
    n = jnp.arange(1, L + 1, dtype=h.dtype)[:, None]
    return jnp.cumsum(h, 0) / n, att.reshape(L, E), n


class SeqVelocityNet(nn.Module):
    """v(θ_τ (..., d), τ, zs (..., L, z_dim), mask (..., L)) = VelocityNet(θ_τ, τ, encode(zs, mask))."""
    cfg: SeqCFMConfig

    def setup(self):
        c = self.cfg
        self.encoder = LatentSetEncoder(c.set_width, c.cond_dim, c.heads, c.max_len)
        self.field = VelocityNet(c.theta_dim, c.width, c.blocks, c.embed_width, c.time_dim)

    def encode(self, zs, mask):
        return self.encoder(zs, mask)

    def velocity(self, theta, tau, c):
        return self.field(theta, tau, c)

    def __call__(self, theta, tau, zs, mask):
        return self.field(theta, tau, self.encoder(zs, mask))


def init_params(cfg: SeqCFMConfig, key: jax.Array | None = None):
    key = jax.random.PRNGKey(cfg.seed) if key is None else key
    # The standardisation is applied outside the network: one compiled init per architecture.
    return _init_params(SeqVelocityNet(dataclasses.replace(cfg, z_shift=(), z_scale=())), key)


@partial(jax.jit, static_argnums=0)
def _init_params(net: "SeqVelocityNet", key):
    c = net.cfg
    return net.init(key, jnp.zeros((1, c.theta_dim)), jnp.zeros((1,)), jnp.zeros((1, 2, c.z_dim)),
                    jnp.ones((1, 2), bool))["params"]


def standardize(cfg: SeqCFMConfig, zs):
    """Latents (..., z_dim) -> standardised with cfg.z_shift / z_scale (identity if empty)."""
    zs = jnp.asarray(zs, jnp.float32)
    if not cfg.z_shift:
        return zs
    return (zs - jnp.asarray(cfg.z_shift, jnp.float32)) / jnp.asarray(cfg.z_scale, jnp.float32)


def random_windows(key, n: int, length: int):
    """n random windows of a length-L sequence: (start (n,), W (n,)) int32, W log-uniform on
    {1..L}, start uniform on {0..L−W}."""
    k1, k2 = jax.random.split(key)
    w = jnp.floor(jnp.exp(jax.random.uniform(k1, (n,)) * math.log(length + 1.0))).astype(jnp.int32)
    w = jnp.clip(w, 1, length)
    start = jnp.floor(jax.random.uniform(k2, (n,)) * (length - w + 1).astype(jnp.float32)).astype(jnp.int32)
    return jnp.minimum(start, length - w), w


def window_mask(start, w, length: int):
    """(start (n,), W (n,)) -> mask (n, L) bool of the latents start..start+W−1."""
    i = jnp.arange(length)
    return (i >= start[:, None]) & (i < (start + w)[:, None])


def _check_data(theta_norm, zs, cfg: SeqCFMConfig, what: str):
    th = np.asarray(theta_norm, np.float32)
    zz = np.asarray(zs, np.float32)
    if th.ndim != 2 or th.shape[1] != cfg.theta_dim:
        raise ValueError(f"{what}: theta_norm must have shape (n, {cfg.theta_dim}); got {th.shape}")
    if zz.ndim != 3 or zz.shape[2] != cfg.z_dim or zz.shape[0] != th.shape[0]:
        raise ValueError(f"{what}: latent trajectories must have shape ({th.shape[0]}, L, {cfg.z_dim}); got {zz.shape}")
    if th.shape[0] == 0 or zz.shape[1] == 0:
        raise ValueError(f"{what}: empty data set")
    if not (np.isfinite(th).all() and np.isfinite(zz).all()):
        raise ValueError(f"{what}: theta_norm / latent trajectories contain non-finite values")
    return th, zz


def _per_sample_loss(cfg, net, params, theta, zs, mask, key):
    """(B,) CFM losses of θ (B, d) given the masked latent sets zs (B, L, z), mask (B, L)."""
    x_tau, tau, u = cfg.path.sample(key, theta)
    pred = net.apply({"params": params}, x_tau, tau, standardize(cfg, zs), mask)
    return jnp.mean((pred - u) ** 2, -1)


@lru_cache(maxsize=8)
def _epoch_for(cfg: SeqCFMConfig, n: int, L: int):
    """(jitted epoch, optimizer) for ``cfg``, ``n`` flights of ``L`` latents, built once per
    process (a resumed or repeated training re-uses the compiled epoch)."""
    bs = min(cfg.batch, n)
    spe = n // bs
    net = SeqVelocityNet(cfg)
    tx = _optimizer(cfg, cfg.epochs * spe)

    def batch_loss(p, th, zb, k):
        kw, kl = jax.random.split(k)
        start, w = random_windows(kw, th.shape[0], L)
        return jnp.mean(_per_sample_loss(cfg, net, p, th, zb, window_mask(start, w, L), kl))

    return make_epoch(batch_loss, tx, n, spe, bs), tx


def train_seq_cfm(theta_norm, zs, cfg: SeqCFMConfig, log: Callable | None = print, val: tuple | None = None,
                  checkpoint=None, checkpoint_every: int = 10):
    """Train the sequence CFM. theta_norm (n, d) normalised θ; zs (n, L, z_dim) the latent
    trajectory of each flight; val: optional (theta_norm, zs) held out (fixed windows, fixed
    key). Returns (params, history) like :func:`mjxsysid.cfm.train.train_cfm`.

    ``checkpoint``: a file for the training state every ``checkpoint_every`` epochs; when it
    exists (same config and data), training resumes from it and ends with the same weights as
    an uninterrupted run (epoch keys are ``fold_in(key, epoch)``), as for ``train_cfm``."""

    theta, zz = _check_data(theta_norm, zs, cfg, "train")
    n, L = zz.shape[:2]
    bs = min(cfg.batch, n)
    spe = n // bs
    net = SeqVelocityNet(cfg)
    k_init, k_train = jax.random.split(jax.random.PRNGKey(cfg.seed))
    params = init_params(cfg, k_init)
    epoch, tx = _epoch_for(cfg, n, L)
    opt_state = tx.init(params)

    val_fn = None
    if val is not None:
        vth, vz = _check_data(val[0], val[1], cfg, "val")
        val_fn = _make_eval(cfg, net, vth, vz)
    return fit_epochs(epoch, params, opt_state, k_train, theta, zz, cfg=cfg, kind=KIND, tag=f"[{KIND}]",
                      spe=spe, bs=bs, val_fn=val_fn, log=log, checkpoint=checkpoint,
                      checkpoint_every=checkpoint_every)


def _make_eval(cfg, net, theta, zs, chunk: int = 512):
    """Jitted mean validation loss over fixed random windows and a fixed key."""
    n, L = zs.shape[:2]
    c = min(chunk, n)
    nc = -(-n // c)
    pad = nc * c - n
    th = jnp.asarray(np.concatenate([theta, np.zeros((pad, theta.shape[1]), np.float32)]))
    zz = jnp.asarray(np.concatenate([zs, np.zeros((pad,) + zs.shape[1:], np.float32)]))
    start, w = random_windows(jax.random.PRNGKey(cfg.seed + 2), nc * c, L)
    mask = window_mask(start, w, L)
    valid = jnp.asarray(np.arange(nc * c) < n, jnp.float32)
    keys = jax.random.split(jax.random.PRNGKey(cfg.seed + 1), nc)

    @jax.jit
    def ev(params):
        def one(x):
            t, zb, mb, k = x
            return _per_sample_loss(cfg, net, params, t, zb, mb, k)
        per = jax.lax.map(one, (th.reshape(nc, c, -1), zz.reshape((nc, c) + zz.shape[1:]),
                                mask.reshape(nc, c, L), keys)).reshape(-1)
        return jnp.sum(per * valid) / n

    return ev


# ----------------------------------------------------------------------------------------
# Sampling
# ----------------------------------------------------------------------------------------

@partial(jax.jit, static_argnames=("cfg", "n_samples", "steps", "method"))
def _sample_cond(params, cfg: SeqCFMConfig, c, key, n_samples: int, steps: int, method: str):
    """Normalised (flow-coordinate) samples (m, n_samples, d) given conditioning vectors c (m, C)."""
    net = SeqVelocityNet(cfg)
    theta0 = jax.random.normal(key, (c.shape[0], n_samples, cfg.theta_dim), jnp.float32)

    def one(th, ci):
        cb = jnp.broadcast_to(ci, (n_samples, ci.shape[-1]))
        return integrate(lambda x, t: net.apply({"params": params}, x, t, cb, method="velocity"),
                         th, steps, method)

    return jax.vmap(one)(theta0, c)


@partial(jax.jit, static_argnames=("cfg", "n_samples", "steps", "method"))
def _sample(params, cfg: SeqCFMConfig, zs, mask, key, n_samples: int, steps: int, method: str):
    c = SeqVelocityNet(cfg).apply({"params": params}, standardize(cfg, zs), mask, method="encode")     # (m, C)
    return _sample_cond(params, cfg, c, key, n_samples, steps, method)


def _encoder(cfg: SeqCFMConfig) -> LatentSetEncoder:
    return LatentSetEncoder(cfg.set_width, cfg.cond_dim, cfg.heads, cfg.max_len)


@partial(jax.jit, static_argnames=("cfg",))
def _encode_prefixes(params, cfg: SeqCFMConfig, zs):
    """c (L, C) of every prefix of one flight's latents zs (L, z_dim): O(L)."""
    h, score = _embed(params, cfg, zs)
    return _encoder(cfg).apply({"params": params["encoder"]}, *prefix_pool(h, score, cfg.heads), method="head")


@partial(jax.jit, static_argnames=("cfg",))
def _embed(params, cfg: SeqCFMConfig, zs):
    """Per-latent embedding h (L, E) and attention scores (L, H) of one flight's latents (L, z_dim)."""
    return _encoder(cfg).apply({"params": params["encoder"]}, standardize(cfg, zs), method="embed")


@partial(jax.jit, static_argnames=("cfg",))
def _encode_windows(params, cfg: SeqCFMConfig, h, score, idx, mask):
    """c (K, C) of K windows of one flight, from its embedding (:func:`_embed`): latent indices
    idx (K, w) where mask (K, w)."""
    return _encoder(cfg).apply({"params": params["encoder"]}, *masked_pool(h[idx], score[idx], mask, cfg.heads),
                               method="head")


def check_windows(zs, mask, cfg: SeqCFMConfig):
    """zs (m, L, z_dim), mask (m, L) (None: all) -> float32 zs, bool mask. Every window needs at
    least one latent; latents must be finite where masked in."""
    zs = np.asarray(zs, np.float32)
    if zs.ndim != 3 or zs.shape[2] != cfg.z_dim or zs.shape[1] < 1:
        raise ValueError(f"latent windows must have shape (m, L, {cfg.z_dim}); got {zs.shape}")
    mask = np.ones(zs.shape[:2], bool) if mask is None else np.asarray(mask, bool)
    if mask.shape != zs.shape[:2]:
        raise ValueError(f"mask must have shape {zs.shape[:2]} (m, L); got {mask.shape}")
    if not mask.any(1).all():
        raise ValueError(f"every window needs at least one latent; windows {np.flatnonzero(~mask.any(1))[:5].tolist()} are empty")
    if not np.isfinite(np.where(mask[..., None], zs, 0.0)).all():
        raise ValueError("latent windows contain non-finite values")
    return np.where(mask[..., None], zs, 0.0).astype(np.float32), mask


def sample(params, cfg: SeqCFMConfig, zs, key, n_samples: int, steps: int = 50, method: str = "euler",
           mask=None) -> jax.Array:
    """Normalised θ samples given latent windows. zs (m, L, z_dim), mask (m, L) bool (None: all
    latents) -> (m, n_samples, theta_dim)."""
    if method not in METHODS:
        raise ValueError(f"unknown ODE method {method!r}; choose from {METHODS}")
    if int(steps) < 1 or int(n_samples) < 1:
        raise ValueError(f"steps and n_samples must be >= 1, got {steps}, {n_samples}")
    zs, mask = check_windows(zs, mask, cfg)
    return _sample(params, cfg, jnp.asarray(zs), jnp.asarray(mask), key, int(n_samples), int(steps), method)


# ----------------------------------------------------------------------------------------
# Save / load and the physical interface
# ----------------------------------------------------------------------------------------

def save_seq_decoder(path, params, cfg: SeqCFMConfig, normalizer=None, meta: dict | None = None):
    nd = _normalizer_dict(normalizer)
    full = {"format": FORMAT, "kind": KIND, "config": cfg.to_dict(), "normalizer": nd, "meta": dict(meta or {})}
    return save_tree(path, params, full)


@dataclasses.dataclass(frozen=True)
class SequenceDecoder:
    """A trained sequence decoder p(θ | ẑ_1..ẑ_W) with its normaliser; physical θ outside.

    Windows: one window (W, z_dim) -> samples (n, 19); a batch (m, L, z_dim) with mask (m, L)
    -> (m, n, 19). ``max_len`` is the longest window seen in training (L of the training
    flights); longer windows work (the count feature saturates) but are extrapolation.
    """
    params: dict
    cfg: SeqCFMConfig
    normalizer: object = None
    meta: dict = dataclasses.field(default_factory=dict)
    kind: str = KIND

    def __post_init__(self):
        object.__setattr__(self, "normalizer", FlowNormalizer.of(self.normalizer))

    @classmethod
    def load(cls, path) -> "SequenceDecoder":
        full = load_meta(path)
        if full.get("format") != FORMAT or full.get("kind") != KIND:
            raise ValueError(f"{path}: not a sequence decoder (format {full.get('format')!r}, "
                             f"kind {full.get('kind')!r}; expected {FORMAT!r}, {KIND!r})")
        try:
            cfg = SeqCFMConfig.from_dict(full["config"])
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{path}: bad sequence decoder config ({type(e).__name__}: {e})") from None
        params = load_tree(path, jax.eval_shape(lambda: init_params(cfg)), finite=True)
        norm = None
        if full.get("normalizer") is not None:
            try:
                norm = FlowNormalizer.from_dict(full["normalizer"])
                ok = all(np.shape(getattr(norm, k)) == (cfg.theta_dim,) and np.all(np.isfinite(getattr(norm, k)))
                         for k in ("shift", "scale")) and np.all(np.asarray(norm.scale) > 0)
            except (KeyError, TypeError, ValueError) as e:
                raise ValueError(f"{path}: bad normalizer ({type(e).__name__}: {e})") from None
            if not ok:
                raise ValueError(f"{path}: bad normalizer: shift and scale must be {cfg.theta_dim} finite values, "
                                 f"scale > 0")
        return cls(jax.tree_util.tree_map(jnp.asarray, params), cfg, norm, full.get("meta", {}))

    def save(self, path, meta: dict | None = None):
        return save_seq_decoder(path, self.params, self.cfg, self.normalizer, self.meta if meta is None else meta)

    @property
    def max_len(self) -> int:
        return int(self.cfg.max_len)

    def sample_norm(self, zs, key, n: int, steps: int = 50, method: str = "euler", mask=None):
        zs = np.asarray(zs, np.float32)
        single = zs.ndim == 2
        if single:
            if mask is not None:
                raise ValueError("mask applies to a batch of windows (m, L, z_dim) only")
            zs = zs[None]
        out = sample(self.params, self.cfg, zs, key, n, steps, method, mask)
        if self.normalizer is not None:
            out = self.normalizer.from_flow(out)     # the flow's coordinates -> normalised θ
        return out[0] if single else out

    def encode_flight(self, zs, ends, starts=None, chunk: int = 4096):
        """Conditioning vectors c (K, cond_dim) of one flight's latents zs (L, z_dim) for the
        windows [starts_k, ends_k] of latent indices (inclusive; ``starts`` None: every latent up
        to the end, all prefixes at once in O(L)); otherwise O(K w) for windows of at most w
        latents, in chunks of ``chunk`` windows. The same vectors as encoding each window by
        itself, in time linear in the flight and memory bounded by the chunk: what decoding long
        logs uses."""
        zs = jnp.asarray(zs, jnp.float32)
        ends = np.asarray(ends, np.int64)
        if zs.ndim != 2 or zs.shape[1] != self.cfg.z_dim or zs.shape[0] < 1:
            raise ValueError(f"latents must have shape (L, {self.cfg.z_dim}); got {tuple(zs.shape)}")
        if ends.ndim != 1 or ends.size == 0 or ends.min() < 0 or ends.max() >= zs.shape[0]:
            raise ValueError(f"ends must be latent indices in [0, {zs.shape[0]}); got {ends[:5].tolist()}…")
        if starts is None:
            return _encode_prefixes(self.params, self.cfg, zs)[jnp.asarray(ends)]
        starts = np.asarray(starts, np.int64)
        if starts.shape != ends.shape or (starts < 0).any() or (starts > ends).any():
            raise ValueError("starts must be latent indices (K,) with 0 <= starts <= ends")
        offs = np.arange(-int((ends - starts).max()), 1)
        h, score = _embed(self.params, self.cfg, zs)                     # once per latent, not per chunk
        out = []
        for i in range(0, len(ends), chunk):
            idx = ends[i:i + chunk, None] + offs[None, :]
            mask = idx >= starts[i:i + chunk, None]
            out.append(_encode_windows(self.params, self.cfg, h, score, jnp.asarray(np.maximum(idx, 0)),
                                       jnp.asarray(mask)))
        return jnp.concatenate(out, 0)

    def sample_cond_theta(self, c, key, n: int, steps: int = 50, method: str = "euler"):
        """Physical θ samples (K, n, 19) given conditioning vectors c (K, cond_dim) from
        :meth:`encode_flight`."""
        if self.normalizer is None:
            raise ValueError("this decoder has no normaliser")
        if method not in METHODS:
            raise ValueError(f"unknown ODE method {method!r}; choose from {METHODS}")
        out = _sample_cond(self.params, self.cfg, jnp.asarray(c, jnp.float32), key, int(n), int(steps), method)
        return self.normalizer.denormalize(self.normalizer.from_flow(out))

    def sample_theta(self, zs, key, n: int, steps: int = 50, method: str = "euler", mask=None):
        """Physical θ samples: (n, 19) for one window (W, z_dim), (m, n, 19) for (m, L, z_dim)."""
        if self.normalizer is None:
            raise ValueError("this decoder has no normaliser; use sample_norm")
        return self.normalizer.denormalize(self.sample_norm(zs, key, n, steps, method, mask))
