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
import os

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify.calibrate import SHIPPED, calibrate, load, log_features
from mjxsysid.identify.coords import (
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
from mjxsysid.identify.logdata import RATES, LogData, LogTooShort, prepare
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


def _project(x, prior):
    """Optima (K, 21) into the prior's support: the box, and J's triangle inequality
    (A_z no smaller than 1 / (1/A_x + 1/A_y))."""
    lo, hi = prior.v_bounds()
    nlo, nhi = _nuis_lo_hi()
    lo, hi = np.concatenate([lo, nlo]), np.concatenate([hi, nhi])
    eps = 1e-4 * (hi - lo)
    x = np.clip(np.asarray(x, np.float64), lo + eps, hi - eps)
    x[:, L.LOG_AUTH_Z] = np.maximum(x[:, L.LOG_AUTH_Z],
                                    -np.log(np.exp(-x[:, L.LOG_AUTH_X]) + np.exp(-x[:, L.LOG_AUTH_Y])) + 1e-4)
    r4 = 4.0 - x[:, L.RHO].sum(1)
    bad = (r4 < prior.rel_eff[0]) | (r4 > prior.rel_eff[1])
    x[bad, L.RHO] = 1.0
    return x.astype(np.float32)


def _ls_residuals(z, args):
    """Standardised residuals for the least-squares stage: z (13,) = [v, bias], σ fixed in ``args``."""
    data, ld, ls = args
    x = L.x_from_y(L.y_from_z(z, ls), ld)
    rg, sg, ra, sa = residuals(x, data)
    u = data.use
    return jnp.concatenate([(rg * (u[L.GYRO] / sg)).ravel(), ra * (u[L.ACC_Z] / sa), z[L.Z_BIAS, None] / ACC_BIAS_SD])


@functools.partial(jax.jit, static_argnames=("max_steps", "normal"))
def _fit_ls(z0, data, ld, ls, max_steps=200, normal=False):
    """Levenberg–Marquardt (optimistix) on the standardised residuals from one start (13,).
    ``normal``: each step's damped least squares by its normal equations (lineax's Cholesky of a
    13 × 13 matrix) instead of a QR of the residuals' Jacobian: the same fits (on a 4 s log, the
    same residual sums to 1e-6), and under a vmap over many logs on a GPU, where batched QR runs
    one matrix after the other, about 50× faster."""
    import optimistix as optx
    if normal:
        import lineax as lx
        solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8, linear_solver=lx.Normal(lx.Cholesky()))
    else:
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
    sw = jnp.concatenate([jnp.repeat(jnp.sqrt(w[None, L.GYRO]), nw, 0).ravel(),
                          jnp.full(data.acc.shape[0], jnp.sqrt(w[L.ACC_Z])),
                          jnp.ones(1)])
    return jax.jacfwd(lambda q: _ls_residuals(q, args) * sw)(z)


@functools.partial(jax.jit, static_argnames=("max_steps",))
def _fit_ls_logs(z0, data, ld, ls, max_steps=200):
    """:func:`_fit_ls` (by the normal equations) from every start of every log at once: z0 (L, K,
    13), data / ld / ls with a leading log axis -> (L, K, 13)."""
    def one(z, d, a, b):
        return jax.vmap(lambda q: _fit_ls(q, d, a, b, max_steps=max_steps, normal=True))(z)
    return jax.vmap(one)(z0, data, ld, ls)


@jax.jit
def _ls_jacobian_logs(z, data, ld, ls, w):
    """:func:`_ls_jacobian` of every log at z (L, 13) -> (L, R, 13)."""
    return jax.vmap(lambda q, d, a, b, c: _ls_jacobian(q, (d, a, b), c))(z, data, ld, ls, w)


def _discrepancy(y, data):
    """δ per channel (4,) at y (17,): what the residuals' mean square leaves beyond the scale they
    have without a discrepancy (noise, resolution, the windows' floor; at least 1e-6)."""
    rg, sg, ra, sa = (np.asarray(a, np.float64) for a in residuals_jit(full_x(y, np.full(L.N_CHANNELS, -30.0)), data))
    bv = np.asarray(data.bmask) > 0
    ms_acc = np.mean(ra[bv] ** 2) - sa ** 2
    if data.rates == "innovations":     # the process noise that makes the innovations most likely
        out = np.log(np.sqrt(np.maximum(np.array([1e-12] * 3 + [ms_acc]), 1e-12)))
        out[L.GYRO] = best_log_delta(full_x(y, out), data, _DELTA_GRID)
        return out.astype(np.float32)
    wv = np.asarray(data.wmask) > 0
    ms = np.array([np.mean(rg[wv, k] ** 2 - sg[wv, k] ** 2) for k in range(3)] + [ms_acc])
    return np.log(np.sqrt(np.maximum(ms, 1e-12))).astype(np.float32)


