"""The log-grounded posterior: the stated physical prior × the log's likelihood, with the decoded
ensemble as the proposal and a tempered SMC where it misses.

Target: p(v) p(σ, bias) p(log | v, σ, bias; δ, w) (:mod:`.coords`, :mod:`.likelihood`), 17-d: the
visible coordinates v (12), the IMU noise σ per channel (4) and the accelerometer bias. The
discrepancy δ per channel and the weights w that discount correlated residuals
(:func:`~.likelihood.residual_weights`) are set at the joint mode (empirical Bayes: both are
properties of the log and the model, not of the vehicle, and δ's flat direction below the log's
resolution would otherwise spoil every proposal). The hidden coordinates h are independent of the
log, so θ = θ(v, h) with h drawn from the prior.

0. **The mode.** Levenberg–Marquardt (optimistix) on the standardised residuals from a linear
   least-squares start (at fixed τ_m the rate changes are linear in authority × ρ), from the
   decoded samples and from prior draws, δ re-set from the best fit's residuals between rounds;
   then the correlation discounts w, and a Gauss–Newton precision of the tempered Student-t
   residuals there (the Laplace proposal, a Student-t).
1. **Importance sampling from the decoders.** The decoded samples θ (S, 19) mapped to v are
   fitted by a Gaussian (widened by :data:`~.proposals.PROPOSAL_WIDEN`), the nuisances' proposal centred on
   the log's own noise estimate; N draws are weighted by target / proposal. Reported: the
   effective sample size and Pareto k̂ of the weights' upper tail (Vehtari et al., PSIS; the
   generalised-Pareto fit is scipy's). The decoded density is the proposal only, never a factor
   of the target: the latent came from the same log. Then from the Laplace proposal, likewise.
2. **Tempered SMC** (blackjax's adaptive tempered SMC, random-walk Metropolis moves whose
   covariance is the particles', re-estimated each stage) when the weights are unreliable
   (ESS < :data:`MIN_ESS_FRACTION` N or k̂ > :data:`MAX_KHAT`): from a mixture of the prior
   (:data:`PRIOR_SHARE`), the decoded and the Laplace proposals, tempered to the target (the path
   q^{1−λ} target^{λ}).
"""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify.calibrate import SHIPPED, calibrate, load, log_features
from mjxsysid.identify.coords import (
    N_V,
    PHYSICAL_PRIOR,
    PhysicalPrior,
    theta_from,
    visible_from_theta,
    xp_of,
)
from mjxsysid.identify.likelihood import (
    N_NUIS,
    NU,
    best_log_delta,
    drag_at,
    linear_start,
    log_likelihood,
    rate_rows,
    residual_weights,
    residuals,
    residuals_jit,
)
from mjxsysid.identify.logdata import RATES, LogData, prepare
from mjxsysid.identify.proposals import StudentT, decoded_proposal, ess, nuisance_proposal, pareto_khat

MIN_ESS_FRACTION = 0.05
MAX_KHAT = 0.7
"""Importance sampling is trusted when ESS ≥ 5 % of the draws and k̂ ≤ 0.7 (PSIS's threshold)."""
DRAWS = 4096
"""Importance draws per proposal (``draws`` of :func:`log_grounded_posterior` when not given)."""
PARTICLES = 2048
"""SMC particles (``particles`` of :func:`log_grounded_posterior` when not given). The test tier
lowers both for its in-process decodes (tests/conftest.py): it checks behaviour, not resolution."""
PRIOR_SHARE = 0.3
"""Share of the prior in the SMC's starting mixture (the rest: the decoded and Laplace proposals)."""
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


N_Y = N_V + 5
"""The sampled coordinates: v (12), log σ (4), acc_z bias."""


def _nuis_lo_hi():
    a, b, c, d, e, f = NUIS_BOUNDS
    return np.array([a] * 4 + [c] * 4 + [e]), np.array([b] * 4 + [d] * 4 + [f])


