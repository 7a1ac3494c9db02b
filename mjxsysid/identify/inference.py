"""The log-grounded posterior: the stated physical prior × the log's likelihood, with the decoded
ensemble as the proposal and a tempered SMC where it misses.

Target (21-d): p(v) p(nuisances) p(log | v, nuisances) (:mod:`.coords`, :mod:`.likelihood`);
the hidden coordinates h are independent of the log, so θ = θ(v, h) with h drawn from the prior.

1. **Importance sampling from the decoders.** The decoded samples θ (S, 19) mapped to v are
   fitted by a Gaussian (widened by :data:`PROPOSAL_WIDEN`), the nuisances' proposal centred on
   the log's own noise estimate; N draws are weighted by target / proposal. Reported: the
   effective sample size and Pareto k̂ of the weights' upper tail (Vehtari et al., PSIS; the
   generalised-Pareto fit is scipy's). The decoded density is the proposal only, never a factor
   of the target: the latent came from the same log.
2. **Tempered SMC** (blackjax's adaptive tempered SMC, random-walk Metropolis moves whose
   covariance is the particles', re-estimated each stage) when the weights are unreliable
   (ESS < :data:`MIN_ESS_FRACTION` N or k̂ > :data:`MAX_KHAT`): from a mixture of the proposal and
   the prior, tempered to the target (the path q^{1−λ} target^{λ}).
"""
from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify.coords import (N_V, PHYSICAL_PRIOR, PhysicalPrior, hidden_from_theta, theta_from,
                                      visible_from_theta)
from mjxsysid.identify.likelihood import N_NUIS, LogData, linear_start, log_likelihood, noise_estimate, prepare

PROPOSAL_WIDEN = 1.5
"""The decoded ensemble's Gaussian fit in v is widened by this factor (a defensive proposal)."""
MIN_ESS_FRACTION = 0.05
MAX_KHAT = 0.7
"""Importance sampling is trusted when ESS ≥ 5 % of the draws and k̂ ≤ 0.7 (PSIS's threshold)."""
PRIOR_SHARE = 0.3
"""Share of the prior in the SMC's starting mixture (the rest: the decoded proposal)."""
NUIS_BOUNDS = (np.log(1e-6), np.log(5.0), np.log(1e-6), np.log(5.0), -3.0, 3.0)
"""Uniform priors of the nuisances: log σ, log δ in [log 1e-6, log 5] (rad/s, m/s²), acc_z bias
in [−3, 3] m/s² (times :data:`ACC_BIAS_SD`'s normal)."""
ACC_BIAS_SD = 0.3
"""m/s²: the accelerometer's z bias is N(0, 0.3²) a priori (a calibrated MEMS accelerometer's bias:
0.05–0.3 m/s²). It trades against thrust-to-weight at hover (acc_z = g there whatever the thrust
coefficient), so a flat prior would leave thrust-to-weight to the bias's range."""


def _nuis_lo_hi():
    a, b, c, d, e, f = NUIS_BOUNDS
    lo = np.array([a] * 4 + [c] * 4 + [e]); hi = np.array([b] * 4 + [d] * 4 + [f])
    return lo, hi


def log_prior(x, prior: PhysicalPrior = PHYSICAL_PRIOR):
    """log p(x) up to a constant, x (21,) = [v, nuisances]."""
    lo, hi = _nuis_lo_hi()
    n = x[N_V:]
    ok = jnp.all((n >= lo) & (n <= hi))
    return prior.log_prob_v(x[:N_V]) + jnp.where(ok, 0.0, -jnp.inf) - 0.5 * (x[-1] / ACC_BIAS_SD) ** 2


@dataclasses.dataclass(frozen=True)
class Gaussian:
    """A multivariate normal (mean (d,), chol (d, d) lower)."""
    mean: np.ndarray
    chol: np.ndarray

    def sample(self, key, n):
        z = jax.random.normal(key, (n, len(self.mean)), jnp.float32)
        return np.asarray(self.mean + z @ self.chol.T, np.float32)

    def log_prob(self, x):
        d = x - jnp.asarray(self.mean, jnp.float32)
        z = jax.scipy.linalg.solve_triangular(jnp.asarray(self.chol, jnp.float32), d.T, lower=True).T
        logdet = jnp.sum(jnp.log(jnp.diag(jnp.asarray(self.chol, jnp.float32))))
        return -0.5 * jnp.sum(z * z, -1) - logdet - 0.5 * len(self.mean) * np.log(2 * np.pi)


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


