"""Small dense linear algebra inside the posterior's programs, without LAPACK's custom calls.

On a CPU, jaxlib's LAPACK kernels split a batch of matrices into tasks on XLA's thread pool and wait for them
from inside that pool (``ParallelBatchMap``, once a batch holds 2·10⁵ FLOP). In a program vmapped over logs,
two such kernels at once hold both threads of a 2-core machine, and the program waits forever: the SMC of 8 logs
of 10 s in one batch hung in ``lapack_strsm`` (the proposals' triangular solves), with or without
``--xla_cpu_multi_thread_eigen=false``. The matrices here are at most 17 × 17, so on a CPU a row-by-row loop
(one loop in the program) does the work instead. Other backends keep their solvers (cuBLAS, cuSOLVER: the GPU
measurements were made with them).
"""
from __future__ import annotations

import jax
import jax.numpy as jnp


def _on_cpu() -> bool:
    return jax.default_backend() == "cpu"


def solve_lower(c, d):
    """z with c zᵀ = dᵀ for a lower-triangular c (k, k) (what lies above its diagonal ignored) and right-hand
    sides d (..., k), by forward substitution on a CPU -> (..., k)."""
    k = c.shape[-1]
    if not _on_cpu():
        return jax.scipy.linalg.solve_triangular(c, jnp.reshape(d, (-1, k)).T, lower=True).T.reshape(jnp.shape(d))
    idx = jnp.arange(k)

    def row(i, z):
        ci = jnp.where(idx < i, c[i], 0)
        zi = (jnp.take(d, i, axis=-1) - z @ ci) / c[i, i]
        return jnp.where(idx == i, zi[..., None], z)
    return jax.lax.fori_loop(0, k, row, jnp.zeros(jnp.shape(d), jnp.result_type(c, d)))


def cholesky(a):
    """The lower Cholesky factor of a symmetric positive-definite a (k, k), column by column -> (k, k); NaN where
    a is not positive definite, as LAPACK's (on a CPU; elsewhere the backend's own)."""
    if not _on_cpu():
        return jnp.linalg.cholesky(a)
    k = a.shape[-1]
    idx = jnp.arange(k)

    def column(j, out):
        v = a[:, j] - out @ out[j]                  # the columns filled so far: 0 … j − 1
        d = jnp.sqrt(v[j])
        return jnp.where(idx[None, :] == j, jnp.where(idx > j, v / d, jnp.where(idx == j, d, 0))[:, None], out)
    return jax.lax.fori_loop(0, k, column, jnp.zeros_like(a))