_DELTA_GRID = np.linspace(NUIS_BOUNDS[2], NUIS_BOUNDS[3], 64)
"""log δ the innovations' process noise is chosen from at the mode (:func:`_discrepancy`)."""


def _take(tree, idx):
    """The logs ``idx`` of a stacked pytree (leading axis: the log)."""
    idx = np.asarray(idx)
    return jax.tree.map(lambda a: a[idx], tree)


def _pow2_pad(idx):
    """Indices padded to the next power of two by repeating the first: a subset of a batch takes
    one of a few compiled shapes, not one per size."""
    idx = list(idx)
    n = 1 << int(np.ceil(np.log2(max(len(idx), 1))))
    return np.asarray(idx + [idx[0]] * (n - len(idx)))


def _pad_rows(a, n: int) -> np.ndarray:
    """``a`` (m, ...) padded to n rows by repeating its first (the rows of :func:`_pow2_pad`)."""
    a = np.asarray(a, np.float32)
    return np.concatenate([a, np.broadcast_to(a[:1], (n - len(a),) + a.shape[1:])]) if n > len(a) else a  # rows, not coordinates


class _Logs:
    """Logs of one shape (their :class:`LogData` pytrees' leaves alike) evaluated together.

    One log runs the single-log programs (on a CPU the starts one after the other, see
    :func:`_fit_ls_many`); several run programs vmapped over a leading log axis (:data:`LOG_BATCH`),
    the logs (or a subset of them) padded to a power of two (:func:`_pow2_pad`): a batch's last,
    shorter chunk reuses the programs the full ones compiled."""

    def __init__(self, datas):
        self.datas = list(datas)
        self.stack = jax.tree.map(lambda *a: jnp.asarray(np.stack(a)), *self.datas) if len(self.datas) > 1 else None

    def __len__(self):
        return len(self.datas)

    def _sub(self, idx):
        p = _pow2_pad(idx)
        return p, _take(self.stack, p)

    def targets(self, y, ld, w, prior, idx=None):
        """log target of y (m, N, 17) for the logs ``idx`` (m,) (default all), each with its log δ
        (m, 4) and weights (m, 4) (None: 1) -> (m, N)."""
        idx = list(range(len(self))) if idx is None else list(idx)
        w = np.ones((len(idx), L.N_CHANNELS), np.float32) if w is None else np.asarray(w, np.float32)
        if self.stack is None:
            return np.asarray(log_target(y[0], self.datas[idx[0]], ld[0], w[0], prior))[None]  # rows, not coordinates
        p, data = self._sub(idx)
        pad = len(p) - len(idx)
        y, ld, w = (np.concatenate([a, np.broadcast_to(a[:1], (pad,) + a.shape[1:])]) if pad else a
                    for a in (np.asarray(y, np.float32), np.asarray(ld, np.float32), w))
        n = y.shape[1]
        chunk = max(16, TARGET_EVALS // len(p))
        padn = -n % chunk
        if padn:
            y = np.concatenate([y, np.broadcast_to(y[:, :1], (len(p), padn, y.shape[2]))], 1)  # rows, not coordinates
        out = [np.asarray(_batch_log_target_logs(jnp.asarray(y[:, i:i + chunk]), data, jnp.asarray(ld), jnp.asarray(w), prior))
               for i in range(0, y.shape[1], chunk)]
        return np.concatenate(out, 1)[:len(idx), :n]

    def fit(self, z, ld, ls):
        """Levenberg–Marquardt from every start z (L, K, 13) -> (L, K, 13)."""
        if self.stack is None:
            z0 = z[0]  # rows, not coordinates
            return np.asarray(_fit_ls_many(jnp.asarray(z0), self.datas[0], jnp.asarray(ld[0]), jnp.asarray(ls[0])))[None]
        p, data = self._sub(range(len(self)))
        z, ld, ls = (_pad_rows(a, len(p)) for a in (z, ld, ls))
        return np.asarray(_fit_ls_logs(jnp.asarray(z), data, jnp.asarray(ld), jnp.asarray(ls)))[:len(self)]

    def jacobians(self, z, ld, ls, w):
        """The tempered residuals' Jacobians at z (L, 13) -> (L, R, 13)."""
        if self.stack is None:
            z0 = z[0]  # rows, not coordinates
            return np.asarray(_ls_jacobian(jnp.asarray(z0), (self.datas[0], jnp.asarray(ld[0]), jnp.asarray(ls[0])),
                                           jnp.asarray(w[0])))[None]
        p, data = self._sub(range(len(self)))
        z, ld, ls, w = (_pad_rows(a, len(p)) for a in (z, ld, ls, w))
        return np.asarray(_ls_jacobian_logs(jnp.asarray(z), data, jnp.asarray(ld), jnp.asarray(ls), jnp.asarray(w)))[:len(self)]

    def smc(self, idx, keys, y0, ld, w, qv, qn, lap, prior, n_mcmc, max_stages):
        """The tempered SMC of the logs ``idx`` (m,) from their particles y0 (m, P, 17) -> the
        outputs of :func:`_smc`, each with a leading axis m."""
        idx = list(idx)
        args = (np.asarray(keys, np.uint32), np.asarray(y0, np.float32), np.asarray(ld, np.float32), np.asarray(w, np.float32))
        if self.stack is None:
            out = _smc(*(jnp.asarray(a[0]) for a in args[:2]), self.datas[idx[0]], *(jnp.asarray(a[0]) for a in args[2:]),
                       qv[0], qn[0], lap[0], prior, n_mcmc, max_stages, float(PRIOR_SHARE), 0.5)
            return [np.asarray(o)[None] for o in out]
        p, data = self._sub(idx)
        pad = len(p) - len(idx)
        args = [np.concatenate([a, np.broadcast_to(a[:1], (pad,) + a.shape[1:])]) if pad else a for a in args]
        stk = lambda ts: None if ts[0] is None else jax.tree.map(lambda *a: jnp.stack(a), *(ts + [ts[0]] * pad))  # noqa: E731
        out = _smc_logs(*(jnp.asarray(a) for a in args[:2]), data, *(jnp.asarray(a) for a in args[2:]),
                        stk(list(qv)), stk(list(qn)), stk(list(lap)), prior, n_mcmc, max_stages, float(PRIOR_SHARE), 0.5)
        return [np.asarray(o)[:len(idx)] for o in out]


TARGET_EVALS = 4096
"""Evaluations of the target per call when several logs are evaluated together (a batch's draws are
cut into chunks of TARGET_EVALS / logs each)."""


@functools.partial(jax.jit, static_argnames=("prior",))
def _batch_log_target_logs(y, data, log_delta, weights, prior):
    """:func:`_batch_log_target` vmapped over logs: y (L, N, 17) -> (L, N)."""
    return jax.vmap(lambda z, d, a, b: jax.vmap(lambda q: _log_target_y(q, d, a, b, prior))(z))(y, data, log_delta, weights)


@full_precision
def find_mode(data: LogData, starts, prior: PhysicalPrior = PHYSICAL_PRIOR, rounds: int = 3):
    """The mode from ``starts`` (K, 21) -> (x* (21,), log δ* (4,), weights (4,), y* (17,), the
    Laplace Student-t at y*). δ and σ are fixed while v and the bias are fitted (Levenberg–Marquardt
    from every start, in later rounds from its previous fit), δ then set from the best fit's
    residuals, ``rounds`` times (δ free in the
    same fit lets a poor start explain the rates as discrepancy and stay there; a Student-t BFGS
    from a good start wandered off in float32); then the correlation discounts w are set."""
    return find_modes(_Logs([data]), np.asarray(starts, np.float32)[None], prior, rounds)[0]


def find_modes(logs: "_Logs", starts, prior: PhysicalPrior = PHYSICAL_PRIOR, rounds: int = 3) -> list:
    """:func:`find_mode` of every log of ``logs`` at once from its starts (L, K, 21) -> L tuples."""
    starts = np.asarray(starts, np.float32)
    nl, K = starts.shape[:2]
    rows = np.arange(nl)
    ys = L.y_from_x(starts)                                                  # (L, K, 17)
    ld = starts[:, 0, L.X_LOG_DISCREPANCY].astype(np.float32)                # (L, 4)
    ls = ys[:, 0, L.Y_LOG_NOISE]                                             # (L, 4)
    for _ in range(rounds):
        z = logs.fit(L.z_from_y(ys), ld, ls)
        fits = L.y_from_z(z, ls[:, None])
        fits = _project(np.asarray(full_x(fits, ld[:, None])).reshape(nl * K, -1), prior).reshape(nl, K, -1)
        fits = L.y_from_x(fits)
        lt = logs.targets(fits, ld, None, prior)
        best = fits[rows, np.argmax(np.where(np.isfinite(lt), lt, -np.inf), 1)]
        ld = np.stack([np.clip(_discrepancy(best[i], d), NUIS_BOUNDS[2], NUIS_BOUNDS[3])
                       for i, d in enumerate(logs.datas)]).astype(np.float32)
        ys = fits       # every start refitted under the new δ: the same rows each round, one compiled fit
    w = np.stack([residual_weights(full_x(best[i], ld[i]), d) for i, d in enumerate(logs.datas)])
    jac = logs.jacobians(L.z_from_y(best), ld, best[:, L.Y_LOG_NOISE], w)
    out = []
    for i, d in enumerate(logs.datas):
        x, ldi, yi, lap = _laplace(best[i], ld[i], jac[i], d, prior)
        out.append((x, ldi, w[i], yi, lap))
    return out


def _laplace(y, ld, jac, data: LogData, prior: PhysicalPrior):
    """The mode y (17,) with its log δ (4,) and the tempered residuals' Jacobian there (R, 13) -> (x*
    (21,), log δ, y, the Laplace Student-t): the Gauss–Newton precision of the tempered Student-t
    residuals (Fisher information (ν+1)/(ν+3) per standardised residual); σ's from its second
    differences (2 n per log σ)."""
    jac = np.asarray(jac, np.float64)
    pz = (NU + 1) / (NU + 3) * jac.T @ jac
    h = np.zeros((N_Y, N_Y))
    iz = L.Z_IN_Y
    h[np.ix_(iz, iz)] = pz
    h[L.Y_LOG_NOISE, L.Y_LOG_NOISE] = np.diag(2.0 * np.asarray(data.n2, np.float64))
    h = np.nan_to_num(0.5 * (h + h.T), nan=0.0, posinf=1e12, neginf=-1e12)
    ev, u = np.linalg.eigh(h)
    ev = np.clip(ev, 1e-9 + 1e-9 * max(ev.max(), 1e-12), None)      # flat directions: broad, not infinite
    lo, hi = _y_lo_hi(prior)
    prec = (u * ev) @ u.T + np.diag(1.0 / ((hi - lo) / 2) ** 2)        # no wider than the prior's box
    cov = np.linalg.inv(prec)
    lap = StudentT(y.astype(np.float32), (np.linalg.cholesky(0.5 * (cov + cov.T)) * LAPLACE_WIDEN).astype(np.float32))
    return np.asarray(full_x(jnp.asarray(y)[None], ld))[0], ld, y, lap


LAPLACE_WIDEN = 2.0
"""The Laplace Student-t's scale is the inverse Hessian's × this (a defensive proposal; with 1.2
and 8 moves per stage the SMC ended under-dispersed on clean logs: 8 MJX flights' 90 % coverage
0.38–0.62, against 0.38–0.88 with 2.0 and 24 moves)."""


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


_SMC_STATIC = ("prior", "n_mcmc", "max_stages", "share", "target_ess")
_smc = jax.jit(_smc_impl, static_argnames=_SMC_STATIC)


@functools.partial(jax.jit, static_argnames=_SMC_STATIC)
def _smc_logs(key, y0, data, ld, w, qv, qn, lap, prior, n_mcmc, max_stages, share, target_ess):
    """:func:`_smc` vmapped over logs (every argument but the static ones with a leading log axis)."""
    def one(k, y, d, a, b, q1, q2, q3):
        return _smc_impl(k, y, d, a, b, q1, q2, q3, prior, n_mcmc, max_stages, share, target_ess)
    return jax.vmap(one)(key, y0, data, ld, w, qv, qn, lap)


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


def _ess_diag(lw) -> dict:
    """Importance weights' diagnostics: ESS, and Pareto k̂ where the ESS passes (a generalised
    Pareto fit, tens of ms; below :data:`MIN_ESS_FRACTION` the weights are unreliable whatever
    k̂ says: ``khat`` None)."""
    e = ess(lw)
    frac = e / len(lw)
    return {"ess": e, "draws": len(lw), "ess_fraction": frac,
            "khat": pareto_khat(lw) if frac >= MIN_ESS_FRACTION else None}


def _reliable(diag) -> bool:
    return diag["ess_fraction"] >= MIN_ESS_FRACTION and diag["khat"] is not None and diag["khat"] <= MAX_KHAT


@full_precision
def log_grounded_posterior(rec_or_data, decoded_theta=None, *, prior: PhysicalPrior = PHYSICAL_PRIOR,
                           samples: int = 1000, draws: int | None = None, particles: int | None = None, seed: int = 0,
                           n_mcmc: int = 24, max_stages: int = 200, starts: int = 12,
                           force_smc: bool = False, rates: str | None = None, calibration="shipped") -> dict:
    """The posterior of a flight log (``rec_or_data``: the arrays of ``read_log`` or a
    :class:`LogData`) under the physical ``prior``, with ``decoded_theta`` (S, 19) — the decoders'
    samples of this log, or None — as the proposal (module doc). ``draws`` / ``particles`` default to
    :data:`DRAWS` / :data:`PARTICLES`; ``rates``: the likelihood's rate term, "windows" or "innovations"
    (default :data:`~.logdata.RATES`; a :class:`LogData` carries its own). It is
    :func:`log_grounded_posteriors` of one log.

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
    dec = None if decoded_theta is None else [decoded_theta]
    return log_grounded_posteriors([rec_or_data], dec, seeds=[seed], prior=prior, samples=samples, draws=draws,
                                   particles=particles, n_mcmc=n_mcmc, max_stages=max_stages, starts=starts,
                                   force_smc=force_smc, rates=rates, calibration=calibration, batch=1, workers=1)[0]


LOG_BATCH = 256
"""Logs evaluated together on an accelerator (:func:`log_grounded_posteriors`; on a CPU one at a
time: its cores are busy with one log's particles already)."""


@full_precision
def log_grounded_posteriors(logs, decoded_thetas=None, *, prior: PhysicalPrior = PHYSICAL_PRIOR,
                            samples: int = 1000, draws: int | None = None, particles: int | None = None,
                            seeds=0, n_mcmc: int = 24, max_stages: int = 200, starts: int = 12,
                            force_smc: bool = False, rates: str | None = None, calibration="shipped",
                            batch: int | None = None, workers: int | None = None,
                            desc: str | None = None) -> list[dict]:
    """The posteriors of many logs (a list of what :func:`log_grounded_posterior` takes), batched:
    logs of one shape (their windows and blocks bucketed, :func:`~.logdata.bucket`) and of one kind
    of proposal are evaluated ``batch`` at a time (default :data:`LOG_BATCH` on an accelerator, 1 on
    a CPU) by programs vmapped over the logs. ``decoded_thetas``: None, or one (S, 19) or None per
    log; ``seeds``: one per log, or an int (log i gets seeds + i); ``workers``: processes that reduce
    the logs (:func:`~.logdata.prepare`; default 1 on a CPU, up to 16 beside an accelerator);
    ``desc``: a progress bar's label. A log too short for the posterior raises
    :class:`~.logdata.LogTooShort` naming its index.
    -> one dict per log, in order, as :func:`log_grounded_posterior` returns it (the same draws up
    to float rounding, whatever the batch)."""
    from mjxsysid.runtime.progress import progress
    logs = list(logs)
    n = len(logs)
    dec = [None] * n if decoded_thetas is None else list(decoded_thetas)
    seeds = [int(seeds) + i for i in range(n)] if np.ndim(seeds) == 0 else [int(s) for s in seeds]
    if len(dec) != n or len(seeds) != n:
        raise ValueError(f"log_grounded_posteriors: {n} logs, {len(dec)} decoded ensembles and {len(seeds)} seeds; "
                         "give one of each per log")
    cfg = dict(prior=prior, samples=int(samples), draws=DRAWS if draws is None else int(draws),
               particles=PARTICLES if particles is None else int(particles), n_mcmc=n_mcmc, max_stages=max_stages,
               starts=starts, force_smc=force_smc, calibration=calibration)
    rates = RATES if rates is None else rates
    if workers is None:
        workers = 1 if jax.default_backend() == "cpu" else min(16, os.cpu_count() or 1)
    datas = _prepare_all(logs, rates, int(workers))
    qvs = [None if d is None else decoded_proposal(d, prior) for d in dec]
    batch = (1 if jax.default_backend() == "cpu" else LOG_BATCH) if batch is None else int(batch)
    if batch < 1:
        raise ValueError(f"log_grounded_posteriors: batch must be ≥ 1, got {batch}")
    groups: dict = {}
    for i, (d, q) in enumerate(zip(datas, qvs)):
        key = (d.rates, q is None, tuple(np.shape(a) for a in jax.tree.leaves(d)))
        groups.setdefault(key, []).append(i)
    chunks = [idx[c:c + batch] for idx in groups.values() for c in range(0, len(idx), batch)]
    out = [None] * n
    for chunk in progress(chunks, desc=desc or "log-grounded posteriors", enabled=False if len(chunks) < 2 else None):
        res = _posterior_batch([datas[i] for i in chunk], [dec[i] for i in chunk], [qvs[i] for i in chunk],
                               [seeds[i] for i in chunk], **cfg)
        for i, r in zip(chunk, res):
            out[i] = r
    return out


def _prepare_one(x, rates: str, i: int):
    if isinstance(x, LogData):
        return x
    try:
        return prepare(x, rates=rates)
    except LogTooShort as e:
        raise LogTooShort(f"log {i}: {e}") from None


def _prepare_all(logs, rates: str, workers: int) -> list:
    """Each log's :class:`LogData` (those given as one kept), in ``workers`` processes (a reduction
    is many small NumPy calls: threads wait on each other's interpreter lock)."""
    if workers <= 1 or len(logs) < 2 * workers:
        return [_prepare_one(x, rates, i) for i, x in enumerate(logs)]
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as ex:
        return list(ex.map(_prepare_one, logs, [rates] * len(logs), range(len(logs)), chunksize=8))


def _starts(data, decoded_theta, rng, prior, starts: int) -> np.ndarray:
    """The mode's ``starts`` starting points (starts, 21), always as many (one compiled fit): a
    linear start, the decoded samples, prior draws."""
    x_lin = linear_start(data)
    sv = [prior.sample_v(rng, max(starts // 3, 1))]
    if decoded_theta is not None:
        dv = np.asarray(visible_from_theta(np.asarray(decoded_theta, np.float32)), np.float32)
        dv = dv[np.all(np.isfinite(dv), 1) & np.asarray(prior.v_valid(dv))][: starts - len(sv[0]) - 1]
        sv.append(dv)
    n_fill = max(starts - 1 - sum(len(a) for a in sv), 0)
    if n_fill:
        sv.append(prior.sample_v(rng, n_fill))
    sv = np.concatenate(sv)
    return np.concatenate([x_lin[None], np.concatenate([sv, np.broadcast_to(x_lin[L.X_NUIS], (len(sv), N_NUIS))], 1)])


def _posterior_batch(datas, decs, qvs, seeds, *, prior, samples, draws, particles, n_mcmc, max_stages, starts,
                     force_smc, calibration) -> list[dict]:
    """:func:`log_grounded_posteriors` of logs of one shape and one kind of proposal (module doc)."""
    nl = len(datas)
    logs = _Logs(datas)
    # host draws from NumPy generators (they compile nothing); the SMC's key is PRNGKey(seed)'s bits
    rng = [[np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(7)] for seed in seeds]
    r_is, r_n, r_mix, r_h, r_res, r_st, r_lp = (list(r) for r in zip(*rng))
    qns = [nuisance_proposal(d, ACC_BIAS_SD) for d in datas]
    # 0. the mode
    st = np.stack([_starts(d, dc, r_st[i], prior, starts) for i, (d, dc) in enumerate(zip(datas, decs))])
    modes = find_modes(logs, st.astype(np.float32), prior)
    ld = np.stack([m[1] for m in modes]).astype(np.float32)
    w = np.stack([m[2] for m in modes]).astype(np.float32)
    laps = [m[4] for m in modes]
    outs = [{"proposal": "decoded" if qvs[i] is not None else "prior", "mode": modes[i][0], "weights": modes[i][2],
             "channels_used": np.asarray(d.use), "rates": d.rates} for i, d in enumerate(datas)]
    chosen = [None] * nl
    # 1. the decoded ensemble as the proposal, then the Laplace proposal
    if qvs[0] is not None:
        ys = np.stack([np.concatenate([q.sample(r_is[i], draws), qns[i].sample(r_n[i], draws)], 1) for i, q in enumerate(qvs)])
        lt = logs.targets(ys, ld, w, prior)
        for i, q in enumerate(qvs):
            lw = lt[i].astype(np.float64) - np.asarray(q.log_prob(ys[i, :, L.Y_V]) + qns[i].log_prob(ys[i, :, L.Y_NUIS]), np.float64)
            outs[i]["decoded_is"] = _ess_diag(lw)
            if _reliable(outs[i]["decoded_is"]) and not force_smc:
                chosen[i] = ("decoded_is", ys[i], lw)
    need = [i for i in range(nl) if chosen[i] is None]
    if need:
        ys = np.stack([laps[i].sample(r_lp[i], draws) for i in need])
        lt = logs.targets(ys, ld[need], w[need], prior, idx=need)
        for j, i in enumerate(need):
            lw = lt[j].astype(np.float64) - np.asarray(laps[i].log_prob(ys[j]), np.float64)
            outs[i]["laplace_is"] = _ess_diag(lw)
            if _reliable(outs[i]["laplace_is"]) and not force_smc:
                chosen[i] = ("laplace_is", ys[j], lw)
    draws_y = [None] * nl
    for i, c in enumerate(chosen):
        if c is not None:
            name, y, lw = c
            p = np.exp(lw - lw.max())
            draws_y[i] = y[r_res[i].choice(len(y), samples, p=p / p.sum())]
            outs[i]["method"] = name
    # 2. tempered SMC from a mixture of the proposals and the prior
    need = [i for i in range(nl) if chosen[i] is None]
    if need:
        y0 = np.stack([_smc_start(prior, qvs[i], qns[i], laps[i], particles, r_mix[i], r_n[i], r_lp[i], r_is[i])
                       for i in need])
        keys = np.stack([np.array([0, seeds[i] & 0xFFFFFFFF], np.uint32) for i in need])
        pts, wts, lam, stages, acc, acc_min = logs.smc(need, keys, y0, ld[need], w[need], [qvs[i] for i in need],
                                                       [qns[i] for i in need], [laps[i] for i in need], prior,
                                                       n_mcmc, max_stages)
        for j, i in enumerate(need):
            wt = np.asarray(wts[j], np.float64)
            draws_y[i] = np.asarray(pts[j])[r_res[i].choice(particles, samples, p=wt / wt.sum())]
            outs[i].update(method="smc", smc_stages=int(stages[j]), smc_acceptance=float(acc[j]),
                           smc_acceptance_min=float(acc_min[j]), smc_tempering=float(lam[j]))
    return [_finish(outs[i], draws_y[i], datas[i], ld[i], prior, calibration, seeds[i], r_h[i], samples)
            for i in range(nl)]


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


def _finish(out: dict, ys, data, ld, prior, calibration, seed, r_h, samples) -> dict:
    """One log's draws y (samples, 17) -> its posterior dict: θ, v, the features, the drag, the calibration."""
    mode = out["mode"]
    xs = np.asarray(full_x(ys, ld))
    v_raw = xs[:, L.X_V]
    out["features"] = log_features(data, mode)
    if out["features"]["velocity_used"]:     # (3,) 1/s: x and y from the accelerometer's x and y, z from its term
        xy = getattr(data, "_rows", {}).get("drag_xy")
        out["drag_per_mass"] = [*(xy.tolist() if xy is not None else [None, None]), drag_at(mode, data)]
    else:
        out["drag_per_mass"] = None
    v, out["calibration"] = _calibrated(v_raw, out["features"], out["weights"], calibration, prior, seed)
    h = prior.sample_h(r_h, samples)
    out.update(v=v, v_raw=v_raw, nuisance=xs[:, L.X_NUIS], theta=np.asarray(theta_from(v, h), np.float32))
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