def nuisance_proposal(data: LogData) -> Gaussian:
    """log σ near the second differences' estimate, log δ broad, the bias near 0."""
    sig = np.maximum(noise_estimate(data), 1e-6)
    mean = np.concatenate([np.log(sig), np.log(np.maximum(sig, 1e-3)) + 1.0, [0.0]])
    sd = np.concatenate([np.full(4, 0.3), np.full(4, 2.5), [0.5]])
    return Gaussian(mean, np.diag(sd))


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


@functools.partial(jax.jit, static_argnames=("prior",))
def _batch_log_target(x, data, prior):
    lp = jax.vmap(lambda z: log_prior(z, prior))(x)
    ll = jax.vmap(lambda z: log_likelihood(z, data))(x)
    return jnp.where(jnp.isfinite(lp), lp + jnp.where(jnp.isfinite(ll), ll, -jnp.inf), -jnp.inf)


def log_target(x, data: LogData, prior: PhysicalPrior = PHYSICAL_PRIOR):
    """log prior + log likelihood of a batch x (N, 21) -> (N,), in one jitted call."""
    return _batch_log_target(jnp.asarray(x, jnp.float32), data, prior)


def _mixture_log_prob(x, qv: Gaussian | None, qn: Gaussian, prior: PhysicalPrior, share: float, lap=None):
    """log density of the SMC's starting mixture: ``share`` prior, the rest split between the
    decoded proposal ``qv`` and the Laplace proposal ``lap`` (the nuisances from ``qn`` in the
    first two components, from ``lap`` in the last)."""
    lo, hi = prior.v_bounds()
    vol = float(np.sum(np.log(hi - lo)))   # the box's volume (the truncation only adds a constant)
    lp_prior = jnp.where(prior.v_valid(x[..., :N_V]), -vol, -jnp.inf) + qn.log_prob(x[..., N_V:])
    comps = [jnp.log(share) + lp_prior] if share > 0 else []
    rest = 1.0 - share
    k = (qv is not None) + (lap is not None)
    if qv is not None:
        comps.append(jnp.log(rest / k) + qv.log_prob(x[..., :N_V]) + qn.log_prob(x[..., N_V:]))
    if lap is not None:
        comps.append(jnp.log(rest / k) + lap.log_prob(x))
    out = comps[0]
    for c in comps[1:]:
        out = jnp.logaddexp(out, c)
    return out


