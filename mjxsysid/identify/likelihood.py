"""The likelihood of a flight log's IMU given its motor commands, under a candidate vehicle.

Equation error over short windows started from the measured state (no open-loop rollout): the
log is cut into non-overlapping windows of 2 × :data:`~.logdata.WINDOW_STEPS` control steps; in each,

- the change of the measured body rates — the mean over the window's second half minus the mean
  over its first — is compared with the integral of the angular acceleration the motor commands
  imply (Euler's equation, :mod:`.coords`), each step weighted by how much of it lies between
  the two halves (a triangle), the gyroscopic term from the measured rates. Half-window means,
  not two samples: a feedback controller reacts to the gyro's noise, so the noise of a single
  start sample is correlated with the commands that follow and biases the fit (seen: at 5× the
  hardware-like white noise τ_m came out 25 % low and the yaw authority 4× high); averaged over W
  samples its share shrinks W-fold;
- the mean measured specific force along body z over blocks of :data:`~.logdata.ACC_BLOCK_STEPS` is
  compared with the thrust the commands imply, plus an accelerometer bias, minus the body drag
  D_z · v_z where the log carries its velocity (D_z = d_z / m, profiled: the least-squares value
  in [0, :data:`DRAG_MAX`] for each candidate, :func:`drag_per_mass`). Without velocity the drag's
  share of the specific force is left to the discrepancy δ and to the calibration.

The rotor speeds are the commands through the simulator's first-order lag, integrated exactly
(:func:`~mjxsysid.sim.motors.mean_square_speed`: the exact mean of s² over each step for the
rates, the end-of-step s² for the accelerometer); where the log's rotor speeds are used, through the
fitted command→speed map as well (:func:`~.speeds.model_features`). The lag depends on τ_m alone, so the window
sums of s² are computed once per log on a grid of τ_m (:data:`~.logdata.TAU_GRID`, :mod:`.logdata`) and interpolated in
log τ_m per candidate: a candidate then costs a few multiply-adds per window, and thousands are
evaluated in one jitted call.

Residuals are Student-t (ν = :data:`NU`: heavy tails for glitches), with a scale per channel
(gyro x, y, z, accelerometer z) of √(k σ² + δ²): σ the IMU's white-noise level per sample
(k = 2 / W for a difference of two means of W gyro samples, 1 / W_eff for a mean of W_eff
independent accelerometer samples) and δ a model-discrepancy term for physics the model lacks (aerodynamics,
another simulator's motors, drag). σ is a parameter with its own evidence — the log's second
differences, which for white noise have variance 6 σ² while a rigid body's signal barely enters
— so the noise level is estimated jointly, not assumed; δ has only the residuals.

**The rate term, two ways** (``rates``, :data:`~.logdata.RATES`). The half-window means shrink the feedback
bias but do not remove it: the noise of a window's first half still reaches the commands that follow
(measured on MJX flights of the oracle: τ_m 1.18× at 5× white noise, 1.56× at 20×). ``"innovations"``
is the prediction-error method's answer (Ljung, *System Identification*, §13: consistent in closed
loop when the noise model holds): a steady-state Kalman filter of each body rate (state ω, process
noise δ² per step for what the model lacks, measurement noise σ²) predicts every gyro sample from
the samples before it and the commands before it; its innovations are independent of everything
the controller saw, so the commands' reaction to the noise no longer correlates with the errors.
The innovations are linear in the model's coefficients once τ_m and the gain are fixed, so their
sums of squares come from Gram matrices computed once per log on a grid of τ_m × gain
(:func:`~.logdata._innovation_factors`) and interpolated per candidate, as the windows' sums are; the
filter's start is profiled out. Gaussian (no heavy tails). A rotor vibration (narrow-band measurement
noise the controller reacts to) would break the white noise model and bias the fit; where the gyro's
spectrum shows one, the filter runs on the gyro and the regressors whitened by a fixed autoregressive
filter fitted to that spectrum (:mod:`.vibration`), the measurement noise then the whitened noise
(:attr:`~.logdata.LogData.kf_rscale`). docs/identify.md, "The rate term", has the measurements.
"""
from __future__ import annotations

