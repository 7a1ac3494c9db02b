"""mjxsysid.identify.smalllinalg on a CPU: forward substitution and Cholesky without LAPACK's kernels, equal to
LAPACK's to rounding, and the posterior's proposals traced without a LAPACK custom call (jaxlib's batched LAPACK
kernels wait inside XLA:CPU's thread pool: a program vmapped over logs hung in them on 2 cores)."""
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

from mjxsysid.identify.proposals import Gaussian, StudentT
from mjxsysid.identify.smalllinalg import cholesky, solve_lower


def _spd(rng, k):
    m = rng.normal(size=(k, k))
    return (m @ m.T + k * np.eye(k)).astype(np.float32)


def test_forward_substitution_and_cholesky_equal_lapacks_and_a_matrix_not_positive_definite_gives_nan():
    rng = np.random.default_rng(0)
    for k in (1, 5, 17):
        a = _spd(rng, k)
        want = np.linalg.cholesky(a.astype(np.float64))
        np.testing.assert_allclose(np.asarray(jax.jit(cholesky)(a)), want, rtol=2e-5, atol=2e-5)
        d = rng.normal(size=(4, 3, k)).astype(np.float32)
        upper = want + np.triu(np.ones((k, k)), 1)                    # what lies above the diagonal is ignored
        got = np.asarray(jax.jit(solve_lower)(upper.astype(np.float32), d))
        ref = scipy.linalg.solve_triangular(want, d.reshape(-1, k).T.astype(np.float64), lower=True).T.reshape(d.shape)
        np.testing.assert_allclose(got, ref, rtol=1e-4, atol=1e-5)
    assert np.isnan(np.asarray(cholesky(jnp.array([[1.0, 2.0], [2.0, 1.0]]))))[1, 1]


def test_the_proposals_log_densities_vmapped_over_logs_call_no_lapack_kernel_and_match_the_hosts():
    rng = np.random.default_rng(1)
    k, logs = 17, 4
    chols = np.stack([np.linalg.cholesky(_spd(rng, k)) for _ in range(logs)]).astype(np.float32)
    x = rng.normal(size=(logs, 64, k)).astype(np.float32)
    mean = np.zeros(k, np.float32)
    for dist in (Gaussian, StudentT):
        f = jax.jit(jax.vmap(lambda c, y, dist=dist: dist(mean, c).log_prob(y)))
        assert "lapack" not in f.lower(chols, x).as_text().lower()
        host = np.stack([dist(mean, c).log_prob(y) for c, y in zip(chols, x)])
        np.testing.assert_allclose(np.asarray(f(chols, x)), host, rtol=1e-4, atol=1e-3)