@functools.partial(jax.jit, static_argnames=("prior", "n_mcmc", "max_stages", "share", "target_ess"))
def _smc(key, x0, data, qv_mean, qv_chol, qn_mean, qn_chol, prior, n_mcmc, max_stages, share, target_ess,
         lap_mean=None, lap_chol=None):
    import blackjax
    from blackjax.mcmc.random_walk import build_additive_step, normal
    from blackjax.smc.base import extend_params

    qv = None if qv_mean is None else Gaussian(qv_mean, qv_chol)
    qn = Gaussian(qn_mean, qn_chol)
    lap = None if lap_mean is None else StudentT(lap_mean, lap_chol)

    def logq(x):
        return _mixture_log_prob(x, qv, qn, prior, share, lap)

    def logrest(x):   # target / q: what the tempering brings in
        lt = log_prior(x, prior) + log_likelihood(x, data)
        lt = jnp.where(jnp.isfinite(lt), lt, -jnp.inf)
        return jnp.where(jnp.isfinite(lt), lt - logq(x), -1e30)

    rw = build_additive_step()

    def step(rng, state, logdensity_fn, chol):
        return rw(rng, state, logdensity_fn, normal(chol))

    d = x0.shape[1]

    def update(_key, state, info):
        p = state.particles
        cov = jnp.cov(p.T) + 1e-8 * jnp.eye(d)
        return extend_params({"chol": 2.38 / jnp.sqrt(d) * jnp.linalg.cholesky(cov)})

    cov0 = jnp.cov(x0.T) + 1e-8 * jnp.eye(d)
    smc = blackjax.inner_kernel_tuning(
        smc_algorithm=blackjax.adaptive_tempered_smc, logprior_fn=logq, loglikelihood_fn=logrest,
        mcmc_step_fn=step, mcmc_init_fn=blackjax.rmh.init, resampling_fn=blackjax.smc.resampling.systematic,
        mcmc_parameter_update_fn=update,
        initial_parameter_value=extend_params({"chol": 2.38 / jnp.sqrt(d) * jnp.linalg.cholesky(cov0)}),
        num_mcmc_steps=n_mcmc, target_ess=target_ess)
    state = smc.init(x0)

    def cond(c):
        s, i, _, _ = c
        return (s.sampler_state.tempering_param < 1.0) & (i < max_stages)

    def body(c):
        s, i, k, acc = c
        k, sub = jax.random.split(k)
        s, info = smc.step(sub, s)
        return s, i + 1, k, acc + jnp.mean(info.update_info.is_accepted)

    state, n, _, acc = jax.lax.while_loop(cond, body, (state, 0, key, 0.0))
    return state.sampler_state.particles, state.sampler_state.weights, state.sampler_state.tempering_param, n, acc / jnp.maximum(n, 1)


@dataclasses.dataclass(frozen=True)
class StudentT:
    """A multivariate Student-t (location (d,), chol (d, d) of the scale, ``df``)."""
    mean: np.ndarray
    chol: np.ndarray
    df: float = 5.0

    def sample(self, key, n):
        k1, k2 = jax.random.split(key)
        z = jax.random.normal(k1, (n, len(self.mean)), jnp.float32)
        g = jax.random.gamma(k2, self.df / 2, (n, 1)) / (self.df / 2)
        return np.asarray(self.mean + (z / jnp.sqrt(g)) @ jnp.asarray(self.chol, jnp.float32).T, np.float32)

    def log_prob(self, x):
        d = len(self.mean)
        z = jax.scipy.linalg.solve_triangular(jnp.asarray(self.chol, jnp.float32),
                                              (x - jnp.asarray(self.mean, jnp.float32)).T, lower=True).T
        logdet = jnp.sum(jnp.log(jnp.diag(jnp.asarray(self.chol, jnp.float32))))
        c = (jax.scipy.special.gammaln((self.df + d) / 2) - jax.scipy.special.gammaln(self.df / 2)
             - d / 2 * jnp.log(self.df * jnp.pi))
        return c - logdet - (self.df + d) / 2 * jnp.log1p(jnp.sum(z * z, -1) / self.df)


def _objective(x, data):
    """What the optimiser minimises: −(log likelihood + the bias prior), smooth (the prior's box
    is checked on the result, not imposed)."""
    return -(log_likelihood(x, data) - 0.5 * (x[-1] / ACC_BIAS_SD) ** 2)


@functools.partial(jax.jit, static_argnames=("max_steps",))
def _fit_modes(starts, data, max_steps=400):
    """BFGS (optimistix) from each start (K, 21) -> optima (K, 21), objective values (K,)."""
    import optimistix as optx

    def one(x0):
        sol = optx.minimise(lambda x, d: _objective(x, d), optx.BFGS(rtol=1e-7, atol=1e-7), x0, args=data,
                            max_steps=max_steps, throw=False)
        return sol.value, _objective(sol.value, data)

    return jax.vmap(one)(starts)


@jax.jit
def _hessian(x, data):
    return jax.hessian(_objective)(x, data)