from math import comb

import jax
import jax.numpy as jnp
import numpy as np

from mjxsysid import theta as P
from mjxsysid.identify import logspace as L
from mjxsysid.identify.logspace import CHANNELS, N_NUIS, NUIS_NAMES  # noqa: F401 (the likelihood's names)
from mjxsysid.identify.logdata import DRAG_MAX, KF_LOGIT_GRID, LogData, gyro_rows, kf_gains, step_lag, whitened_columns
from mjxsysid.identify.speeds import SPEED_TAU_GRID

NU = 4.0
"""Degrees of freedom of the Student-t residuals (the windows' rate term and the accelerometer)."""
RESOLUTION = np.array([1e-4, 1e-4, 1e-4, 1e-3], np.float32)
"""rad/s, m/s²: the finest residual scale per channel — a logged number's resolution (a 16-bit
gyro at ±2000 °/s has 1e-3 rad/s steps; a CSV with 7 digits ~1e-5 relative): without a floor a
noise-free simulated log would make every model error infinitely significant."""

QUANTISATION_VAR = RESOLUTION.astype(np.float64) ** 2 / 12.0
"""(rad/s)², (m/s²)²: the variance a reading rounded to :data:`RESOLUTION` carries (q²/12), in the
second differences' model beside the white noise σ². Below it the second differences cannot tell σ
apart, so the posterior of log σ is flat down to its prior's floor instead of piling against it: on
a noise-free simulated log (float32 rounding, σ ≈ 1e-6) NUTS's chains otherwise froze at the wall."""

_BASIS = np.stack([P.ROTOR_DIRECTIONS[:, 1], -P.ROTOR_DIRECTIONS[:, 0], P.YAW_SIGNS]).astype(np.float32)  # (3, 4)


def _interp(log_tau, grid, f):
    """Feature f (G, ...) at log τ (), linear in log τ between grid points (clamped)."""
    x = jnp.clip(log_tau, grid[0], grid[-1])
    i = jnp.clip(jnp.searchsorted(grid, x) - 1, 0, grid.shape[0] - 2)
    w = (x - grid[i]) / (grid[i + 1] - grid[i])
    return (1 - w) * f[i] + w * f[i + 1]


def _student_t(r, scale, mask):
    """Sum of Student-t(ν = NU) log densities of residuals r (W,) at ``scale`` (), over ``mask``."""
    z = r / scale
    c = (jax.scipy.special.gammaln((NU + 1) / 2) - jax.scipy.special.gammaln(NU / 2)
         - 0.5 * jnp.log(NU * jnp.pi))
    return jnp.sum(mask * (c - jnp.log(scale) - (NU + 1) / 2 * jnp.log1p(z * z / NU)))


def _rho(v):
    """The four motor effectivenesses ρ (4,) of v (12,): three coordinates, the fourth makes Σρ = 4."""
    rho = v[L.RHO]
    return jnp.concatenate([rho, (4.0 - rho[0] - rho[1] - rho[2])[None]])


def _rate_coefficients(v):
    """The rate model's coefficients per axis (3, 6) under v (12,): authority × the basis × ρ_i per
    rotor (4), the gyroscopic coefficient (from the inertia ratios), the rate bias c — what multiplies
    each step's ∫ s_i² dt, gyroscopic product and dt (the innovations' β without its −1)."""
    auth = jnp.exp(jnp.stack([v[L.LOG_AUTH_X], v[L.LOG_AUTH_Y], v[L.LOG_YAW]]))   # roll, pitch; yaw authority
    inv = 1.0 / jnp.exp(v[L.LOG_AUTH])                                             # ∝ J
    gyro_coef = jnp.stack([(inv[1] - inv[2]) / inv[0], (inv[2] - inv[0]) / inv[1], (inv[0] - inv[1]) / inv[2]])
    return jnp.concatenate([auth[:, None] * jnp.asarray(_BASIS) * _rho(v)[None], gyro_coef[:, None],
                            v[L.EXT_ACC, None]], 1)