def _y_lo_hi(prior):
    lo, hi = prior.v_bounds()
    nlo, nhi = _nuis_lo_hi()
    return np.concatenate([lo, nlo[:4], nlo[8:]]), np.concatenate([hi, nhi[:4], nhi[8:]])


def full_x(y, log_delta):
    """y (..., 17) and log δ (4,) -> x (..., 21) = [v, log σ, log δ, bias]."""
    xp = xp_of(y)
    y = xp.asarray(y)
    ld = xp.broadcast_to(xp.asarray(log_delta, y.dtype), y.shape[:-1] + (4,))
    return xp.concatenate([y[..., :N_V + 4], ld, y[..., N_V + 4:]], -1)



def log_prior(x, prior: PhysicalPrior = PHYSICAL_PRIOR):
    """log p(x) up to a constant, x (21,) = [v, log σ, log δ, bias]: the physical prior, uniform
    nuisances, the bias N(0, :data:`ACC_BIAS_SD`²)."""
    lo, hi = _nuis_lo_hi()
    n = x[N_V:]
    ok = jnp.all((n >= lo) & (n <= hi))
    return prior.log_prob_v(x[:N_V]) + jnp.where(ok, 0.0, -jnp.inf) - 0.5 * (x[-1] / ACC_BIAS_SD) ** 2


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
    ld = np.full(4, np.log(1e-4), np.float32) if log_delta is None else jnp.asarray(log_delta, jnp.float32)
    w = np.ones(4, np.float32) if weights is None else jnp.asarray(weights, jnp.float32)
    y = np.asarray(y, np.float32)
    n = len(y)
    pad = -n % TARGET_CHUNK
    yp = np.concatenate([y, np.broadcast_to(y[:1], (pad, y.shape[1]))]) if pad else y
    out = [np.asarray(_batch_log_target(jnp.asarray(yp[i:i + TARGET_CHUNK]), data, ld, w, prior))
           for i in range(0, len(yp), TARGET_CHUNK)]
    return np.concatenate(out)[:n]


def _project(x, prior):
    """Optima (K, 21) into the prior's support: the box, and J's triangle inequality
    (A_z no smaller than 1 / (1/A_x + 1/A_y))."""
    lo, hi = prior.v_bounds()
    nlo, nhi = _nuis_lo_hi()
    lo, hi = np.concatenate([lo, nlo]), np.concatenate([hi, nhi])
    eps = 1e-4 * (hi - lo)
    x = np.clip(np.asarray(x, np.float64), lo + eps, hi - eps)
    x[:, 7] = np.maximum(x[:, 7], -np.log(np.exp(-x[:, 5]) + np.exp(-x[:, 6])) + 1e-4)
    r4 = 4.0 - x[:, 1:4].sum(1)
    bad = (r4 < prior.rel_eff[0]) | (r4 > prior.rel_eff[1])
    x[bad, 1:4] = 1.0
    return x.astype(np.float32)


def _ls_residuals(z, args):
    """Standardised residuals for the least-squares stage: z (13,) = [v, bias], σ fixed in ``args``."""
    data, ld, ls = args
    x = jnp.concatenate([z[:N_V], ls, ld, z[N_V:]])
    rg, sg, ra, sa = residuals(x, data)
    u = data.use
    return jnp.concatenate([(rg * (u[:3] / sg)).ravel(), ra * (u[3] / sa), z[N_V:] / ACC_BIAS_SD])


@functools.partial(jax.jit, static_argnames=("max_steps",))
def _fit_ls(z0, data, ld, ls, max_steps=200):
    """Levenberg–Marquardt (optimistix) on the standardised residuals from one start (13,)."""
    import optimistix as optx
    solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)
    return optx.least_squares(_ls_residuals, solver, z0, args=(data, ld, ls), max_steps=max_steps, throw=False).value


@functools.partial(jax.jit, static_argnames=("max_steps",))
def _fit_ls_batched(z0, data, ld, ls, max_steps=200):
    """:func:`_fit_ls` from every start (K, 13) at once (vmapped)."""
    return jax.vmap(lambda z: _fit_ls(z, data, ld, ls, max_steps=max_steps))(z0)


