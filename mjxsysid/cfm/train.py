"""Training of the decoder p(θ | ẑ) (paper §IV-A, DESIGN §6): CFM and the Regression baseline.

Both work on normalised θ (``theta_norm`` (n, 19), e.g. ``Normalizer.normalize(θ)``) and
latents z (n, 8). Losses (mean over the batch *and* the dimensions, torchcfm convention)::

    CFM:        x0 ~ N(0, I), τ ~ U[0, τ_max], ε ~ N(0, I)
                L = mean ‖v(x_τ, τ, z) − (x1 − x0)‖² / d,  x_τ = (1 − τ) x0 + τ x1 + σ ε
    Regression: L = mean ‖r(z) − x1‖² / d

Optimiser: gradient clipping (global norm) then AdamW with a cosine decay of the learning
rate to 0 over ``epochs`` × (n // batch) steps. One epoch (shuffle + scan over minibatches,
the last incomplete minibatch dropped) is a single jitted function; the host prints
progress between epochs. Validation loss (if ``val`` is given) uses a fixed key, so its
values are comparable across epochs.

Weights are stored with :mod:`mjxsysid.runtime.checkpoint` (npz + JSON meta, no pickle); the
meta holds the kind, the config and the normaliser, so a saved decoder is self-contained.
"""
from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path
from typing import Callable, Mapping, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from mjxsysid.cfm.flow_coords import DECODER_COORDS, FlowNormalizer
from mjxsysid.cfm.networks import RegressionNet, VelocityNet
from mjxsysid.cfm.path import GaussianSmoothedLinearPath
from mjxsysid.runtime.checkpoint import load_meta, load_tree, save_tree
from mjxsysid.runtime.progress import progress

KINDS = ("cfm", "regression")
FORMAT = "mjxsysid.cfm.decoder/1"


@dataclasses.dataclass(frozen=True)
class CFMConfig:
    """Hyper-parameters of the decoder (defaults: the paper's, DESIGN §6)."""
    lr: float = 5e-4
    weight_decay: float = 1e-5
    grad_clip: float = 1.0
    epochs: int = 100
    batch: int = 256
    sigma: float = 0.05
    tau_max: float = 0.95
    width: int = 512
    blocks: int = 4
    embed_width: int = 0      # θ / τ embedding width; 0 -> width // 2
    time_dim: int = 128       # sinusoidal τ features
    theta_dim: int = 19
    z_dim: int = 8
    seed: int = 0
    # The flow's coordinates (cfm.flow_coords.DECODER_COORDS): "identifiable" puts log thrust-to-weight and the
    # log angular authorities on axes of the flow (calibrated T/W bands half as wide as in "theta",
    # normalised θ, on a latent that carries T/W: docs/runs/archive/latent_trials/latent_trials.md). Samples are θ either way.
    coords: str = "identifiable"

    def __post_init__(self):
        for k in ("epochs", "batch", "width", "blocks", "time_dim", "theta_dim", "z_dim"):
            if int(getattr(self, k)) < 1:
                raise ValueError(f"CFMConfig.{k} must be >= 1, got {getattr(self, k)}")
        if self.embed_width < 0:
            raise ValueError(f"CFMConfig.embed_width must be >= 0, got {self.embed_width}")
        if not self.lr > 0:
            raise ValueError(f"CFMConfig.lr must be > 0, got {self.lr}")
        GaussianSmoothedLinearPath(self.sigma, self.tau_max)  # validates sigma, tau_max
        if self.coords not in DECODER_COORDS:
            raise ValueError(f"CFMConfig.coords must be one of {DECODER_COORDS}, got {self.coords!r}")

    @property
    def path(self) -> GaussianSmoothedLinearPath:
        return GaussianSmoothedLinearPath(self.sigma, self.tau_max)

    def replace(self, **kw) -> "CFMConfig":
        return dataclasses.replace(self, **kw)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping) -> "CFMConfig":
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"unknown CFMConfig key(s) {unknown}; known: {sorted(known)}")
        return cls(**d)


# ----------------------------------------------------------------------------------------
# Networks and checks
# ----------------------------------------------------------------------------------------

def make_network(cfg: CFMConfig, kind: str = "cfm"):
    """The flax module of a decoder kind ("cfm" -> VelocityNet, "regression" -> RegressionNet)."""
    _check_kind(kind)
    if kind == "cfm":
        return VelocityNet(cfg.theta_dim, cfg.width, cfg.blocks, cfg.embed_width, cfg.time_dim)
    return RegressionNet(cfg.theta_dim, cfg.width, cfg.blocks)