def predict(v, data: LogData):
    """The windows' predicted rate changes (W, 3) and the blocks' mean acc_z without bias (Wa,) under the
    visible coordinates v (12,) (:mod:`.coords`)."""
    fg = _interp(v[L.LOG_TAU_M], data.log_tau, data.fg)     # (W, 4)
    fa = _interp(v[L.LOG_TAU_M], data.log_tau, data.fa)
    c = _rate_coefficients(v)
    dgyro = fg @ c[:, :4].T + c[:, 4] * data.gyq + c[:, 5] * data.span
    acc = P.GRAVITY / 4.0 * jnp.exp(v[L.LOG_TW]) * (fa @ _rho(v))
    return dgyro, acc


_SPEED_LOG_TAU = np.log(SPEED_TAU_GRID).astype(np.float32)


def speed_loglik(v, data: LogData):
    """The measured rotor speeds' evidence on τ_m under v (12,) (:mod:`.speeds`): their term's
    log-likelihood, linear in log τ_m between the nodes of :data:`~.speeds.SPEED_TAU_GRID`; 0 on a log
    without speeds."""
    return _interp(v[L.LOG_TAU_M], jnp.asarray(_SPEED_LOG_TAU), data.speed_ll)


def innovation_variance(log_sigma, log_delta, rscale=1.0):
    """The steady-state filter per gyro axis from the noise σ (3,) and the process noise δ (3,) per
    step (both log): (innovation variance S (3,), logit of the gain K = P / (P + r)), with
    r = ``rscale`` σ² + the resolution² (``rscale`` (3,): :attr:`~.logdata.LogData.kf_rscale`, 1 for white
    noise), P the predicted state's variance, P = (Q + √(Q² + 4 Q r)) / 2."""
    r = rscale * jnp.exp(2 * log_sigma) + jnp.asarray(RESOLUTION[L.GYRO]) ** 2
    q = jnp.exp(2 * log_delta)
    p = 0.5 * (q + jnp.sqrt(q * q + 4 * q * r))
    return p + r, jnp.log(p) - jnp.log(r)


def _interp2(log_tau, logit, data: LogData):
    """The factors kf_r at (log τ (), logit K (3,)) -> (3, 7, 7): bilinear in log τ and logit K."""
    def w_of(x, grid):
        x = jnp.clip(x, grid[0], grid[-1])
        i = jnp.clip(jnp.searchsorted(grid, x) - 1, 0, grid.shape[0] - 2)
        return i, (x - grid[i]) / (grid[i + 1] - grid[i])
    i, wt = w_of(log_tau, data.log_tau)
    ft = (1 - wt) * data.kf_r[i] + wt * data.kf_r[i + 1]            # (H, 3, 7, 7)
    j, wk = jax.vmap(lambda x: w_of(x, data.kf_logit))(logit)       # (3,)
    ax = jnp.arange(3)
    return (1 - wk)[:, None, None] * ft[j, ax] + wk[:, None, None] * ft[j + 1, ax]


def innovations(x, data: LogData):
    """The gyro's innovations under x (21,) as the whitened sums they enter through: z (7, 3) with
    Σ_k e_k² = ‖z[:, a]‖² per axis, and the innovation variance S (3,)."""
    v, ls, ld = x[L.X_V], x[L.X_LOG_NOISE_GYRO], x[L.X_LOG_DISCREPANCY_GYRO]
    s, logit = innovation_variance(ls, ld, data.kf_rscale)
    r = _interp2(v[L.LOG_TAU_M], logit, data)                                  # (3, 7, 7)
    beta = jnp.concatenate([_rate_coefficients(v), -jnp.ones((3, 1))], 1)
    return jnp.einsum("aij,aj->ia", r, beta), s