def laplace_proposal(data: LogData, starts, prior: PhysicalPrior = PHYSICAL_PRIOR, widen: float = 1.3):
    """The mode of the target found by BFGS from ``starts`` (K, 21) and a Student-t around it with
    the inverse Hessian as its scale (× ``widen``) -> (StudentT or None, the mode, its objective)."""
    xs, fs = _fit_modes(jnp.asarray(starts, jnp.float32), data)
    lo, hi = _box(prior)
    eps = 1e-4 * (hi - lo)
    xs = np.clip(np.asarray(xs), lo + eps, hi - eps)   # an optimum past the box's edge: its edge
    # and J's triangle inequality: A_z no smaller than 1 / (1/A_x + 1/A_y)
    xs[:, 7] = np.maximum(xs[:, 7], -np.log(np.exp(-xs[:, 5]) + np.exp(-xs[:, 6])) + 1e-4)
    lt = np.asarray(log_target(xs, data, prior))
    ok = np.isfinite(lt)
    if not ok.any():
        return None, None, None
    best = xs[np.argmax(np.where(ok, lt, -np.inf))]
    h = np.asarray(_hessian(jnp.asarray(best), data), np.float64)
    h = np.nan_to_num(0.5 * (h + h.T), nan=0.0, posinf=1e12, neginf=-1e12)
    w, u = np.linalg.eigh(h)
    w = np.clip(w, 1e-6 * max(w.max(), 1e-12) + 1e-9, None)       # flat directions: broad, not infinite
    cov = (u / w) @ u.T
    lo, hi = _box(prior)
    span = np.diag(((hi - lo) / 2) ** 2)
    cov = np.linalg.inv(np.linalg.inv(cov) + np.linalg.inv(span))  # no wider than the prior's box
    return StudentT(best, np.linalg.cholesky(cov) * widen), best, float(lt.max())


def _box(prior):
    lo, hi = prior.v_bounds()
    nlo, nhi = _nuis_lo_hi()
    return np.concatenate([lo, nlo]), np.concatenate([hi, nhi])


def _weights(x, logq, data, prior):
    lw = np.asarray(log_target(x, data, prior), np.float64) - np.asarray(logq, np.float64)
    return lw, ess(lw), pareto_khat(lw)