def _fit_ls_many(z0, data, ld, ls, max_steps=200):
    """:func:`_fit_ls` from each start (K, 13): on a CPU one after the other — the batched solver's
    trace compiles in twice the time (about 4 s against 2 s on a core, a first decode's largest
    program) and runs until its slowest start has converged; on an accelerator batched, where one
    start at a time is bound by kernel launches (a calibration of 96 logs on an H100: 561 s one at
    a time against 388 s batched)."""
    if jax.default_backend() != "cpu":
        return _fit_ls_batched(jnp.asarray(z0), data, ld, ls, max_steps=max_steps)
    return jnp.stack([_fit_ls(z, data, ld, ls, max_steps=max_steps) for z in np.asarray(z0, np.float32)])


@jax.jit
def _ls_jacobian(z, args, w):
    """Jacobian of the standardised residuals, each channel's × √w (the tempering), at z (13,)."""
    data = args[0]
    nw = rate_rows(data)
    sw = jnp.concatenate([jnp.repeat(jnp.sqrt(w[None, :3]), nw, 0).ravel(), jnp.full(data.acc.shape[0], jnp.sqrt(w[3])),
                          jnp.ones(1)])
    return jax.jacfwd(lambda q: _ls_residuals(q, args) * sw)(z)


def _discrepancy(y, data):
    """δ per channel (4,) at y (17,): what the residuals' mean square leaves beyond the scale they
    have without a discrepancy (noise, resolution, the windows' floor; at least 1e-6)."""
    rg, sg, ra, sa = (np.asarray(a, np.float64) for a in residuals_jit(full_x(y, np.full(4, -30.0)), data))
    bv = np.asarray(data.bmask) > 0
    ms_acc = np.mean(ra[bv] ** 2) - sa ** 2
    if data.rates == "innovations":     # the process noise that makes the innovations most likely
        out = np.log(np.sqrt(np.maximum(np.array([1e-12] * 3 + [ms_acc]), 1e-12)))
        out[:3] = best_log_delta(full_x(y, out), data, _DELTA_GRID)
        return out.astype(np.float32)
    wv = np.asarray(data.wmask) > 0
    ms = np.array([np.mean(rg[wv, k] ** 2 - sg[wv, k] ** 2) for k in range(3)] + [ms_acc])
    return np.log(np.sqrt(np.maximum(ms, 1e-12))).astype(np.float32)


_DELTA_GRID = np.linspace(NUIS_BOUNDS[2], NUIS_BOUNDS[3], 64)
"""log δ the innovations' process noise is chosen from at the mode (:func:`_discrepancy`)."""