def init_params(cfg: CFMConfig, kind: str = "cfm", key: jax.Array | None = None):
    """Freshly initialised parameters (key defaults to PRNGKey(cfg.seed))."""
    key = jax.random.PRNGKey(cfg.seed) if key is None else key
    return _init_params(make_network(cfg, kind), key, kind == "cfm", cfg.theta_dim, cfg.z_dim)


@functools.partial(jax.jit, static_argnums=(0, 2, 3, 4))
def _init_params(net, key, cfm: bool, theta_dim: int, z_dim: int):
    """One compiled init per network (not one compile per initialiser op)."""
    z = jnp.zeros((1, z_dim), jnp.float32)
    if cfm:
        th = jnp.zeros((1, theta_dim), jnp.float32)
        return net.init(key, th, jnp.zeros((1,), jnp.float32), z)["params"]
    return net.init(key, z)["params"]


def _check_kind(kind):
    if kind not in KINDS:
        raise ValueError(f"unknown decoder kind {kind!r}; choose from {KINDS}")


def check_latents(z, cfg: CFMConfig, what: str = "z"):
    """z must be (m, z_dim); returns it as float32 (jnp or tracer)."""
    shape = np.shape(z)
    if len(shape) != 2 or shape[1] != cfg.z_dim:
        raise ValueError(f"{what} must have shape (m, {cfg.z_dim}); got {tuple(shape)}")
    return jnp.asarray(z, jnp.float32)


def _check_pairs(theta_norm, z, cfg: CFMConfig, what: str):
    th = np.asarray(theta_norm, np.float32)
    zz = np.asarray(z, np.float32)
    if th.ndim != 2 or th.shape[1] != cfg.theta_dim:
        raise ValueError(f"{what}: theta_norm must have shape (n, {cfg.theta_dim}) (normalised θ); "
                         f"got {th.shape}")
    if zz.ndim != 2 or zz.shape[1] != cfg.z_dim:
        raise ValueError(f"{what}: z must have shape (n, {cfg.z_dim}); got {zz.shape}")
    if th.shape[0] != zz.shape[0]:
        raise ValueError(f"{what}: theta_norm and z have different lengths ({th.shape[0]} vs {zz.shape[0]})")
    if th.shape[0] == 0:
        raise ValueError(f"{what}: empty data set")
    if not (np.isfinite(th).all() and np.isfinite(zz).all()):
        raise ValueError(f"{what}: theta_norm / z contain non-finite values")
    return th, zz


# ----------------------------------------------------------------------------------------
# Losses
# ----------------------------------------------------------------------------------------

def _per_sample_loss(kind: str, cfg: CFMConfig, net, params, theta, z, key):
    """(n,) per-sample losses (mean over dimensions)."""
    if kind == "cfm":
        x_tau, tau, u = cfg.path.sample(key, theta)
        pred = net.apply({"params": params}, x_tau, tau, z)
        return jnp.mean((pred - u) ** 2, -1)
    pred = net.apply({"params": params}, z)
    return jnp.mean((pred - theta) ** 2, -1)


def loss(params, cfg: CFMConfig, theta_norm, z, key, kind: str = "cfm"):
    """Mean training loss of a batch (jit-able; cfg and kind static)."""
    return jnp.mean(_per_sample_loss(kind, cfg, make_network(cfg, kind), params, theta_norm, z, key))


# ----------------------------------------------------------------------------------------
# Training loop
# ----------------------------------------------------------------------------------------

def _optimizer(cfg: CFMConfig, total_steps: int):
    sched = optax.cosine_decay_schedule(cfg.lr, max(total_steps, 1))
    return optax.chain(optax.clip_by_global_norm(cfg.grad_clip),
                       optax.adamw(sched, weight_decay=cfg.weight_decay))