def _innovation_loglik(z, s, n):
    """Per axis (3,), the Gaussian log density of n innovations of variance S (3,) whose sum of squares
    is ‖z[:, a]‖² (z (7, 3), :func:`innovations`): −½ n log(2π S) − Σ e² / (2 S)."""
    return -0.5 * n * jnp.log(2 * jnp.pi * s) - 0.5 * jnp.sum(z * z, 0) / s


def rate_rows(data: LogData) -> int:
    """How many rate residuals per axis :func:`residuals` returns."""
    return 7 if data.rates == "innovations" else data.dgyro.shape[0]


def residuals(x, data: LogData):
    """Residuals of x (21,) (:func:`log_likelihood`) and their scales: the rates' (R, 3) with a
    scale each (R, 3) — for "windows" each window's rate change, its scale the channel's noise,
    discrepancy and resolution and the window's relative floor; for "innovations" the whitened
    innovation sums of :func:`innovations` with √S — and the blocks' acc_z (Wa,) with the
    accelerometer's scale (). The padding's residuals are 0."""
    v, ls, ld, bias = x[L.X_V], x[L.X_LOG_NOISE], x[L.X_LOG_DISCREPANCY], x[L.X_BIAS]
    dgyro, acc = predict(v, data)
    var = data.kvar * jnp.exp(2 * ls) + jnp.exp(2 * ld) + jnp.asarray(RESOLUTION) ** 2
    r0 = (data.acc - acc - bias) * data.bmask
    ra, sa = (r0 + drag_per_mass(r0, data) * data.vz) * data.bmask, jnp.sqrt(var[L.ACC_Z])
    if data.rates == "innovations":
        z, s = innovations(x, data)
        return z, jnp.broadcast_to(jnp.sqrt(s), z.shape), ra, sa
    return ((data.dgyro - dgyro) * data.wmask[:, None], jnp.sqrt(var[L.GYRO] + data.gfloor ** 2), ra, sa)


def drag_per_mass(r0, data: LogData):
    """The body-z drag per mass D_z (1/s, in [0, :data:`DRAG_MAX`]) that best explains the blocks'
    acc_z residual r0 (Wa,) through their body-z velocity (the model reads −D_z v_z): least squares;
    0 where the log carries no velocity."""
    vz = data.vz * data.bmask
    d = -jnp.sum(r0 * vz) / jnp.maximum(jnp.sum(vz * vz), 1e-9)
    return jnp.clip(d, 0.0, DRAG_MAX)


def drag_at(x, data: LogData) -> float:
    """The body-z drag per mass D_z (1/s) :func:`residuals` profiles at the parameter vector x (21,)
    (the posterior's mode: a point value for a log that carries velocity)."""
    return float(_drag_at(jnp.asarray(x, jnp.float32), data))


@jax.jit
def _drag_at(x, data: LogData):
    _, acc = predict(x[L.X_V], data)
    return drag_per_mass((data.acc - acc - x[L.X_BIAS]) * data.bmask, data)


residuals_jit = jax.jit(residuals)
""":func:`residuals` compiled (once per log bucket): what host-side callers use."""

residuals_logs = jax.jit(jax.vmap(residuals))
""":func:`residuals` of logs of one shape at once: x (L, 21) and the logs' stacked data -> its four arrays,
each with a leading log axis (one device call for a batch)."""