@full_precision
def find_mode(data: LogData, starts, prior: PhysicalPrior = PHYSICAL_PRIOR, rounds: int = 3):
    """The mode from ``starts`` (K, 21) -> (x* (21,), log δ* (4,), weights (4,), y* (17,), the
    Laplace Student-t at y*). δ and σ are fixed while v and the bias are fitted (Levenberg–Marquardt
    from every start, in later rounds from its previous fit), δ then set from the best fit's
    residuals, ``rounds`` times (δ free in the
    same fit lets a poor start explain the rates as discrepancy and stay there; a Student-t BFGS
    from a good start wandered off in float32); then the correlation discounts w are set."""
    starts = np.asarray(starts, np.float32)
    ys = np.concatenate([starts[:, :N_V + 4], starts[:, N_V + 8:]], 1)
    ld = starts[0, N_V + 4:N_V + 8].astype(np.float32)
    ls = ys[0, N_V:N_V + 4]
    for _ in range(rounds):
        z = np.concatenate([ys[:, :N_V], ys[:, N_V + 4:]], 1)
        z = np.asarray(_fit_ls_many(jnp.asarray(z), data, jnp.asarray(ld), jnp.asarray(ls)))
        fits = np.concatenate([z[:, :N_V], np.broadcast_to(ls, (len(z), 4)), z[:, N_V:]], 1)
        fits = _project(np.asarray(full_x(fits, ld)), prior)
        fits = np.concatenate([fits[:, :N_V + 4], fits[:, N_V + 8:]], 1)
        lt = np.asarray(log_target(fits, data, ld, None, prior))
        best = fits[int(np.argmax(np.where(np.isfinite(lt), lt, -np.inf)))]
        ld = np.clip(_discrepancy(best, data), NUIS_BOUNDS[2], NUIS_BOUNDS[3])
        ys = fits       # every start refitted under the new δ: the same rows each round, one compiled fit
    w = residual_weights(full_x(best, ld), data)
    y = best
    # Gauss–Newton precision of the tempered Student-t residuals at the least-squares mode (Fisher
    # information (ν+1)/(ν+3) per standardised residual); σ's from its second differences (2 n per log σ)
    z = jnp.asarray(np.concatenate([y[:N_V], y[N_V + 4:]]))
    args = (data, jnp.asarray(ld), jnp.asarray(y[N_V:N_V + 4]))
    jac = np.asarray(_ls_jacobian(z, args, jnp.asarray(w)), np.float64)
    pz = (NU + 1) / (NU + 3) * jac.T @ jac
    h = np.zeros((N_Y, N_Y))
    iz = np.r_[0:N_V, N_V + 4]
    h[np.ix_(iz, iz)] = pz
    h[N_V:N_V + 4, N_V:N_V + 4] = np.diag(2.0 * np.asarray(data.n2, np.float64))
    h = np.nan_to_num(0.5 * (h + h.T), nan=0.0, posinf=1e12, neginf=-1e12)
    ev, u = np.linalg.eigh(h)
    ev = np.clip(ev, 1e-9 + 1e-9 * max(ev.max(), 1e-12), None)      # flat directions: broad, not infinite
    lo, hi = _y_lo_hi(prior)
    prec = (u * ev) @ u.T + np.diag(1.0 / ((hi - lo) / 2) ** 2)        # no wider than the prior's box
    cov = np.linalg.inv(prec)
    lap = StudentT(y.astype(np.float32), (np.linalg.cholesky(0.5 * (cov + cov.T)) * LAPLACE_WIDEN).astype(np.float32))
    return np.asarray(full_x(jnp.asarray(y)[None], ld))[0], ld, w, y, lap


LAPLACE_WIDEN = 2.0
"""The Laplace Student-t's scale is the inverse Hessian's × this (a defensive proposal; with 1.2
and 8 moves per stage the SMC ended under-dispersed on clean logs: 8 MJX flights' 90 % coverage
0.38–0.62, against 0.38–0.88 with 2.0 and 24 moves)."""


def _mixture_log_prob(y, qv, qn, lap, prior: PhysicalPrior, share: float):
    """log density of the SMC's starting mixture over y (17,): ``share`` prior (v; the nuisances from
    ``qn``), the rest split between the decoded proposal ``qv`` (with ``qn``) and ``lap``."""
    lo, hi = prior.v_bounds()
    vol = float(np.sum(np.log(hi - lo)))   # the box's volume (the truncation only adds a constant)
    comps = [jnp.log(share) + jnp.where(prior.v_valid(y[..., :N_V]), -vol, -jnp.inf) + qn.log_prob(y[..., N_V:])]
    k = (qv is not None) + (lap is not None)
    if qv is not None:
        comps.append(jnp.log((1 - share) / k) + qv.log_prob(y[..., :N_V]) + qn.log_prob(y[..., N_V:]))
    if lap is not None:
        comps.append(jnp.log((1 - share) / k) + lap.log_prob(y))
    out = comps[0]
    for c in comps[1:]:
        out = jnp.logaddexp(out, c)
    return out


@functools.partial(jax.jit, static_argnames=("prior", "n_mcmc", "max_stages", "share", "target_ess"))
def _smc(key, y0, data, ld, w, qv, qn, lap, prior, n_mcmc, max_stages, share, target_ess):
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
        return 2.38 / jnp.sqrt(dim) * jnp.linalg.cholesky(jnp.cov(p.T) + 1e-8 * jnp.eye(dim))

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