def _data_digest(*arrays) -> str:
    """sha256 of arrays' shapes and bytes: identifies the data a checkpoint was trained on."""
    import hashlib
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a, np.float32)
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def fit_epochs(epoch, params, opt_state, k_train, theta, zz, *, cfg, kind: str, tag: str, spe: int, bs: int,
               val_fn=None, log=None, checkpoint=None, checkpoint_every: int = 10, keep_best: bool = False):
    """The epoch loop every decoder shares: resume from ``checkpoint`` (refused if it was
    written for another config or data set), ``cfg.epochs`` calls of ``epoch`` (see
    :func:`make_epoch`) with a progress bar and a log line each, a non-finite-loss guard,
    validation by ``val_fn(params)``, and a checkpoint every ``checkpoint_every`` epochs.
    theta, zz: the host training arrays. ``keep_best``: early stopping on the validation loss
    (needs ``val_fn``): the returned parameters are those of the epoch with the lowest
    validation loss (``history['best_epoch']``, ``history['best_val_loss']``), not the last.
    Returns (params, history)."""
    if keep_best and val_fn is None:
        raise ValueError(f"{tag} early stopping (keep_best) needs validation data")
    import json  # the config as it reads back from a checkpoint (tuples -> lists)

    theta_d, z_d = jnp.asarray(theta), jnp.asarray(zz)
    hist = {"epoch": [], "train_loss": [], "val_loss": [], "steps_per_s": [], "epoch_s": [],
            "steps_per_epoch": spe, "batch": bs}
    start, wall_prev = 0, 0.0
    best = (float("inf"), 0, params)  # (validation loss, epoch, parameters) of the best epoch so far
    ck_meta = None
    if checkpoint is not None:
        checkpoint = Path(checkpoint)
        ck_meta = {"kind": kind, "config": json.loads(json.dumps(cfg.to_dict())), "data": _data_digest(theta, zz),
                   "keep_best": keep_best}
        if checkpoint.is_file():
            meta = load_meta(checkpoint)
            if {k: meta.get(k) for k in ck_meta} != ck_meta:
                raise ValueError(f"{checkpoint} was written for another config or data set; "
                                 f"delete it or train into a new folder")
            if keep_best:
                params, opt_state, best_params = load_tree(checkpoint, (params, opt_state, params))
                best = (meta["best_val_loss"], meta["best_epoch"], best_params)
            else:
                params, opt_state = load_tree(checkpoint, (params, opt_state))
            start, wall_prev, hist = meta["epoch"], meta["wall_s"], meta["hist"]
            if log is not None:
                log(f"{tag} resumed from {checkpoint} at epoch {start}")
    bar = progress(total=cfg.epochs, initial=start, desc=f"train {kind}", unit="epoch")
    t_start = time.perf_counter()
    for e in range(start, cfg.epochs):
        t0 = time.perf_counter()
        params, opt_state, tl = epoch(params, opt_state, jax.random.fold_in(k_train, e), theta_d, z_d)
        tl = float(tl)  # blocks
        dt = time.perf_counter() - t0
        vl = float(val_fn(params)) if val_fn is not None else None
        sps = spe / max(dt, 1e-9)
        hist["epoch"].append(e + 1)
        hist["train_loss"].append(tl)
        hist["val_loss"].append(vl)
        hist["steps_per_s"].append(sps)
        hist["epoch_s"].append(dt)
        if log is not None:
            vs = f" val {vl:.4f}" if vl is not None else ""
            note = " (incl. compile)" if e == 0 else ""
            log(f"{tag} epoch {e + 1}/{cfg.epochs} train {tl:.4f}{vs} {sps:.1f} steps/s{note}")
        if not np.isfinite(tl):
            bar.close()
            raise FloatingPointError(f"{tag} training loss is not finite at epoch {e + 1}")
        if keep_best and vl < best[0]:
            best = (vl, e + 1, params)
        bar.update(1)
        bar.set_postfix(train=f"{tl:.4f}", **({"val": f"{vl:.4f}"} if vl is not None else {}), refresh=False)
        if ck_meta is not None and ((e + 1) % checkpoint_every == 0 and e + 1 < cfg.epochs):
            tree = (params, opt_state, best[2]) if keep_best else (params, opt_state)
            extra = {"best_val_loss": best[0], "best_epoch": best[1]} if keep_best else {}
            save_tree(checkpoint, tree, dict(ck_meta, epoch=e + 1, hist=hist, **extra,
                                             wall_s=wall_prev + time.perf_counter() - t_start))
    bar.close()
    hist["wall_s"] = wall_prev + time.perf_counter() - t_start
    if keep_best:
        hist["best_val_loss"], hist["best_epoch"], params = best
        if log is not None:
            log(f"{tag} early stopping: kept epoch {best[1]} (validation loss {best[0]:.4f}) of {cfg.epochs}")
    if val_fn is None:
        hist["val_loss"] = None
    return params, hist