def log_likelihood(x, data: LogData, weights=None):
    """log p(log | v, nuisances) for one parameter vector x (12 + 9,) = [v, log σ (4), log δ (4),
    acc_z bias]: the Student-t window residuals, the second differences' evidence on σ and, where the
    log's rotor speeds are used, their evidence on τ_m (:func:`speed_loglik`).
    ``weights`` (4,): each channel's residual term multiplied by it (default 1: see
    :func:`residual_weights`); a channel the log cannot inform (``data.use``) counts 0."""
    rg, sg, ra, sa = residuals(x, data)
    w = data.use if weights is None else data.use * weights
    sig2 = jnp.exp(2 * x[L.X_LOG_NOISE])
    acc = w[L.ACC_Z] * _student_t(ra, sa, data.bmask)
    if data.rates == "innovations":
        res = jnp.sum(w[L.GYRO] * _innovation_loglik(rg, sg[0] ** 2, data.kf_n)) + acc
    else:
        wm = data.wmask
        gyro = range(L.GYRO.start, L.GYRO.stop)            # the rate residuals' columns are the gyro channels
        res = sum(w[c] * _student_t(rg[:, c], sg[:, c], wm) for c in gyro) + acc
    var2 = comb(4, 2) * (sig2 + jnp.asarray(QUANTISATION_VAR))   # variance of a second difference
    noise = jnp.sum(-0.5 * data.n2 * jnp.log(var2) - 0.5 * data.s2 / var2)
    return res + noise + speed_loglik(x[L.X_V], data)


def residual_weights(x, data: LogData, res=None) -> np.ndarray:
    """Per channel (4,), the weight that makes correlated residuals count as the independent
    evidence they are worth: at the parameters x (21,), the lag-1 autocorrelation φ of each
    channel's residuals in time order gives (1 − φ)/(1 + φ) (the variance of a mean of an AR(1)
    sequence over the white one's), 1 for φ ≤ 0, at least 0.02. A model error that follows the
    manoeuvre (a clean log's residuals are not white) then widens the posterior instead of being
    counted once per window. ``res``: :func:`residuals` at x where the caller has them."""
    rg, _, ra, _ = residuals_jit(jnp.asarray(x, jnp.float32), data) if res is None else res
    wv, bv = np.asarray(data.wmask) > 0, np.asarray(data.bmask) > 0
    rates = innovation_series(x, data) if data.rates == "innovations" else [np.asarray(rg)[wv, k] for k in range(3)]
    out = []
    for r in list(rates) + [np.asarray(ra)[bv]]:
        r = r - r.mean()
        den = float(r @ r)
        phi = float(r[1:] @ r[:-1]) / den if den > 0 and len(r) > 3 else 0.0
        out.append(1.0 if phi <= 0 else max((1 - phi) / (1 + phi), 0.02))
    return np.asarray(out, np.float32)


def innovation_series(x, data: LogData) -> np.ndarray:
    """The gyro's innovations (3, m) under x (21,), in time order (host, float64; whitened where the log has
    a vibration, the start offset profiled out, as in the likelihood; m = ``data.kf_n``): what
    :func:`residual_weights` reads for the rates."""
    rows = getattr(data, "_rows", None)
    if rows is None:
        raise ValueError("this LogData has no log rows (made by prepare() in this process?): cannot form its innovations")
    x = np.asarray(x, np.float64)
    v = x[L.X_V]
    y, q = gyro_rows(rows["imu"], rows["start"], rows["n"])
    tau = float(np.exp(v[L.LOG_TAU_M]))
    step_f = rows.get("step_f")          # the rotor speeds' (:mod:`.speeds`), where used
    f = step_lag(rows["motor"], tau, rows["start"], rows["n"]) if step_f is None else step_f(tau)
    rscale = np.asarray(data.kf_rscale, np.float64)
    logit = np.asarray(innovation_variance(x[L.X_LOG_NOISE_GYRO], x[L.X_LOG_DISCREPANCY_GYRO], rscale)[1], np.float64)
    coef = np.asarray(_rate_coefficients(jnp.asarray(v, jnp.float32)), np.float64)
    gains = kf_gains(np.clip(logit, KF_LOGIT_GRID[0], KF_LOGIT_GRID[-1]))
    whiten = rows.get("whiten", np.ones((3, 1)))
    out = []
    for a in range(3):
        X = whitened_columns(y, q, f, whiten, gains[a], a)          # ψ, H A φ (6), A ỹ
        e = X[:, 7] - X[:, 1:7] @ coef[a]
        psi = X[:, 0]
        out.append(e - psi * (psi @ e) / (psi @ psi))
    return np.stack(out)