def _is(x, logq, data, ld, w, prior):
    lw = np.asarray(log_target(x, data, ld, w, prior), np.float64) - np.asarray(logq, np.float64)
    e = ess(lw)
    return lw, {"ess": e, "draws": len(x), "ess_fraction": e / len(x), "khat": pareto_khat(lw)}


def _reliable(diag) -> bool:
    return diag["ess_fraction"] >= MIN_ESS_FRACTION and diag["khat"] <= MAX_KHAT


@full_precision
def log_grounded_posterior(rec_or_data, decoded_theta=None, *, prior: PhysicalPrior = PHYSICAL_PRIOR,
                           samples: int = 1000, draws: int | None = None, particles: int | None = None, seed: int = 0,
                           n_mcmc: int = 24, max_stages: int = 200, starts: int = 12,
                           force_smc: bool = False, rates: str | None = None, calibration="shipped") -> dict:
    """The posterior of a flight log (``rec_or_data``: the arrays of ``read_log`` or a
    :class:`LogData`) under the physical ``prior``, with ``decoded_theta`` (S, 19) — the decoders'
    samples of this log, or None — as the proposal (module doc). ``draws`` / ``particles`` default to
    :data:`DRAWS` / :data:`PARTICLES`; ``rates``: the likelihood's rate term, "windows" or "innovations"
    (default :data:`~.logdata.RATES`; a :class:`LogData` carries its own).

    -> dict: ``theta`` (samples, 19) (hidden coordinates drawn from the prior), ``v`` (samples, 12),
    ``nuisance`` (samples, 9: log σ (4), log δ (4, fixed), bias), ``method`` ('decoded_is',
    'laplace_is' or 'smc'), ``decoded_is`` / ``laplace_is`` ({ess, ess_fraction, khat}),
    ``weights`` (4,) the channels' correlation discounts, ``mode`` (21,), ``channels_used`` (4,),
    and for SMC ``smc_stages``, ``smc_acceptance`` (the moves' acceptance rate, mean over the stages),
    ``smc_acceptance_min`` (the lowest stage's), ``smc_tempering`` (1 when it reached the target).

    ``calibration``: "shipped" (default: the table fitted on simulated logs,
    :mod:`.calibrate`), a table (dict) or a path to one, or None for the raw posterior. The draws
    ``v`` / ``theta`` are the calibrated ones; ``v_raw`` the raw ones; ``features`` what the log
    shows; ``calibration`` the report (scale factor and bin per coordinate, the model check,
    ``seen`` (12,) and ``why`` (12,) per visible coordinate, ``table`` the file it came from)."""
    draws = DRAWS if draws is None else int(draws)
    particles = PARTICLES if particles is None else int(particles)
    data = rec_or_data if isinstance(rec_or_data, LogData) else prepare(rec_or_data, rates=RATES if rates is None else rates)
    # host draws from NumPy generators (they compile nothing); the SMC's key is PRNGKey(seed)'s bits
    r_is, r_n, r_mix, r_h, r_res, r_st, r_lp = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(7))
    k_smc = np.array([0, seed & 0xFFFFFFFF], np.uint32)
    qv = None if decoded_theta is None else decoded_proposal(decoded_theta, prior)
    qn = nuisance_proposal(data, ACC_BIAS_SD)
    # 0. the mode from ``starts`` starting points (always as many: one compiled fit): a linear
    # start, the decoded samples, prior draws
    x_lin = linear_start(data)
    sv = [prior.sample_v(r_st, max(starts // 3, 1))]
    if decoded_theta is not None:
        dv = np.asarray(visible_from_theta(np.asarray(decoded_theta, np.float32)), np.float32)
        dv = dv[np.all(np.isfinite(dv), 1) & np.asarray(prior.v_valid(dv))][: starts - len(sv[0]) - 1]
        sv.append(dv)
    n_fill = max(starts - 1 - sum(len(a) for a in sv), 0)
    if n_fill:
        sv.append(prior.sample_v(r_st, n_fill))
    sv = np.concatenate(sv)
    st = np.concatenate([x_lin[None], np.concatenate([sv, np.broadcast_to(x_lin[N_V:], (len(sv), N_NUIS))], 1)])
    mode, ld, w, _, lap = find_mode(data, st.astype(np.float32), prior)
    out = {"proposal": "decoded" if qv is not None else "prior", "mode": mode, "weights": w,
           "channels_used": np.asarray(data.use), "rates": data.rates}
    chosen = None
    # 1. the decoded ensemble as the proposal
    if qv is not None:
        y = np.concatenate([qv.sample(r_is, draws), qn.sample(r_n, draws)], 1)
        lw, out["decoded_is"] = _is(y, qv.log_prob(y[:, :N_V]) + qn.log_prob(y[:, N_V:]), data, ld, w, prior)
        if _reliable(out["decoded_is"]) and not force_smc:
            chosen = ("decoded_is", y, lw)
    if chosen is None:
        y = lap.sample(r_lp, draws)
        lw, out["laplace_is"] = _is(y, lap.log_prob(y), data, ld, w, prior)
        if _reliable(out["laplace_is"]) and not force_smc:
            chosen = ("laplace_is", y, lw)
    if chosen is not None:
        name, y, lw = chosen
        p = np.exp(lw - lw.max())
        idx = r_res.choice(len(y), samples, p=p / p.sum())
        ys = y[idx]
        out["method"] = name
    else:   # 2. tempered SMC from a mixture of the proposals and the prior
        n_prior = int(round(PRIOR_SHARE * particles))
        parts = [np.concatenate([prior.sample_v(r_mix, n_prior), qn.sample(r_n, n_prior)], 1)]
        rest = particles - n_prior
        n_lap = rest if qv is None else rest // 2
        parts.append(lap.sample(r_lp, n_lap))
        if rest - n_lap:
            parts.append(np.concatenate([qv.sample(r_is, rest - n_lap), qn.sample(r_n, rest - n_lap)], 1))
        y0 = jnp.asarray(np.concatenate(parts), jnp.float32)
        pts, wts, lam, n, acc, acc_min = _smc(k_smc, y0, data, jnp.asarray(ld), jnp.asarray(w), qv, qn, lap,
                                              prior, n_mcmc, max_stages, float(PRIOR_SHARE), 0.5)
        wts = np.asarray(wts, np.float64)
        idx = r_res.choice(particles, samples, p=wts / wts.sum())
        ys = np.asarray(pts)[idx]
        out.update(method="smc", smc_stages=int(n), smc_acceptance=float(acc), smc_acceptance_min=float(acc_min),
                   smc_tempering=float(lam))
    xs = np.asarray(full_x(ys, ld))
    v_raw = xs[:, :N_V]
    out["features"] = log_features(data, mode)
    if out["features"]["velocity_used"]:     # (3,) 1/s: x and y from the accelerometer's x and y, z from its term
        xy = getattr(data, "_rows", {}).get("drag_xy")
        out["drag_per_mass"] = [*(xy.tolist() if xy is not None else [None, None]), drag_at(mode, data)]
    else:
        out["drag_per_mass"] = None
    v, out["calibration"] = _calibrated(v_raw, out["features"], w, calibration, prior, seed)
    h = prior.sample_h(r_h, samples)
    out.update(v=v, v_raw=v_raw, nuisance=xs[:, N_V:], theta=np.asarray(theta_from(v, h), np.float32))
    return out


def _calibrated(v_raw, features, weights, calibration, prior, seed):
    """The raw draws through the calibration table (``calibration``: "shipped", a dict, a path or
    None) -> (draws (S, 12), report)."""
    if calibration is None:
        return v_raw, {"applied": False, "why": "calibration=None: the raw posterior"}
    table = load() if calibration == "shipped" else calibration if isinstance(calibration, dict) else load(calibration)
    v, rep = calibrate(v_raw, features, weights, table, prior, rng=seed)
    rep.update(applied=True, table=str(SHIPPED) if calibration == "shipped" else
               (str(calibration) if not isinstance(calibration, dict) else "a table given in Python"))
    return v, rep
