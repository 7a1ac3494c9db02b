"""The log-grounded posterior's tempered SMC (step 2 of :mod:`.inference`): blackjax's adaptive
tempered SMC from a mixture of the prior and the proposals to the target, random-walk moves scaled by
the particles' covariance and tuned to an acceptance rate; one log, or vmapped over logs."""
from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify.coords import PhysicalPrior
from mjxsysid.identify.target import _log_target_y
from mjxsysid.identify.smalllinalg import cholesky


PRIOR_SHARE = 0.3
"""Share of the prior in the SMC's starting mixture (the rest: the decoded and Laplace proposals)."""


def _mixture_log_prob(y, qv, qn, lap, prior: PhysicalPrior, share: float):
    """log density of the SMC's starting mixture over y (17,): ``share`` prior (v; the nuisances from
    ``qn``), the rest split between the decoded proposal ``qv`` (with ``qn``) and ``lap``."""
    lo, hi = prior.v_bounds()
    vol = float(np.sum(np.log(hi - lo)))   # the box's volume (the truncation only adds a constant)
    comps = [jnp.log(share) + jnp.where(prior.v_valid(y[..., L.Y_V]), -vol, -jnp.inf) + qn.log_prob(y[..., L.Y_NUIS])]
    k = (qv is not None) + (lap is not None)
    if qv is not None:
        comps.append(jnp.log((1 - share) / k) + qv.log_prob(y[..., L.Y_V]) + qn.log_prob(y[..., L.Y_NUIS]))
    if lap is not None:
        comps.append(jnp.log((1 - share) / k) + lap.log_prob(y))
    out = comps[0]
    for c in comps[1:]:
        out = jnp.logaddexp(out, c)
    return out


def _smc_impl(key, y0, data, ld, w, qv, qn, lap, prior, n_mcmc, max_stages, share, target_ess):
    """The tempered SMC of one log from its particles y0 (P, 17) -> (particles, weights, λ, stages,
    mean acceptance, lowest stage's acceptance)."""
    import blackjax
    from blackjax.mcmc.random_walk import build_additive_step, normal
    from blackjax.smc.base import extend_params

    def logq(y):
        return _mixture_log_prob(y, qv, qn, lap, prior, share)

    def logrest(y):   # target / q: what the tempering brings in
        lt = _log_target_y(y, data, ld, w, prior)
        return jnp.where(jnp.isfinite(lt), lt - logq(y), -1e30)

    rw = build_additive_step()

    def step(rng, state, logdensity_fn, chol):
        return rw(rng, state, logdensity_fn, normal(chol))

    dim = y0.shape[1]

    def chol_of(p):
        return 2.38 / jnp.sqrt(dim) * cholesky(jnp.cov(p.T) + 1e-8 * jnp.eye(dim))

    smc = blackjax.inner_kernel_tuning(
        smc_algorithm=blackjax.adaptive_tempered_smc, logprior_fn=logq, loglikelihood_fn=logrest,
        mcmc_step_fn=step, mcmc_init_fn=blackjax.rmh.init, resampling_fn=blackjax.smc.resampling.systematic,
        mcmc_parameter_update_fn=lambda _k, state, _i: extend_params({"chol": chol_of(state.particles)}),
        initial_parameter_value=extend_params({"chol": chol_of(y0)}), num_mcmc_steps=n_mcmc, target_ess=target_ess)

    def cond(c):
        return (c[0].sampler_state.tempering_param < 1.0) & (c[1] < max_stages)

    def body(c):
        s, i, k, acc, log_scale, acc_min = c
        k, sub = jax.random.split(k)
        s = s._replace(parameter_override={"chol": s.parameter_override["chol"] * jnp.exp(log_scale)})
        s, info = smc.step(sub, s)
        a = jnp.mean(info.update_info.is_accepted)
        return s, i + 1, k, acc + a, log_scale + rw_scale_update(a), jnp.minimum(acc_min, a)

    state, n, _, acc, _, acc_min = jax.lax.while_loop(
        cond, body, (smc.init(y0), 0, key, 0.0, jnp.float32(0.0), jnp.float32(1.0)))
    st = state.sampler_state
    return st.particles, st.weights, st.tempering_param, n, acc / jnp.maximum(n, 1), acc_min


def _smc_logs(key, y0, data, ld, w, qv, qn, lap, prior, n_mcmc, max_stages, share, target_ess):
    """:func:`_smc_impl` vmapped over logs (every argument but the static ones with a leading log axis)."""
    def one(k, y, d, a, b, q1, q2, q3):
        return _smc_impl(k, y, d, a, b, q1, q2, q3, prior, n_mcmc, max_stages, share, target_ess)
    return jax.vmap(one)(key, y0, data, ld, w, qv, qn, lap)


def program(logs: bool, prior: PhysicalPrior, n_mcmc: int, max_stages: int, share: float = PRIOR_SHARE,
            target_ess: float = 0.5) -> tuple:
    """The SMC's (name, function, static arguments) for :func:`mjxsysid.runtime.exported.call`: one log's
    (:func:`_smc_impl`), or with ``logs`` every log's of a batch (:func:`_smc_logs`). Exported, a later process
    loads its trace (blackjax's tempered SMC: 2.6-3.3 s of a warm ``decode --log`` on 2 cores) from disk."""
    static = {"prior": prior, "n_mcmc": int(n_mcmc), "max_stages": int(max_stages), "share": float(share),
              "target_ess": float(target_ess)}
    return ("smc_logs", _smc_logs, static) if logs else ("smc", _smc_impl, static)


RW_TARGET_ACCEPTANCE = 0.25
"""The SMC's random-walk moves aim at this acceptance rate (about the optimum for a Gaussian
target, 0.234). Scaled by the particles' covariance alone (2.38/√d · chol Σ), they are accepted
0–0.6 % of the time once the likelihood enters (a 10 s log: 15 stages, from the sixth on): 24
moves then leave most particles where resampling copied them, and the posterior is the
spread of a few ancestors — the bands too narrow."""


def rw_scale_update(acceptance):
    """The change of the random walk's log scale after a stage with this acceptance rate:
    ½ log((a + 0.005) / target), within log 0.2 … log 2 (a stage at 0.5 % shrinks the steps
    five-fold; one at 90 % doubles them)."""
    r = 0.5 * jnp.log((acceptance + 0.005) / RW_TARGET_ACCEPTANCE)
    return jnp.clip(r, jnp.log(0.2), jnp.log(2.0))


def _smc_start(prior, qv, qn, lap, particles, r_mix, r_n, r_lp, r_is) -> np.ndarray:
    """The SMC's starting particles (particles, 17): :data:`PRIOR_SHARE` from the prior, the rest
    split between the Laplace and the decoded proposals."""
    n_prior = int(round(PRIOR_SHARE * particles))
    parts = [np.concatenate([prior.sample_v(r_mix, n_prior), qn.sample(r_n, n_prior)], 1)]
    rest = particles - n_prior
    n_lap = rest if qv is None else rest // 2
    parts.append(lap.sample(r_lp, n_lap))
    if rest - n_lap:
        parts.append(np.concatenate([qv.sample(r_is, rest - n_lap), qn.sample(r_n, rest - n_lap)], 1))
    return np.concatenate(parts).astype(np.float32)