def _rate_loglik(xs, data):
    """The innovations' log-likelihood per gyro axis of each x of xs (D, 21) -> (D, 3)."""
    return jax.vmap(lambda x: _innovation_loglik(*innovations(x, data), data.kf_n))(xs)


_rate_loglik_jit = jax.jit(_rate_loglik)
rate_loglik_logs = jax.jit(jax.vmap(_rate_loglik))
""":func:`_rate_loglik` of logs of one shape at once: xs (L, D, 21) and the logs' stacked data -> (L, D, 3)."""


def log_delta_of(grid, ll) -> np.ndarray:
    """The gyro's process noise per axis (3,): the log δ of ``grid`` (D,) with the largest innovations'
    log-likelihood ``ll`` (D, 3) at the other coordinates (the empirical-Bayes δ of the inference)."""
    ll = np.asarray(ll, np.float64)
    return np.asarray(grid, np.float64)[np.argmax(np.where(np.isfinite(ll), ll, -np.inf), 0)]


def delta_grid_x(x, grid) -> np.ndarray:
    """x (21,) repeated over the gyro's log δ of ``grid`` (D,) -> (D, 21), float32."""
    xs = np.repeat(np.asarray(x, np.float32)[None], len(grid), 0)
    xs[:, L.X_LOG_DISCREPANCY_GYRO] = np.asarray(grid, np.float32)[:, None]
    return xs


def noise_estimate(data: LogData) -> np.ndarray:
    """σ per channel (4,) from the second differences alone (the maximum of their own likelihood), at
    least 1e-6 (the prior's floor: a log whose second differences are at the readings' rounding,
    :data:`QUANTISATION_VAR`)."""
    var = np.asarray(data.s2, np.float64) / np.maximum(np.asarray(data.n2), 1) / comb(4, 2) - QUANTISATION_VAR
    return np.sqrt(np.maximum(var, 1e-12))


def noise_information(log_sigma, data: LogData) -> np.ndarray:
    """The second differences' Fisher information (4,) on log σ at log σ (4,): 2 n f² with
    f = σ² / (σ² + :data:`QUANTISATION_VAR`) (it fades where σ falls below the rounding)."""
    s2 = np.exp(2.0 * np.asarray(log_sigma, np.float64))
    return 2.0 * np.asarray(data.n2, np.float64) * (s2 / (s2 + QUANTISATION_VAR)) ** 2


def _innovation_start(data: LogData):
    """Least squares on the innovations' factors: per τ_m of the grid and axis, the coefficients at
    the gain whose innovations are smallest, the τ_m with the smallest Σ log Σ e² wins -> (its grid
    index, authority × ρ_i (3, 4), rate biases (3,), the process noise δ per axis (3,))."""
    R = np.asarray(data.kf_r, np.float64)                           # (G, H, 3, 7, 7)
    c = np.linalg.solve(R[..., :6, :6] + 1e-30 * np.eye(6), R[..., :6, 6:7])[..., 0]     # (G, H, 3, 6)
    sse = np.maximum(R[..., 6, 6] ** 2, 1e-30)                      # (G, H, 3)
    h = np.argmin(sse, 1)                                           # (G, 3): the best gain per τ and axis
    cost = np.log(np.take_along_axis(sse, h[:, None], 1)[:, 0]).sum(-1)
    g = int(np.argmin(cost))
    ax = np.arange(3)
    cg = c[g, h[g], ax]                                             # (3, 6)
    n = max(float(data.kf_n), 1.0)
    S = sse[g, h[g], ax] / n
    K = kf_gains()[h[g]]
    return g, cg[:, :4] / _BASIS, cg[:, 5], list(K * np.sqrt(S))