def make_epoch(batch_loss, tx, n: int, spe: int, bs: int):
    """One jitted training epoch: ``spe`` minibatches of ``bs`` of a random permutation of the
    ``n`` examples, AdamW-style updates by ``tx``. batch_loss(params, θ (bs, d), z (bs, ...), key)
    -> scalar. Returns epoch(params, opt_state, key, θ (n, d), z (n, ...)) -> (params,
    opt_state, mean loss). Shared by the single-latent and sequence decoders."""
    @jax.jit
    def epoch(params, opt_state, key, theta, zz):
        kp, ks = jax.random.split(key)
        perm = jax.random.permutation(kp, n)[: spe * bs].reshape(spe, bs)
        keys = jax.random.split(ks, spe)

        def step(carry, x):
            p, o = carry
            idx, k = x
            l, g = jax.value_and_grad(batch_loss)(p, theta[idx], zz[idx], k)
            upd, o = tx.update(g, o, p)
            return (optax.apply_updates(p, upd), o), l

        (params, opt_state), losses = jax.lax.scan(step, (params, opt_state), (perm, keys))
        return params, opt_state, jnp.mean(losses)

    return epoch


@functools.lru_cache(maxsize=8)
def _epoch_for(kind, cfg: CFMConfig, n: int):
    """(jitted epoch, optimizer) of ``kind`` for ``cfg`` and ``n`` examples, built once per
    process: a resumed or repeated training of the same config and data size re-uses the
    compiled epoch."""
    bs = min(cfg.batch, n)
    spe = n // bs
    net = make_network(cfg, kind)
    tx = _optimizer(cfg, cfg.epochs * spe)

    def batch_loss(p, th, zb, k):
        return jnp.mean(_per_sample_loss(kind, cfg, net, p, th, zb, k))

    return make_epoch(batch_loss, tx, n, spe, bs), tx


def _fit(kind, theta_norm, z, cfg: CFMConfig, log, val, params=None, checkpoint=None,
         checkpoint_every: int = 10, keep_best: bool = False):

    _check_kind(kind)
    tag = f"[{kind}]"
    theta, zz = _check_pairs(theta_norm, z, cfg, "train")
    n = theta.shape[0]
    bs = min(cfg.batch, n)
    spe = n // bs
    net = make_network(cfg, kind)
    key = jax.random.PRNGKey(cfg.seed)
    k_init, k_train = jax.random.split(key)
    if params is None:
        params = init_params(cfg, kind, k_init)
    epoch, tx = _epoch_for(kind, cfg, n)
    opt_state = tx.init(params)

    val_fn = None
    if val is not None:
        vth, vz = _check_pairs(val[0], val[1], cfg, "val")
        val_fn = _make_eval(kind, cfg, net, vth, vz)

    return fit_epochs(epoch, params, opt_state, k_train, theta, zz, cfg=cfg, kind=kind, tag=tag, spe=spe,
                      bs=bs, val_fn=val_fn, log=log, checkpoint=checkpoint,
                      checkpoint_every=checkpoint_every, keep_best=keep_best)


