"""The log-grounded posterior's mode and its Laplace proposal (step 0 of :mod:`.inference`):
Levenberg–Marquardt (optimistix) from several starts with δ re-set between rounds, the residuals'
correlation discounts, and a Student-t at the mode from the Gauss–Newton precision — for one log or
for every log of a batch at once."""
from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify.coords import PHYSICAL_PRIOR, PhysicalPrior
from mjxsysid.identify.likelihood import (NU, delta_grid_x, log_delta_of, noise_information, rate_rows,
                                          residual_weights, residuals)
from mjxsysid.identify.logdata import LogData
from mjxsysid.identify.proposals import StudentT
from mjxsysid.identify.target import ACC_BIAS_SD, N_Y, NUIS_BOUNDS, _nuis_lo_hi, _y_lo_hi, full_x
from mjxsysid.runtime import exported


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


def standardised(rg, sg, ra, sa, use, bias):
    """The least squares' residuals from :func:`~.likelihood.residuals`' (rates (R, 3) and their scales, acc_z
    (Wa,) and its scale), the channels' use (4,) and the accelerometer bias () -> (rates (R, 3), acc_z (Wa,),
    the bias's prior term ()), each over its scale. Arithmetic only: NumPy's arrays in, NumPy's out
    (:mod:`.idlecheck` on the host), JAX's in a trace."""
    return rg * (use[L.GYRO] / sg), ra * (use[L.ACC_Z] / sa), bias / ACC_BIAS_SD


def _ls_residuals(z, args):
    """Standardised residuals for the least-squares stage: z (13,) = [v, bias], σ fixed in ``args``."""
    data, ld, ls = args
    x = L.x_from_y(L.y_from_z(z, ls), ld)
    g, a, b = standardised(*residuals(x, data), data.use, z[L.Z_BIAS])
    return jnp.concatenate([g.ravel(), a, b[None]])


def _fit_ls_impl(z0, data, ld, ls, max_steps=200, normal=False):
    """Levenberg–Marquardt (optimistix) on the standardised residuals from one start (13,).
    ``normal``: each step's damped least squares by its normal equations (lineax's Cholesky of a
    13 × 13 matrix) instead of a QR of the residuals' Jacobian, what every vmapped fit uses: the
    same fits (twelve starts of a 4 s log: the same residual sums to 0.01), and on a GPU, where
    batched QR runs one matrix after the other, the fits of a batch of logs took 51 s per 64 logs
    with QR and about 2 s per 256 with Cholesky (an H200)."""
    import optimistix as optx
    if normal:
        import lineax as lx
        solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8, linear_solver=lx.Normal(lx.Cholesky()))
    else:
        solver = optx.LevenbergMarquardt(rtol=1e-8, atol=1e-8)
    return optx.least_squares(_ls_residuals, solver, z0, args=(data, ld, ls), max_steps=max_steps, throw=False).value


_fit_ls = jax.jit(_fit_ls_impl, static_argnames=("max_steps", "normal"))
""":func:`_fit_ls_impl` jitted."""


@functools.partial(jax.jit, static_argnames=("max_steps",))
def _fit_ls_batched(z0, data, ld, ls, max_steps=200):
    """:func:`_fit_ls` from every start (K, 13) at once (vmapped; by the normal equations)."""
    return jax.vmap(lambda z: _fit_ls(z, data, ld, ls, max_steps=max_steps, normal=True))(z0)


def _fit_ls_many(z0, data, ld, ls, max_steps=200):
    """:func:`_fit_ls` from each start (K, 13): on a CPU one after the other — the batched solver's
    trace compiles in twice the time (about 4 s against 2 s on a core, a first decode's largest
    program) and runs until its slowest start has converged; on an accelerator batched, where one
    start at a time is bound by kernel launches (a calibration of 96 logs on an H100: 561 s one at
    a time against 388 s batched)."""
    if jax.default_backend() != "cpu":
        return _fit_ls_batched(jnp.asarray(z0), data, ld, ls, max_steps=max_steps)
    static = {"max_steps": int(max_steps), "normal": False}      # its trace (optimistix's solver) kept on disk
    return jnp.stack([exported.call("fit_ls", _fit_ls_impl, static, jnp.asarray(z), data, ld, ls)
                      for z in np.asarray(z0, np.float32)])


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
    return jax.vmap(lambda z, d, a, b: _fit_ls_batched(z, d, a, b, max_steps=max_steps))(z0, data, ld, ls)


@jax.jit
def _ls_jacobian_logs(z, data, ld, ls, w):
    """:func:`_ls_jacobian` of every log at z (L, 13) -> (L, R, 13)."""
    return jax.vmap(lambda q, d, a, b, c: _ls_jacobian(q, (d, a, b), c))(z, data, ld, ls, w)


