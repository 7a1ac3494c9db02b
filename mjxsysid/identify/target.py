"""The log-grounded posterior's target: the stated prior of v and the nuisances times the log's
likelihood (:mod:`.likelihood`), evaluated in jitted chunks, for one log or a batch of logs, at full
float32 precision on every backend (:func:`full_precision`).

Coordinates (:mod:`.logspace`): y (17,) = [v (12), log σ (4), acc_z bias] is what the samplers move;
x (21,) adds the discrepancy log δ (4), fixed at the mode (:mod:`.mode`)."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify.coords import PHYSICAL_PRIOR, PhysicalPrior
from mjxsysid.identify.likelihood import log_likelihood
from mjxsysid.identify.logdata import LogData


NUIS_BOUNDS = (np.log(1e-6), np.log(5.0), np.log(1e-6), np.log(5.0), -3.0, 3.0)
"""Uniform priors of the nuisances: log σ, log δ in [log 1e-6, log 5] (rad/s, m/s²), acc_z bias
in [−3, 3] m/s² (times :data:`ACC_BIAS_SD`'s normal)."""


ACC_BIAS_SD = 0.3
"""m/s²: the accelerometer's z bias is N(0, 0.3²) a priori (a calibrated MEMS accelerometer's bias:
0.05–0.3 m/s²). It trades against thrust-to-weight at hover (acc_z = g there whatever the thrust
coefficient), so a flat prior would leave thrust-to-weight to the bias's range."""


def full_precision(f):
    """``f`` with every float32 matmul it traces at full precision, on every backend. A GPU's
    default (TF32 on an H100) narrows and shifts the posterior's bands: on 25 logs at × 1 noise
    the roll authority's coverage is 1.00 on a CPU and 0.84 on an H100 at the default precision
    (docs/identify.md). CPUs
    compute full float32 anyway. The public entry points of this module carry it."""
    @functools.wraps(f)
    def run(*args, **kwargs):
        with jax.default_matmul_precision("highest"):
            return f(*args, **kwargs)
    return run


N_Y = L.N_Y
"""The sampled coordinates: v (12), log σ (4), acc_z bias."""


def _nuis_lo_hi():
    a, b, c, d, e, f = NUIS_BOUNDS
    n = L.N_CHANNELS
    return (L.pack(L.NUISANCE_FIELDS, log_noise=np.full(n, a), log_discrepancy=np.full(n, c), acc_z_bias=e),
            L.pack(L.NUISANCE_FIELDS, log_noise=np.full(n, b), log_discrepancy=np.full(n, d), acc_z_bias=f))


def _y_lo_hi(prior):
    lo, hi = prior.v_bounds()
    nlo, nhi = _nuis_lo_hi()
    return np.concatenate([lo, nlo[L.NUIS_IN_Y]]), np.concatenate([hi, nhi[L.NUIS_IN_Y]])


def full_x(y, log_delta):
    """y (..., 17) and log δ (4,) -> x (..., 21) = [v, log σ, log δ, bias]."""
    return L.x_from_y(y, log_delta)


def log_prior(x, prior: PhysicalPrior = PHYSICAL_PRIOR):
    """log p(x) up to a constant, x (21,) = [v, log σ, log δ, bias]: the physical prior, uniform
    nuisances, the bias N(0, :data:`ACC_BIAS_SD`²)."""
    lo, hi = _nuis_lo_hi()
    n = x[L.X_NUIS]
    ok = jnp.all((n >= lo) & (n <= hi))
    return prior.log_prob_v(x[L.X_V]) + jnp.where(ok, 0.0, -jnp.inf) - 0.5 * (x[L.X_BIAS] / ACC_BIAS_SD) ** 2


def _log_target_y(y, data, log_delta, weights, prior):
    x = full_x(y, log_delta)
    lp = log_prior(x, prior)
    ll = log_likelihood(x, data, weights)
    return jnp.where(jnp.isfinite(lp) & jnp.isfinite(ll), lp + ll, -jnp.inf)


@functools.partial(jax.jit, static_argnames=("prior",))
def _batch_log_target(y, data, log_delta, weights, prior):
    return jax.vmap(lambda z: _log_target_y(z, data, log_delta, weights, prior))(y)


TARGET_CHUNK = 4096
"""Candidates per call of the jitted target: a batch is padded to a multiple of it, so one program
serves the mode's few fits, the importance draws and any batch a caller passes."""


@full_precision
def log_target(y, data: LogData, log_delta=None, weights=None, prior: PhysicalPrior = PHYSICAL_PRIOR):
    """log prior + log likelihood of a batch y (N, 17) -> (N,), in jitted chunks of
    :data:`TARGET_CHUNK` (log δ (4,) default 1e-4; weights (4,) default 1)."""
    ld = np.full(L.N_CHANNELS, np.log(1e-4), np.float32) if log_delta is None else jnp.asarray(log_delta, jnp.float32)
    w = np.ones(L.N_CHANNELS, np.float32) if weights is None else jnp.asarray(weights, jnp.float32)
    y = np.asarray(y, np.float32)
    n = len(y)
    pad = -n % TARGET_CHUNK
    yp = np.concatenate([y, np.broadcast_to(y[:1], (pad, y.shape[1]))]) if pad else y  # rows, not coordinates
    out = [np.asarray(_batch_log_target(jnp.asarray(yp[i:i + TARGET_CHUNK]), data, ld, w, prior))
           for i in range(0, len(yp), TARGET_CHUNK)]
    return np.concatenate(out)[:n]


TARGET_EVALS = {"cpu": 4096}
"""Evaluations of the target per call when several logs are evaluated together, per backend (a
batch's draws are cut into chunks of TARGET_EVALS / logs each); an accelerator takes
:data:`TARGET_EVALS_ACCELERATOR`."""
TARGET_EVALS_ACCELERATOR = 1 << 18
"""256 logs × 1024 draws a call: a few calls for a batch's 4096 importance draws, not 256."""


def target_evals() -> int:
    """:data:`TARGET_EVALS` of the default backend."""
    return TARGET_EVALS.get(jax.default_backend(), TARGET_EVALS_ACCELERATOR)


@functools.partial(jax.jit, static_argnames=("prior",))
def _batch_log_target_logs(y, data, log_delta, weights, prior):
    """:func:`_batch_log_target` vmapped over logs: y (L, N, 17) -> (L, N)."""
    return jax.vmap(lambda z, d, a, b: _batch_log_target(z, d, a, b, prior))(y, data, log_delta, weights)