def _make_eval(kind, cfg, net, theta, z, chunk: int = 1024):
    """Jitted mean loss over a fixed data set, in padded chunks, with a fixed key."""
    n = theta.shape[0]
    c = min(chunk, n)
    nc = -(-n // c)
    pad = nc * c - n
    th = jnp.asarray(np.concatenate([theta, np.zeros((pad, theta.shape[1]), np.float32)]))
    zz = jnp.asarray(np.concatenate([z, np.zeros((pad, z.shape[1]), np.float32)]))
    mask = jnp.asarray(np.arange(nc * c) < n, jnp.float32)
    keys = jax.random.split(jax.random.PRNGKey(cfg.seed + 1), nc)

    @jax.jit
    def ev(params):
        def one(x):
            t, zb, k = x
            return _per_sample_loss(kind, cfg, net, params, t, zb, k)
        per = jax.lax.map(one, (th.reshape(nc, c, -1), zz.reshape(nc, c, -1), keys)).reshape(-1)
        return jnp.sum(per * mask) / n

    return ev


def train_cfm(theta_norm, z, cfg: CFMConfig = CFMConfig(), log: Callable | None = print,
              val: tuple | None = None, checkpoint=None, checkpoint_every: int = 10):
    """Train the CFM velocity field v(θ_τ, τ, z).

    theta_norm: (n, theta_dim) normalised θ; z: (n, z_dim); val: optional (theta_norm, z)
    held-out pair. Returns (params, history) with history keys ``epoch``, ``train_loss``,
    ``val_loss`` (list or None), ``steps_per_s`` (epoch 1 includes compilation), ``epoch_s``,
    ``steps_per_epoch``, ``batch``, ``wall_s``.

    ``checkpoint``: a file for the training state every ``checkpoint_every`` epochs; when it
    exists (same kind, config and data), training resumes from it and ends with the same
    weights as an uninterrupted run (epoch keys are ``fold_in(key, epoch)``).
    """
    return _fit("cfm", theta_norm, z, cfg, log, val, checkpoint=checkpoint, checkpoint_every=checkpoint_every)


def train_regression(theta_norm, z, cfg: CFMConfig = CFMConfig(), log: Callable | None = print,
                     val: tuple | None = None, checkpoint=None, checkpoint_every: int = 10,
                     early_stopping: bool = True):
    """Train the Regression baseline r(z) (MSE, same architecture and optimiser). Same I/O
    as :func:`train_cfm`. A point estimate over-fits where CFM does not (its validation loss
    is lowest well before the last epoch), so by default it stops early: the epoch with the
    lowest loss on ``val`` is kept (``early_stopping=False``: the last epoch). Give ``val`` a validation split of the training data, not the held-out pairs it
    is scored on."""
    _check_pairs(theta_norm, z, cfg, "train")
    if early_stopping and val is None:
        raise ValueError("train_regression: early stopping needs validation pairs (val=...), or early_stopping=False")
    return _fit("regression", theta_norm, z, cfg, log, val, checkpoint=checkpoint,
                checkpoint_every=checkpoint_every, keep_best=early_stopping)


# ----------------------------------------------------------------------------------------
# Save / load
# ----------------------------------------------------------------------------------------

class LoadedDecoder(NamedTuple):
    kind: str
    params: dict
    cfg: CFMConfig
    normalizer: object      # mjxsysid.cfm.flow_coords.FlowNormalizer or None
    meta: dict


def _normalizer_dict(normalizer):
    if normalizer is None:
        return None
    if hasattr(normalizer, "to_dict"):
        return normalizer.to_dict()
    d = {k: [float(x) for x in np.asarray(normalizer[k], np.float64).ravel()] for k in ("shift", "scale")}
    return d


def save_decoder(path, kind: str, params, cfg: CFMConfig, normalizer_dict=None,
                 meta: dict | None = None) -> Path:
    """Write a decoder to ``path`` (.npz). ``normalizer_dict``: a Normalizer or its
    ``to_dict()`` (shift/scale lists; None only for non-θ toy problems); ``meta``: any
    JSON-serialisable extras (data provenance, history, ...)."""

    _check_kind(kind)
    nd = _normalizer_dict(normalizer_dict)
    if nd is not None:
        for k in ("shift", "scale"):
            if len(nd[k]) != cfg.theta_dim:
                raise ValueError(f"normalizer {k} has {len(nd[k])} entries, expected {cfg.theta_dim}")
    full = {"format": FORMAT, "kind": kind, "config": cfg.to_dict(), "normalizer": nd,
            "meta": dict(meta or {})}
    return save_tree(path, params, full)


def load_decoder(path) -> LoadedDecoder:
    """Read a decoder written by :func:`save_decoder` -> (kind, params, cfg, normalizer, meta)."""

    full = load_meta(path)
    if full.get("format") != FORMAT:
        raise ValueError(f"{path}: not a decoder file (format {full.get('format')!r}, expected {FORMAT!r})")
    kind = full.get("kind")
    if kind == "cfm_seq":
        raise ValueError(f"{path} is a sequence decoder: load it with mjxsysid.cfm.sequence.SequenceDecoder.load")
    if kind not in KINDS:
        raise ValueError(f"{path}: decoder kind {kind!r} is not one of {KINDS}")
    try:
        cfg = CFMConfig.from_dict(full["config"])
    except (KeyError, TypeError, ValueError) as e:
        raise ValueError(f"{path}: bad decoder config ({type(e).__name__}: {e})") from None
    params = load_tree(path, jax.eval_shape(lambda: init_params(cfg, kind)), finite=True)
    norm = None
    if full.get("normalizer") is not None:
        try:
            norm = FlowNormalizer.from_dict(full["normalizer"])
            bad = [k for k in ("shift", "scale") if np.shape(getattr(norm, k)) != (cfg.theta_dim,)
                   or not np.all(np.isfinite(getattr(norm, k)))]
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"{path}: bad normalizer ({type(e).__name__}: {e})") from None
        if bad or not np.all(np.asarray(norm.scale) > 0):
            raise ValueError(f"{path}: bad normalizer: shift and scale must be {cfg.theta_dim} finite values, "
                             f"scale > 0")
    return LoadedDecoder(kind, jax.tree_util.tree_map(jnp.asarray, params), cfg, norm, full.get("meta", {}))