def linear_start(data: LogData) -> np.ndarray:
    """A starting point (12 + 9,) for the optimiser from the log alone: at each τ_m of the grid the
    windows' rate changes are linear in (authority × ρ_i per rotor, c, the gyroscopic coefficient),
    so least squares per axis; the τ_m with the smallest total relative residual wins, ρ and the
    authorities come from its per-rotor coefficients, thrust-to-weight from the accelerometer
    blocks (no bias; with the drag's term where the log carries velocity), the noise from the second differences and δ from the residuals."""
    wv, bv = np.asarray(data.wmask) > 0, np.asarray(data.bmask) > 0
    fg, fa = np.asarray(data.fg, np.float64)[:, wv], np.asarray(data.fa, np.float64)[:, bv]
    dg, gyq = np.asarray(data.dgyro, np.float64)[wv], np.asarray(data.gyq, np.float64)[wv]
    acc = np.asarray(data.acc, np.float64)[bv]
    vz = np.asarray(data.vz, np.float64)[bv]
    span = float(data.span)
    if data.rates == "innovations":
        g, kk, c_rate, res = _innovation_start(data)
    else:
        G, n = fg.shape[0], len(dg)
        # every τ_m of the grid and axis at once: X (G, 3, n, 6), least squares by the pseudo-inverse
        X = np.concatenate([fg[:, None] * _BASIS[None, :, None, :].astype(np.float64),
                            np.broadcast_to(gyq.T[None, :, :, None], (G, 3, n, 1)),
                            np.full((G, 3, n, 1), span)], -1)
        d = dg.T                                                            # (3, n)
        k = np.einsum("gamn,an->gam", np.linalg.pinv(X), d)                 # (G, 3, 6)
        r = d[None] - np.einsum("gamk,gak->gam", X, k)                      # (G, 3, n)
        cost = (np.sum(r * r, -1) / np.maximum(np.sum(d * d, -1), 1e-12)).sum(1)
        g = int(np.argmin(cost))
        res = list(np.sqrt(np.mean(r[g] ** 2, -1)))
        kk = k[g, :, :4]                                                    # (3, 4): authority × ρ_i
        c_rate = k[g, :, 5]
    speed = np.asarray(data.speed, np.float64)
    log_tau0 = float(np.asarray(data.log_tau)[g]) if speed[0] <= 0 else float(speed[1])   # with speeds: their τ_m
    means = kk.mean(1, keepdims=True)
    ok = np.abs(means[:, 0]) > 1e-9
    rho = np.clip((kk[ok] / means[ok]).mean(0) if ok.any() else np.ones(4), 0.35, 1.65)
    rho = rho * 4.0 / rho.sum()
    auth = np.clip(np.abs(means[:, 0]), 11.0, 9000.0)
    f = fa[g] @ rho
    X = np.stack([P.GRAVITY / 4 * f, -vz], 1) if np.any(vz) else (P.GRAVITY / 4 * f)[:, None]
    k, *_ = np.linalg.lstsq(X, acc, rcond=None)        # thrust-to-weight (and D_z where velocity is logged)
    twr = float(np.clip(k[0], 1.1, 14.0))
    ra = acc - P.GRAVITY / 4 * twr * f + (float(np.clip(k[1], 0.0, DRAG_MAX)) * vz if len(k) > 1 else 0.0)
    az = 1.15 / (1 / auth[0] + 1 / auth[1])            # J_z a little below J_x + J_y (a flat vehicle)
    sig = noise_estimate(data)
    dl = np.maximum(np.array(res + [float(np.sqrt(np.mean(ra * ra)))]), 1e-5)
    return L.pack(L.X_FIELDS, log_thrust_to_weight=np.log(twr), rel_effectiveness=rho[:3],
                  log_motor_time_constant=log_tau0,
                  log_authority=np.log([auth[0], auth[1], max(az, 11.0)]), log_yaw_authority=np.log(auth[2]),
                  ext_acc=np.clip(c_rate, -140, 140), log_noise=np.log(sig), log_discrepancy=np.log(dl),
                  acc_z_bias=0.0).astype(np.float32)