def log_grounded_posterior(rec_or_data, decoded_theta=None, *, prior: PhysicalPrior = PHYSICAL_PRIOR,
                           samples: int = 1000, draws: int = 4096, particles: int = 2048, seed: int = 0,
                           n_mcmc: int = 6, max_stages: int = 200, starts: int = 16,
                           force_smc: bool = False) -> dict:
    """The posterior of a flight log (``rec_or_data``: the arrays of ``read_log`` or a
    :class:`LogData`) under the physical ``prior``, with ``decoded_theta`` (S, 19) — the decoders'
    samples of this log, or None — as the proposal.

    1. the decoded ensemble as the proposal (a Gaussian fit in v, the nuisances near the log's
       noise estimate): importance weights, their ESS and Pareto k̂ (``decoded_is``): how far the
       policy's knowledge is from what the log shows;
    2. the target's mode by BFGS (optimistix) started from the decoded samples (and prior draws),
       a Student-t at the inverse Hessian there as the refined proposal: importance weights again
       (``laplace_is``);
    3. if neither proposal's weights are reliable (ESS < :data:`MIN_ESS_FRACTION` of the draws or
       k̂ > :data:`MAX_KHAT`), or ``force_smc``, a tempered SMC (blackjax) from a mixture of the
       proposals and the prior.

    -> dict: ``theta`` (samples, 19) (hidden coordinates drawn from the prior), ``v`` (samples, 12),
    ``nuisance`` (samples, 9), ``method`` ('decoded_is', 'laplace_is' or 'smc'), ``decoded_is`` and
    ``laplace_is`` ({ess, ess_fraction, khat}), ``mode`` (21,) and for SMC ``smc_stages``,
    ``smc_acceptance``, ``smc_tempering`` (1 when it reached the target)."""
    data = rec_or_data if isinstance(rec_or_data, LogData) else prepare(rec_or_data)
    key = jax.random.PRNGKey(seed)
    k_is, k_n, k_smc, k_mix, k_h, k_res, k_st, k_lp = jax.random.split(key, 8)
    qv = None if decoded_theta is None else decoded_proposal(decoded_theta, prior)
    qn = nuisance_proposal(data)
    out = {"proposal": "decoded" if qv is not None else "prior"}
    chosen = None
    if qv is not None:
        x = np.concatenate([qv.sample(k_is, draws), qn.sample(k_n, draws)], 1)
        lw, e, kh = _weights(x, qv.log_prob(x[:, :N_V]) + qn.log_prob(x[:, N_V:]), data, prior)
        out["decoded_is"] = {"ess": e, "ess_fraction": e / draws, "khat": kh}
        if e / draws >= MIN_ESS_FRACTION and kh <= MAX_KHAT and not force_smc:
            chosen = ("decoded_is", x, lw)
    # starting points of the optimiser: the decoded samples' v (the policy's knowledge), prior draws
    n_dec = 0 if qv is None else starts // 2
    sv = [prior.sample_v(k_st, starts - n_dec)]
    if n_dec:
        sv.insert(0, qv.sample(k_st, n_dec) if decoded_theta is None else
                  np.asarray(visible_from_theta(np.asarray(decoded_theta)[:n_dec]), np.float32))
    sv = np.concatenate(sv)
    sn = np.broadcast_to(qn.mean, (len(sv), len(qn.mean)))
    x_lin = linear_start(data)
    st = np.concatenate([x_lin[None], np.concatenate([sv, sn], 1)[:starts - 1]]).astype(np.float32)
    lap, mode, _ = laplace_proposal(data, st, prior)
    out["mode"] = mode
    if chosen is None and lap is not None:
        x = lap.sample(k_lp, draws)
        lw, e, kh = _weights(x, lap.log_prob(x), data, prior)
        out["laplace_is"] = {"ess": e, "ess_fraction": e / draws, "khat": kh}
        if e / draws >= MIN_ESS_FRACTION and kh <= MAX_KHAT and not force_smc:
            chosen = ("laplace_is", x, lw)
    if chosen is not None:
        name, x, lw = chosen
        w = np.exp(lw - lw.max())
        idx = np.asarray(jax.random.choice(k_res, len(x), (samples,), p=jnp.asarray(w / w.sum())))
        xs = x[idx]
        out["method"] = name
    else:
        share = PRIOR_SHARE if qv is not None or lap is not None else 1.0
        n_prior = int(round(share * particles))
        xv = [prior.sample_v(k_mix, n_prior)]
        rest = particles - n_prior
        if lap is not None:
            n_lap = rest if qv is None else rest // 2
            xl = lap.sample(k_lp, n_lap)
            xv.append(xl[:, :N_V])
            rest -= n_lap
        if rest:
            xv.append(qv.sample(k_is, rest))
        x0 = np.concatenate([np.concatenate(xv), qn.sample(k_n, particles)], 1).astype(np.float32)
        qs = qv if qv is not None else None
        parts, wts, lam, n, acc = _smc(k_smc, jnp.asarray(x0), data, None if qs is None else qs.mean,
                                       None if qs is None else qs.chol, qn.mean, qn.chol, prior, n_mcmc,
                                       max_stages, float(share), 0.5,
                                       None if lap is None else lap.mean, None if lap is None else lap.chol)
        wts = np.asarray(wts, np.float64)
        idx = np.asarray(jax.random.choice(k_res, particles, (samples,), p=jnp.asarray(wts / wts.sum())))
        xs = np.asarray(parts)[idx]
        out.update(method="smc", smc_stages=int(n), smc_acceptance=float(acc), smc_tempering=float(lam))
    v, nuis = xs[:, :N_V], xs[:, N_V:]
    h = prior.sample_h(k_h, samples)
    out.update(v=v, nuisance=nuis, theta=np.asarray(theta_from(v, h), np.float32))
    return out


def visible_truth(theta):
    """The visible and hidden coordinates of a known θ (19,) -> (v (12,), h (7,))."""
    return np.asarray(visible_from_theta(theta)), np.asarray(hidden_from_theta(theta))


__all__ = ["log_grounded_posterior", "log_target", "decoded_proposal", "pareto_khat", "ess", "N_NUIS"]
