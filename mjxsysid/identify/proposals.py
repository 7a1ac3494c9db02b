"""The log-grounded posterior's proposals and importance-sampling diagnostics (:mod:`.inference`):
Gaussian and Student-t densities that draw on the host (NumPy: compile nothing) and evaluate on the
host or inside jit, the decoded ensemble's Gaussian fit in v, the nuisances' proposal, and the
effective sample size and Pareto k̂ of importance weights."""
from __future__ import annotations

import dataclasses
import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify.coords import PHYSICAL_PRIOR, PhysicalPrior, visible_from_theta, xp_of
from mjxsysid.identify.logspace import N_V
from mjxsysid.identify.likelihood import QUANTISATION_VAR, noise_estimate
from mjxsysid.identify.logdata import LogData
from mjxsysid.identify.smalllinalg import solve_lower
from mjxsysid.identify.target import NUIS_BOUNDS

PROPOSAL_WIDEN = 1.5
"""The decoded ensemble's Gaussian fit in v is widened by this factor (a defensive proposal)."""


def _solve_lower(chol, d):
    """z with chol z = d for a batch d (..., k) (SciPy on the host; under jit by forward substitution,
    :func:`~.smalllinalg.solve_lower`: no LAPACK kernel in a program vmapped over logs)."""
    if xp_of(d, chol) is jnp:
        return solve_lower(jnp.asarray(chol, jnp.float32), d)
    from scipy.linalg import solve_triangular
    d = np.asarray(d, np.float64)
    return solve_triangular(np.asarray(chol, np.float64), d.reshape(-1, d.shape[-1]).T, lower=True).T.reshape(d.shape)


@functools.partial(jax.tree_util.register_dataclass, data_fields=["mean", "chol"], meta_fields=[])
@dataclasses.dataclass(frozen=True)
class Gaussian:
    """A multivariate normal (mean (d,), chol (d, d) lower). Draws on the host (NumPy: compile
    nothing); ``log_prob`` on the host or inside jit (:func:`~.coords.xp_of`)."""
    mean: np.ndarray
    chol: np.ndarray

    def sample(self, rng, n):
        z = np.random.default_rng(rng).standard_normal((n, len(self.mean)))
        return (np.asarray(self.mean) + z @ np.asarray(self.chol).T).astype(np.float32)

    def log_prob(self, x):
        xp = xp_of(x, self.mean)
        z = _solve_lower(self.chol, x - self.mean)
        logdet = xp.sum(xp.log(xp.diag(self.chol)))
        return -0.5 * xp.sum(z * z, -1) - logdet - 0.5 * len(self.mean) * np.log(2 * np.pi)


@functools.partial(jax.tree_util.register_dataclass, data_fields=["mean", "chol"], meta_fields=["df"])
@dataclasses.dataclass(frozen=True)
class StudentT:
    """A multivariate Student-t (location (d,), chol (d, d) of the scale, ``df``)."""
    mean: np.ndarray
    chol: np.ndarray
    df: float = 5.0

    def sample(self, rng, n):
        rng = np.random.default_rng(rng)
        z = rng.standard_normal((n, len(self.mean)))
        g = rng.gamma(self.df / 2, size=(n, 1)) / (self.df / 2)
        return (np.asarray(self.mean) + (z / np.sqrt(g)) @ np.asarray(self.chol).T).astype(np.float32)

    def log_prob(self, x):
        xp = xp_of(x, self.mean)
        d = len(self.mean)
        z = _solve_lower(self.chol, x - self.mean)
        logdet = xp.sum(xp.log(xp.diag(self.chol)))
        c = math.lgamma((self.df + d) / 2) - math.lgamma(self.df / 2) - d / 2 * math.log(self.df * math.pi)
        return c - logdet - (self.df + d) / 2 * xp.log1p(xp.sum(z * z, -1) / self.df)


def decoded_proposal(decoded_theta, prior: PhysicalPrior = PHYSICAL_PRIOR, widen: float = PROPOSAL_WIDEN):
    """A Gaussian in v fitted to the decoded samples θ (S, 19) inside the prior (None if fewer than
    N_V + 2 of them are)."""
    th = np.asarray(decoded_theta, np.float64)
    th = th[np.all(np.isfinite(th), -1)]
    v = np.asarray(visible_from_theta(th), np.float64)
    v = v[np.all(np.isfinite(v), -1) & np.asarray(prior.v_valid(v))]
    if len(v) < N_V + 2:
        return None
    cov = np.cov(v.T) + np.diag(1e-4 + 1e-2 * np.var(v, 0))   # shrunk: S may be small
    return Gaussian(v.mean(0), np.linalg.cholesky(cov) * widen)


def nuisance_proposal(data: LogData, bias_sd: float) -> Gaussian:
    """y's nuisances (:data:`~.logspace.Y_NUIS_FIELDS`): log σ (4) near the second differences' estimate
    (standard deviation 0.2), the bias near 0 (standard deviation ``bias_sd``). A channel whose second
    differences are at the readings' rounding (σ below √:data:`~.likelihood.QUANTISATION_VAR`) has a
    flat likelihood in log σ from there down to the prior's floor: the proposal spans that range."""
    sig = noise_estimate(data)
    top = np.log(np.sqrt(QUANTISATION_VAR))
    flat = np.log(sig) < top
    floor = NUIS_BOUNDS[0]
    mu = np.where(flat, 0.5 * (top + floor), np.log(sig))
    mean = L.pack(L.Y_NUIS_FIELDS, log_noise=mu, acc_z_bias=0.0).astype(np.float32)
    sd = L.pack(L.Y_NUIS_FIELDS, log_noise=np.where(flat, 0.5 * (top - floor), 0.2), acc_z_bias=bias_sd)
    return Gaussian(mean, np.diag(sd.astype(np.float32)))


def pareto_khat(log_w) -> float:
    """Pareto k̂ of importance weights (log_w (N,)): the shape of a generalised Pareto fitted (scipy,
    location fixed at the threshold) to the largest min(N/5, 3√N) weights (PSIS, Vehtari et al. 2024)."""
    from scipy.stats import genpareto
    lw = np.asarray(log_w, np.float64)
    lw = lw[np.isfinite(lw)]
    if len(lw) < 20:
        return float("inf")
    m = int(min(len(lw) / 5, 3 * np.sqrt(len(lw))))
    w = np.exp(lw - lw.max())
    tail = np.sort(w)[-m - 1:]
    exc = tail[1:] - tail[0]
    if np.all(exc <= 0):
        return 0.0
    c, _, _ = genpareto.fit(exc, floc=0.0)
    return float(c)


def ess(log_w) -> float:
    lw = np.asarray(log_w, np.float64)
    lw = np.where(np.isfinite(lw), lw, -np.inf)
    if not np.isfinite(lw).any():
        return 0.0
    w = np.exp(lw - lw.max())
    return float(w.sum() ** 2 / (w * w).sum())