def _discrepancies(logs, ys) -> np.ndarray:
    """δ per channel of every log of ``logs`` (:class:`~.batched._Logs`: one shape, so one ``rates``) at its y
    (L, 17) -> (L, 4) log δ, float32: what the residuals' mean square leaves beyond the scale they have without a
    discrepancy (noise, resolution, the windows' floor; at least 1e-6); for innovations logs the gyro's is the
    grid's δ the innovations' likelihood prefers (:data:`_DELTA_GRID`). The residuals and the likelihoods of the
    logs come from one call each."""
    datas = logs.datas
    innovations = datas[0].rates == "innovations"
    res = logs.residuals(np.asarray(full_x(ys, np.full(L.N_CHANNELS, -30.0)), np.float32))
    out = np.zeros((len(datas), L.N_CHANNELS))
    for i, d in enumerate(datas):
        rg, sg, ra, sa = (np.asarray(a[i], np.float64) for a in res)
        ms_acc = np.mean(ra[np.asarray(d.bmask) > 0] ** 2) - sa ** 2
        wv = np.asarray(d.wmask) > 0
        ms_gyro = [1e-12] * 3 if innovations else [np.mean(rg[wv, k] ** 2 - sg[wv, k] ** 2) for k in range(3)]
        out[i] = np.log(np.sqrt(np.maximum(np.array(ms_gyro + [ms_acc]), 1e-12)))
    if innovations:                     # the gyro's δ: the process noise that makes the innovations most likely
        ll = logs.rate_logliks(np.stack([delta_grid_x(full_x(y, o), _DELTA_GRID) for y, o in zip(ys, out)]))
        out[:, L.GYRO] = [log_delta_of(_DELTA_GRID, li) for li in ll]
    return out.astype(np.float32)


_DELTA_GRID = np.linspace(NUIS_BOUNDS[2], NUIS_BOUNDS[3], 64)
"""log δ the innovations' process noise is chosen from at the mode (:func:`_discrepancies`)."""


def find_modes(logs, starts, prior: PhysicalPrior = PHYSICAL_PRIOR, rounds: int = 3) -> list:
    """The mode of every log of ``logs`` (:class:`~.batched._Logs`: their ``datas`` and the batched
    ``fit``, ``targets``, ``jacobians``) at once from its starts (L, K, 21) -> L tuples of
    :func:`~.inference.find_mode`."""
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
        ld = np.clip(_discrepancies(logs, best), NUIS_BOUNDS[2], NUIS_BOUNDS[3]).astype(np.float32)
        ys = fits       # every start refitted under the new δ: the same rows each round, one compiled fit
    xb = np.asarray(full_x(best, ld), np.float32)
    res = logs.residuals(xb)                                                 # the logs together: one call
    w = np.stack([residual_weights(xb[i], d, [r[i] for r in res]) for i, d in enumerate(logs.datas)])
    jac = _with_speed_rows(np.asarray(logs.jacobians(L.z_from_y(best), ld, best[:, L.Y_LOG_NOISE], w)), logs.datas)
    return [(np.asarray(full_x(best[i][None], ld[i]))[0], ld[i], w[i], best[i], _laplace(best[i], jac[i], d, prior))
            for i, d in enumerate(logs.datas)]


def _with_speed_rows(jac, datas) -> np.ndarray:
    """The residuals' Jacobians (L, R, 13) with one row more per log: the measured rotor speeds' term
    on τ_m as a residual (log τ_m − its mean) / its standard deviation (``data.speed``, :mod:`.speeds`;
    × √((ν + 3)/(ν + 1)), the Student-t factor :func:`_laplace` applies undone), a row of zeros for a
    log without speeds. The least squares do not read it: τ_m starts at the speeds' (:func:`~.likelihood.linear_start`)."""
    row = np.zeros((len(datas), 1, jac.shape[-1]))
    for i, d in enumerate(datas):
        n_eff, _, sd = np.asarray(d.speed, np.float64)
        if n_eff > 0:
            row[i, 0, L.LOG_TAU_M] = np.sqrt((NU + 3) / (NU + 1)) / sd
    return np.concatenate([jac, row], 1)


def _laplace(y, jac, data: LogData, prior: PhysicalPrior) -> StudentT:
    """The Laplace Student-t at the mode y (17,) from the tempered residuals' Jacobian there (R, 13):
    the Gauss–Newton precision of the tempered Student-t
    residuals (Fisher information (ν+1)/(ν+3) per standardised residual); σ's from its second
    differences (:func:`~.likelihood.noise_information`)."""
    jac = np.asarray(jac, np.float64)
    pz = (NU + 1) / (NU + 3) * jac.T @ jac
    h = np.zeros((N_Y, N_Y))
    iz = L.Z_IN_Y
    h[np.ix_(iz, iz)] = pz
    h[L.Y_LOG_NOISE, L.Y_LOG_NOISE] = np.diag(noise_information(np.asarray(y, np.float64)[L.Y_LOG_NOISE], data))
    h = np.nan_to_num(0.5 * (h + h.T), nan=0.0, posinf=1e12, neginf=-1e12)
    ev, u = np.linalg.eigh(h)
    ev = np.clip(ev, 1e-9 + 1e-9 * max(ev.max(), 1e-12), None)      # flat directions: broad, not infinite
    lo, hi = _y_lo_hi(prior)
    prec = (u * ev) @ u.T + np.diag(1.0 / ((hi - lo) / 2) ** 2)        # no wider than the prior's box
    cov = np.linalg.inv(prec)
    return StudentT(y.astype(np.float32), (np.linalg.cholesky(0.5 * (cov + cov.T)) * LAPLACE_WIDEN).astype(np.float32))


LAPLACE_WIDEN = 2.0
"""The Laplace Student-t's scale is the inverse Hessian's × this (a defensive proposal; with 1.2
and 8 moves per stage the SMC ended under-dispersed on clean logs: 8 MJX flights' 90 % coverage
0.38–0.62, against 0.38–0.88 with 2.0 and 24 moves)."""
