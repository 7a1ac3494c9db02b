"""The likelihood of a flight log's IMU given its motor commands, under a candidate vehicle.

Equation error over short windows started from the measured state (no open-loop rollout): the
log is cut into non-overlapping windows of 2 × :data:`WINDOW_STEPS` control steps; in each,

- the change of the measured body rates — the mean over the window's second half minus the mean
  over its first — is compared with the integral of the angular acceleration the motor commands
  imply (Euler's equation, :mod:`.coords`), each step weighted by how much of it lies between
  the two halves (a triangle), the gyroscopic term from the measured rates. Half-window means,
  not two samples: a feedback controller reacts to the gyro's noise, so the noise of a single
  start sample is correlated with the commands that follow and biases the fit (seen: at 5× the
  hardware-like white noise τ_m came out 25 % low and the yaw authority 4× high); averaged over W
  samples its share shrinks W-fold;
- the mean measured specific force along body z over blocks of :data:`ACC_BLOCK_STEPS` is
  compared with the thrust the commands imply, plus an accelerometer bias.

The rotor speeds are the commands through the simulator's first-order lag, integrated exactly
(:func:`~mjxsysid.sim.quadrotor.mean_square_speed`: the exact mean of s² over each step for the
rates, the end-of-step s² for the accelerometer). The lag depends on τ_m alone, so the window
sums of s² are computed once per log on a grid of τ_m (:data:`TAU_GRID`) and interpolated in
log τ_m per candidate: a candidate then costs a few multiply-adds per window, and thousands are
evaluated in one jitted call.

Residuals are Student-t (ν = :data:`NU`: heavy tails for glitches), with a scale per channel
(gyro x, y, z, accelerometer z) of √(k σ² + δ²): σ the IMU's white-noise level per sample
(k = 2 / W for a difference of two means of W gyro samples, 1 / W_eff for a mean of W_eff
independent accelerometer samples) and δ a model-discrepancy term for physics the model lacks (aerodynamics,
another simulator's motors, drag). σ is a parameter with its own evidence — the log's second
differences, which for white noise have variance 6 σ² while a rigid body's signal barely enters
— so the noise level is estimated jointly, not assumed; δ has only the residuals.

**The rate term, two ways** (``rates``, :data:`RATES`). The half-window means shrink the feedback
bias but do not remove it: the noise of a window's first half still reaches the commands that follow
(measured on MJX flights of the oracle: τ_m 1.18× at 5× white noise, 1.56× at 20×). ``"innovations"``
is the prediction-error method's answer (Ljung, *System Identification*, §13: consistent in closed
loop when the noise model holds): a steady-state Kalman filter of each body rate (state ω, process
noise δ² per step for what the model lacks, measurement noise σ²) predicts every gyro sample from
the samples before it and the commands before it; its innovations are independent of everything
the controller saw, so the commands' reaction to the noise no longer correlates with the errors.
The innovations are linear in the model's coefficients once τ_m and the gain are fixed, so their
sums of squares come from Gram matrices computed once per log on a grid of τ_m × gain
(:func:`_innovation_factors`) and interpolated per candidate, as the windows' sums are; the
filter's start is profiled out. Gaussian (no heavy tails), and white measurement noise assumed: a
rotor vibration (a narrow-band, command-dependent component) breaks that assumption, which is why
the windows, which average it out, stay the default (docs/identify.md, "The rate term").
"""
from __future__ import annotations

import dataclasses
from math import comb

import jax
import jax.numpy as jnp
import numpy as np
from scipy.signal import lfilter

from mjxsysid import theta as P
from mjxsysid.identify.coords import N_V

DT = 0.002
"""s: the log's row spacing (500 Hz)."""
WINDOW_STEPS = 25
"""Control steps per half window (50 ms; a window is 100 ms). The equation error does not drift
with the window's length (the commands drive it all along; only the small gyroscopic term uses
measured rates), so the length trades the feedback bias (a controller reacts to the gyro noise:
its share falls with the samples averaged) against the rotor lag's visibility (shorter windows
see τ_m better). Measured at 5× white noise, 4 MJX flights, the log-target gap between the fitted
mode and the truth: 17–21 nats at 10 steps, 2–9 at 25, 2–11 at 50."""
ACC_BLOCK_STEPS = 250
"""Control steps (0.5 s) over which the accelerometer residual is averaged: the specific force's
largest unmodelled term, drag (−D_z v_z / m, the velocity not in an IMU log), varies over the
manoeuvre's seconds, not the 20 ms windows; residuals of 20 ms would be strongly correlated and
the thrust-to-weight overconfident."""
REL_DISCREPANCY = 0.003
"""The rate windows' model floor, relative to each window's measured rate change: thrust and
torque coefficients that vary a little with the rotor's inflow, a motor's nonlinearity, float32
sums — errors that grow with the signal. Without it a clean simulated log's authorities came out
0.07 % wide and missed a truth 0.1 % away (40 MJX flights: 90 % coverage 0.40–0.68)."""
MIN_MOTOR_RATE_HZ = 100.0
"""Hz: motor commands logged more sparsely than this (PX4's default 10 Hz) are interpolated
linearly between their samples for the thrust, and the rate windows are not used: a rotor follows
its command within tens of ms, so 20 ms rate changes cannot be explained by commands 100 ms apart
(τ_m and the authorities then stay as broad as the prior, and the posterior says so)."""
MAX_WINDOWS = 256
"""Rate windows used at most (evenly spaced over a longer log: 25.6 s of 100 ms windows), and
accelerometer blocks (128 s of 0.5 s blocks). The posterior's cost grows with them (a 60 s log's 590
windows made `decode --log` 72–92 s slower on 2 cores; a 10-minute log's 1,198 blocks, padded to
2,048, made its SMC 4× slower than a 10 s log's); a longer log's extra windows would only narrow
bands that the discrepancy and correlation terms, not the count, already set."""
SKIP_S = (0.2, 1.0)
"""s: the start of the log not used — a tenth of it, within these bounds. The rotor speeds are
reconstructed from the commands starting at the first command; a log that starts with rotors at
another speed (a take-off, a simulator's hover start) is wrong there for about 5 τ_m, and those
windows would dominate the residuals (seen: a 10 s MJX flight's rate residuals were 10× larger
with 0.2 s skipped than with 1 s)."""
TAU_GRID = np.exp(np.linspace(np.log(0.0015), np.log(0.35), 64))
"""s: the motor time constants the window features are computed at (log-spaced)."""
NU = 4.0
"""Degrees of freedom of the Student-t residuals (the windows' rate term and the accelerometer)."""
RATES = "windows"
"""The rate term by default: "windows" (the windowed equation error) or "innovations" (a steady-state
Kalman filter's one-step prediction errors of the gyro, module doc). Measured on 96 MJX flights of the
oracle (docs/identify.md, "The rate term"): the innovations remove the windows' closed-loop bias under
white IMU noise (τ_m's median error at × 20: 57 % -> 4 %) but read a rotor vibration as rate signal
(at × 5 vibration τ_m 95 % off, the authorities 140 %); until their noise model holds a vibration,
the windows stay the default."""
KF_LOGIT_GRID = np.linspace(np.log(1e-4 / (1 - 1e-4)), np.log(0.995 / 0.005), 20)
"""logit of the Kalman gains the innovations' statistics are computed at (K from 1e-4, an almost
open-loop prediction, to 0.995, nearly the next sample's difference); a candidate's K is
interpolated between them."""
MAX_RATE_S = 30.0
"""s: the contiguous stretch of the log (after :data:`SKIP_S`) whose gyro innovations enter: the
filter needs consecutive samples; a longer log's rates only narrow bands that the process noise
already sets, and its accelerometer blocks still cover all of it."""
CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "acc_z")
RESOLUTION = np.array([1e-4, 1e-4, 1e-4, 1e-3], np.float32)
"""rad/s, m/s²: the finest residual scale per channel — a logged number's resolution (a 16-bit
gyro at ±2000 °/s has 1e-3 rad/s steps; a CSV with 7 digits ~1e-5 relative): without a floor a
noise-free simulated log would make every model error infinitely significant."""
N_NUIS = 9
"""Nuisance parameters after v: log σ (4: gyro x, y, z, acc z), log δ (4, same channels), acc_z bias."""
NUIS_NAMES = tuple(f"log_noise[{c}]" for c in CHANNELS) + tuple(f"log_discrepancy[{c}]" for c in CHANNELS) + (
    "acc_z_bias",)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class LogData:
    """A log reduced to what the likelihood reads (arrays; W windows, G grid points).

    log_tau (G,); fg (G, W, 4) ∫ s_i² dt over each window per rotor; fa (G, Wa, 4) mean
    end-of-step s_i² over each accelerometer block (:data:`ACC_BLOCK_STEPS`); dgyro (W, 3) measured rate change; gyq (W, 3) ∫ of the
    gyroscopic products (ω_y ω_z, ω_z ω_x, ω_x ω_y) over each window; acc (Wa,) mean measured
    acc_z per block; span () s per window; kvar (4,) the noise-variance factor per channel; n2 (4,),
    s2 (4,) count and sum of squares of the channels' second differences (trimmed); use (4,) 1 for
    a channel the likelihood reads, 0 for one it cannot (the rates when the motors were logged
    below :data:`MIN_MOTOR_RATE_HZ`); wmask (W,), bmask (Wa,) 1 for a window / block of the log, 0
    for the padding that rounds their counts up to :func:`bucket` (one compiled program serves
    every log of a bucket); gfloor (W, 3) each window's relative model floor
    (:data:`REL_DISCREPANCY` × its measured rate change). The innovations' sufficient statistics
    (:func:`_innovation_factors`): kf_r (G, H, 3, 7, 7) per τ_m, per Kalman gain of
    :data:`KF_LOGIT_GRID` (kf_logit (H,)) and per axis, the upper Cholesky factor of the gain-filtered
    regressors' Gram matrix with the start offset profiled out; kf_n () the innovations counted.
    ``rates`` (static): which rate term :func:`log_likelihood` reads, "innovations" or "windows"."""
    log_tau: jax.Array
    fg: jax.Array
    fa: jax.Array
    dgyro: jax.Array
    gyq: jax.Array
    acc: jax.Array
    span: jax.Array
    kvar: jax.Array
    n2: jax.Array
    s2: jax.Array
    use: jax.Array
    wmask: jax.Array
    bmask: jax.Array
    gfloor: jax.Array
    kf_r: jax.Array
    kf_logit: jax.Array
    kf_n: jax.Array
    rates: str = dataclasses.field(default=RATES, metadata={"static": True})


def _lagged(u, tau, rows=None):
    """Motor commands u (T, 4) through the lag of time constant ``tau``, s_0 = u_0 -> the exact mean
    of s² over each step (the rows ``rows``, default all) and s at each step's end (T, 4)."""
    a = np.exp(-DT / tau)
    # s_{k+1} = a s_k + (1 − a) u_k, s_0 = u_0
    s_end = lfilter([1 - a], [1, -a], u, axis=0, zi=(a * u[0])[None])[0]
    rows = slice(None) if rows is None else rows
    d = np.concatenate([u[:1], s_end[:-1]], 0)[rows] - u[rows]      # start of each step − command
    us = u[rows]
    r1 = tau / DT * (1 - a)
    r2 = tau / (2 * DT) * (1 - a * a)
    return us * us + 2 * us * d * r1 + d * d * r2, s_end


def _lag_features(u, taus, steps, tri, bsteps):
    """Motor commands u (T, 4) through the lag for every τ in ``taus`` (G,), starting at s = u[0],
    reduced at once to what the likelihood reads -> the windows' triangle-weighted sums of the mean
    s² over each step (G, n, 4) (``steps`` (n, S), weights ``tri`` (S,)) and the blocks' mean s² at
    the steps' ends (G, nb, 4) (``bsteps`` (nb, B)). One τ at a time: memory stays O(T), not
    O(G T) (a one-hour log has 1.8 M steps)."""
    fg, fa = [], []
    for tau in taus:
        ms, s_end = _lagged(u, tau, steps)
        fg.append(np.einsum("nsr,s->nr", ms, tri) * DT)
        fa.append((s_end[bsteps] ** 2).mean(1))
    return np.stack(fg), np.stack(fa)


def _gains(logit=KF_LOGIT_GRID):
    return 1.0 / (1.0 + np.exp(-np.asarray(logit, np.float64)))


def _gain_filter(x, gain):
    """(H x)_0 = 0, (H x)_{k+1} = (1 − K) (H x)_k + x_k along axis 0: the steady-state Kalman
    predictor's memory of the inputs it has seen."""
    return lfilter([0.0, 1.0], [1.0, -(1.0 - gain)], x, axis=0)


def _gyro_rows(imu, start: int, n: int):
    """The rows the innovations read: gyro y (n, 3) and each step's gyroscopic products × dt (n, 3)."""
    g = imu[start:start + n, :3]
    return g, np.stack([g[:, 1] * g[:, 2], g[:, 2] * g[:, 0], g[:, 0] * g[:, 1]], -1) * DT


def _step_lag(u, tau: float, start: int, n: int):
    """Each step's ∫ s_i² dt (n, 4) of the rows the innovations read, under τ_m = ``tau``."""
    return _lagged(u, tau, slice(start, start + n))[0] * DT


def _axis_columns(a: int):
    """Columns of :func:`_innovation_factors`' 12 for axis a: ψ, H f_1..4, H q_a, H 1, ỹ_a."""
    return [0, 1, 2, 3, 4, 5 + a, 8, 9 + a]


def _innovation_factors(imu, u, start: int, n: int) -> np.ndarray:
    """The innovations' sufficient statistics (G, H, 3, 7, 7), float64.

    With x̂ the predicted rate, the steady-state filter x̂_{k+1} = x̂_k + K (y_k − x̂_k) + α_k makes
    the innovations e_k = y_k − x̂_k linear in the model's coefficients: e = ỹ − Σ_j c_j H φ_j − x̂_0 ψ,
    ỹ = y − K H y, ψ_k = (1 − K)^k, φ the per-step regressors (∫ s_i² dt per rotor, the gyroscopic
    product, dt for the rate bias). Per τ_m of :data:`TAU_GRID`, gain of :data:`KF_LOGIT_GRID` and
    axis: the Gram matrix of [ψ, H φ (6), ỹ], the start x̂_0 profiled out (its Schur complement),
    as its upper Cholesky factor R (7, 7), so that Σ e² = ‖R β‖² for β = [c (6), −1]. Float64
    Gram matrices, a float32 factor: the sums of squares are formed without cancellation."""
    gains = _gains()
    y, q = _gyro_rows(imu, start, n)
    kcols = []
    for K in gains:
        psi = (1.0 - K) ** np.arange(n)
        kcols.append(np.concatenate([psi[:, None], np.zeros((n, 4)), _gain_filter(q, K),
                                     _gain_filter(np.full((n, 1), DT), K), y - K * _gain_filter(y, K)], 1))
    out = np.zeros((len(TAU_GRID), len(gains), 3, 7, 7))
    for gi, tau in enumerate(TAU_GRID):
        f = _step_lag(u, tau, start, n)
        for h, K in enumerate(gains):
            X = kcols[h]
            X[:, 1:5] = _gain_filter(f, K)
            G = X.T @ X
            for a in range(3):
                c = _axis_columns(a)
                Ga = G[np.ix_(c, c)]
                out[gi, h, a] = Ga[1:, 1:] - np.outer(Ga[1:, 0], Ga[0, 1:]) / max(Ga[0, 0], 1e-300)
    jitter = 1e-12 * np.einsum("...ii->...", out)[..., None, None] * np.eye(7) + 1e-300 * np.eye(7)
    return np.swapaxes(np.linalg.cholesky(out + jitter), -1, -2)


def noise_statistics(rec: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Second differences of gyro x/y/z and acc z per native sample (the native samples if the log
    says it was resampled: ``rec["native"]["imu"]``), trimmed at 6 robust spreads -> count (4,),
    sum of squares (4,) (variance 6 σ² per sample for white noise), and the native sample spacing
    relative to 2 ms (≥ 1)."""
    native = (rec.get("native") or {}).get("imu")
    if native is not None:
        t_nat, imu = np.asarray(native[0], np.float64), np.asarray(native[1], np.float64)
        ratio = max(float(np.median(np.diff(t_nat))) / DT, 1.0) if len(t_nat) > 2 else 1.0
    else:
        imu, ratio = np.asarray(rec["imu"], np.float64), 1.0
    x = imu[:, [0, 1, 2, 5]]
    d = np.diff(x, n=2, axis=0)[::3]          # every third: independent for white noise
    mad = 1.4826 * np.median(np.abs(d - np.median(d, 0)), 0) + 1e-12
    keep = np.abs(d) <= 6 * mad
    return keep.sum(0).astype(np.float64), np.where(keep, d * d, 0.0).sum(0), np.asarray(ratio)


class LogTooShort(ValueError):
    """A log with fewer rate windows than the likelihood needs (:func:`prepare`)."""


def prepare(rec: dict, *, window_steps: int = WINDOW_STEPS, max_windows: int = MAX_WINDOWS,
            rates: str = RATES) -> LogData:
    """A log's arrays (``imu`` (T, 6) the reading each row's motor command was given, ``motor``
    (T, 4) normalised rotor-speed commands, optional ``native``) -> :class:`LogData`. ``rates``:
    the rate term (:data:`RATES`)."""
    if rates not in ("innovations", "windows"):
        raise ValueError(f"rates must be 'innovations' or 'windows', got {rates!r}")
    imu = np.asarray(rec["imu"], np.float64)
    u = np.clip(np.asarray(rec["motor"], np.float64), 0.0, 1.0)
    T = len(u)
    motor_rate = motor_rate_hz(rec)
    use = np.ones(4)
    if motor_rate < MIN_MOTOR_RATE_HZ:
        t_nat, u_nat = (np.asarray(a, np.float64) for a in rec["native"]["motor"])
        u = np.clip(np.stack([np.interp(rec["t"], t_nat, u_nat[:, i]) for i in range(4)], -1), 0.0, 1.0)
        use[:3] = 0.0
    W = int(window_steps)
    start = int(round(float(np.clip(0.1 * T * DT, *SKIP_S)) / DT))
    n_win = (T - 1 - start) // (2 * W)
    if n_win < 5:
        raise LogTooShort(f"flight log: {T} rows ({T * DT:.2f} s) leave {max(n_win, 0)} windows of {2 * W} steps for the "
                         f"log-grounded posterior; need at least 5 ({(10 * W * DT + SKIP_S[0]):.1f} s of flight); "
                         f"decode it with --decoder-only")
    k0 = start + 2 * W * np.arange(n_win)
    if n_win > max_windows:
        k0 = k0[np.linspace(0, n_win - 1, max_windows).astype(int)]
    # the difference of the mean rates over the window's second and first halves is the steps'
    # rate changes weighted by a triangle (1/W … 1 … 1/W): see the module doc
    steps = k0[:, None] + np.arange(2 * W - 1)[None]       # (n, 2W − 1)
    tri = np.concatenate([np.arange(1, W + 1), np.arange(W - 1, 0, -1)]) / W
    B = int(ACC_BLOCK_STEPS)
    n_blk = (T - 1 - start) // B
    if n_blk < 2:                       # a short log: blocks of what there is
        B = max((T - 1 - start) // 2, W)
        n_blk = (T - 1 - start) // B
    b0 = start + B * np.arange(n_blk)
    if n_blk > max_windows:             # as the windows: evenly spaced over a longer log
        b0 = b0[np.linspace(0, n_blk - 1, max_windows).astype(int)]
    bsteps = b0[:, None] + np.arange(B)[None]
    fg, fa = _lag_features(u, TAU_GRID, steps, tri, bsteps)   # (G, n, 4), (G, nb, 4)
    g = imu[:, :3]
    half = np.arange(W)
    dgyro = g[k0[:, None] + W + half].mean(1) - g[k0[:, None] + half].mean(1)
    prod = np.stack([g[:, 1] * g[:, 2], g[:, 2] * g[:, 0], g[:, 0] * g[:, 1]], -1)
    gyq = np.einsum("nsa,s->na", prod[steps], tri) * DT
    acc = imu[bsteps + 1, 5].mean(1)
    n2, s2, ratio = noise_statistics(rec)
    kvar = np.array([2.0 * ratio / W] * 3 + [ratio / B])
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    nw, nb = bucket(len(k0)), bucket(len(acc))
    n_kf = int(min(T - 1 - start, round(MAX_RATE_S / DT)))
    kf = _innovation_factors(imu, u, start, n_kf) if rates == "innovations" else np.zeros((1, 1, 3, 7, 7))
    data = LogData(f32(np.log(TAU_GRID)), f32(_pad(fg, nw, 1)), f32(_pad(fa, nb, 1)), f32(_pad(dgyro, nw)),
                   f32(_pad(gyq, nw)), f32(_pad(acc, nb)), f32(W * DT), f32(kvar), f32(n2), f32(s2), f32(use),
                   f32(_pad(np.ones(len(k0)), nw)), f32(_pad(np.ones(len(acc)), nb)),
                   f32(_pad(REL_DISCREPANCY * np.abs(dgyro), nw)), f32(kf),
                   f32(KF_LOGIT_GRID if rates == "innovations" else KF_LOGIT_GRID[:1]), f32(n_kf), rates)
    # the log's rows, for host-side diagnostics of the innovations (residual_weights): not a
    # pytree field, so never passed into a compiled program
    object.__setattr__(data, "_rows", {"imu": imu, "motor": u, "start": start, "n": n_kf})
    return data


def bucket(n: int) -> int:
    """The padded count of ``n`` windows or blocks: the next power of two, at least 16."""
    return max(16, 1 << int(np.ceil(np.log2(max(n, 1)))))


def _pad(a, n: int, axis: int = 0):
    width = [(0, 0)] * a.ndim
    width[axis] = (0, n - a.shape[axis])
    return np.pad(a, width)


def motor_rate_hz(rec: dict) -> float:
    """The rate (Hz) the motor commands were logged at: their native samples' if the log says it
    was resampled (``rec["native"]["motor"]``), else 500."""
    nat = (rec.get("native") or {}).get("motor")
    if nat is None or len(nat[0]) < 3:
        return 1.0 / DT
    return float(1.0 / max(np.median(np.diff(np.asarray(nat[0], np.float64))), 1e-9))


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
    return jnp.concatenate([v[1:4], (4.0 - v[1] - v[2] - v[3])[None]])


def _rate_coefficients(v):
    """The rate model's coefficients per axis (3, 6) under v (12,): authority × the basis × ρ_i per
    rotor (4), the gyroscopic coefficient (from the inertia ratios), the rate bias c — what multiplies
    each step's ∫ s_i² dt, gyroscopic product and dt (the innovations' β without its −1)."""
    auth = jnp.exp(jnp.concatenate([v[5:7], v[8:9]]))        # roll, pitch authority; yaw authority
    inv = 1.0 / jnp.exp(v[5:8])                               # ∝ J
    gyro_coef = jnp.stack([(inv[1] - inv[2]) / inv[0], (inv[2] - inv[0]) / inv[1], (inv[0] - inv[1]) / inv[2]])
    return jnp.concatenate([auth[:, None] * jnp.asarray(_BASIS) * _rho(v)[None], gyro_coef[:, None], v[9:12, None]], 1)


def predict(v, data: LogData):
    """The windows' predicted rate changes (W, 3) and the blocks' mean acc_z without bias (Wa,) under the
    visible coordinates v (12,) (:mod:`.coords`)."""
    fg = _interp(v[4], data.log_tau, data.fg)               # (W, 4)
    fa = _interp(v[4], data.log_tau, data.fa)
    c = _rate_coefficients(v)
    dgyro = fg @ c[:, :4].T + c[:, 4] * data.gyq + c[:, 5] * data.span
    acc = P.GRAVITY / 4.0 * jnp.exp(v[0]) * (fa @ _rho(v))
    return dgyro, acc


def innovation_variance(log_sigma, log_delta):
    """The steady-state filter per gyro axis from the noise σ (3,) and the process noise δ (3,) per
    step (both log): (innovation variance S (3,), logit of the gain K = P / (P + r)), with
    r = σ² + the resolution², P the predicted state's variance, P = (Q + √(Q² + 4 Q r)) / 2."""
    r = jnp.exp(2 * log_sigma) + jnp.asarray(RESOLUTION[:3]) ** 2
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
    v, ls, ld = x[:N_V], x[N_V:N_V + 3], x[N_V + 4:N_V + 7]
    s, logit = innovation_variance(ls, ld)
    r = _interp2(v[4], logit, data)                                  # (3, 7, 7)
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
    v, ls, ld, bias = x[:N_V], x[N_V:N_V + 4], x[N_V + 4:N_V + 8], x[N_V + 8]
    dgyro, acc = predict(v, data)
    var = data.kvar * jnp.exp(2 * ls) + jnp.exp(2 * ld) + jnp.asarray(RESOLUTION) ** 2
    ra, sa = (data.acc - acc - bias) * data.bmask, jnp.sqrt(var[3])
    if data.rates == "innovations":
        z, s = innovations(x, data)
        return z, jnp.broadcast_to(jnp.sqrt(s), z.shape), ra, sa
    return ((data.dgyro - dgyro) * data.wmask[:, None], jnp.sqrt(var[:3] + data.gfloor ** 2), ra, sa)


residuals_jit = jax.jit(residuals)
""":func:`residuals` compiled (once per log bucket): what host-side callers use."""


def log_likelihood(x, data: LogData, weights=None):
    """log p(log | v, nuisances) for one parameter vector x (12 + 9,) = [v, log σ (4), log δ (4),
    acc_z bias]: the Student-t window residuals plus the second differences' evidence on σ.
    ``weights`` (4,): each channel's residual term multiplied by it (default 1: see
    :func:`residual_weights`); a channel the log cannot inform (``data.use``) counts 0."""
    rg, sg, ra, sa = residuals(x, data)
    w = data.use if weights is None else data.use * weights
    sig2 = jnp.exp(2 * x[N_V:N_V + 4])
    if data.rates == "innovations":
        res = jnp.sum(w[:3] * _innovation_loglik(rg, sg[0] ** 2, data.kf_n)) + w[3] * _student_t(ra, sa, data.bmask)
    else:
        wm = data.wmask
        res = (w[0] * _student_t(rg[:, 0], sg[:, 0], wm) + w[1] * _student_t(rg[:, 1], sg[:, 1], wm)
               + w[2] * _student_t(rg[:, 2], sg[:, 2], wm) + w[3] * _student_t(ra, sa, data.bmask))
    var2 = comb(4, 2) * sig2                                 # variance of a second difference
    noise = jnp.sum(-0.5 * data.n2 * jnp.log(var2) - 0.5 * data.s2 / var2)
    return res + noise


def residual_weights(x, data: LogData) -> np.ndarray:
    """Per channel (4,), the weight that makes correlated residuals count as the independent
    evidence they are worth: at the parameters x (21,), the lag-1 autocorrelation φ of each
    channel's residuals in time order gives (1 − φ)/(1 + φ) (the variance of a mean of an AR(1)
    sequence over the white one's), 1 for φ ≤ 0, at least 0.02. A model error that follows the
    manoeuvre (a clean log's residuals are not white) then widens the posterior instead of being
    counted once per window."""
    rg, _, ra, _ = residuals_jit(jnp.asarray(x, jnp.float32), data)
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
    """The gyro's innovations (3, n) under x (21,), in time order (host, float64; the start offset
    profiled out as in the likelihood): what :func:`residual_weights` reads for the rates."""
    rows = getattr(data, "_rows", None)
    if rows is None:
        raise ValueError("this LogData has no log rows (made by prepare() in this process?): cannot form its innovations")
    x = np.asarray(x, np.float64)
    v = x[:N_V]
    y, q = _gyro_rows(rows["imu"], rows["start"], rows["n"])
    f = _step_lag(rows["motor"], float(np.exp(v[4])), rows["start"], rows["n"])
    logit = np.asarray(innovation_variance(x[N_V:N_V + 3], x[N_V + 4:N_V + 7])[1], np.float64)
    coef = np.asarray(_rate_coefficients(jnp.asarray(v, jnp.float32)), np.float64)
    gains = _gains(np.clip(logit, KF_LOGIT_GRID[0], KF_LOGIT_GRID[-1]))
    n = len(y)
    out = []
    for a in range(3):
        K = gains[a]
        X = np.concatenate([_gain_filter(f, K), _gain_filter(q[:, a:a + 1], K), _gain_filter(np.full((n, 1), DT), K)], 1)
        e = y[:, a] - K * _gain_filter(y[:, a], K) - X @ coef[a]
        psi = (1.0 - K) ** np.arange(n)
        out.append(e - psi * (psi @ e) / (psi @ psi))
    return np.stack(out)


def best_log_delta(x, data: LogData, grid: np.ndarray) -> np.ndarray:
    """Per gyro axis (3,), the process noise log δ of ``grid`` (D,) that maximises the innovations'
    likelihood at the other coordinates of x (21,) (the empirical-Bayes δ of the inference)."""
    xs = np.repeat(np.asarray(x, np.float32)[None], len(grid), 0)
    xs[:, N_V + 4:N_V + 7] = np.asarray(grid, np.float32)[:, None]
    ll = np.asarray(_rate_loglik_jit(jnp.asarray(xs), data), np.float64)       # (D, 3)
    return np.asarray(grid, np.float64)[np.argmax(np.where(np.isfinite(ll), ll, -np.inf), 0)]


@jax.jit
def _rate_loglik_jit(xs, data):
    return jax.vmap(lambda x: _innovation_loglik(*innovations(x, data), data.kf_n))(xs)


def noise_estimate(data: LogData) -> np.ndarray:
    """σ per channel (4,) from the second differences alone (the maximum of their own likelihood)."""
    return np.sqrt(np.asarray(data.s2) / np.maximum(np.asarray(data.n2), 1) / comb(4, 2))


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
    K = _gains()[h[g]]
    return g, cg[:, :4] / _BASIS, cg[:, 5], list(K * np.sqrt(S))


def linear_start(data: LogData) -> np.ndarray:
    """A starting point (12 + 9,) for the optimiser from the log alone: at each τ_m of the grid the
    windows' rate changes are linear in (authority × ρ_i per rotor, c, the gyroscopic coefficient),
    so least squares per axis; the τ_m with the smallest total relative residual wins, ρ and the
    authorities come from its per-rotor coefficients, thrust-to-weight from the accelerometer
    blocks (no bias), the noise from the second differences and δ from the residuals."""
    wv, bv = np.asarray(data.wmask) > 0, np.asarray(data.bmask) > 0
    fg, fa = np.asarray(data.fg, np.float64)[:, wv], np.asarray(data.fa, np.float64)[:, bv]
    dg, gyq = np.asarray(data.dgyro, np.float64)[wv], np.asarray(data.gyq, np.float64)[wv]
    acc = np.asarray(data.acc, np.float64)[bv]
    span = float(data.span)
    if data.rates == "innovations":
        g, kk, c_rate, res = _innovation_start(data)
    else:
        best = None
        for g in range(fg.shape[0]):
            coefs, cost, res = [], 0.0, []
            for a in range(3):
                X = np.concatenate([fg[g] * _BASIS[a], gyq[:, a:a + 1], np.full((len(dg), 1), span)], 1)
                k, *_ = np.linalg.lstsq(X, dg[:, a], rcond=None)
                r = dg[:, a] - X @ k
                cost += float(r @ r) / max(float(dg[:, a] @ dg[:, a]), 1e-12)
                coefs.append(k)
                res.append(np.sqrt(np.mean(r * r)))
            if best is None or cost < best[0]:
                best = (cost, g, coefs, res)
        _, g, coefs, res = best
        kk = np.stack([c[:4] for c in coefs])                             # (3, 4): authority × ρ_i
        c_rate = np.array([c[5] for c in coefs])
    means = kk.mean(1, keepdims=True)
    ok = np.abs(means[:, 0]) > 1e-9
    rho = np.clip((kk[ok] / means[ok]).mean(0) if ok.any() else np.ones(4), 0.35, 1.65)
    rho = rho * 4.0 / rho.sum()
    auth = np.clip(np.abs(means[:, 0]), 11.0, 9000.0)
    f = fa[g] @ rho
    twr = float(np.clip(4.0 / P.GRAVITY * (acc @ f) / max(float(f @ f), 1e-12), 1.1, 14.0))
    ra = acc - P.GRAVITY / 4 * twr * f
    az = 1.15 / (1 / auth[0] + 1 / auth[1])            # J_z a little below J_x + J_y (a flat vehicle)
    v = np.concatenate([[np.log(twr)], rho[:3], [float(np.asarray(data.log_tau)[g])],
                        np.log([auth[0], auth[1], max(az, 11.0)]), [np.log(auth[2])],
                        np.clip(c_rate, -140, 140)])
    sig = np.maximum(noise_estimate(data), 1e-6)
    dl = np.maximum(np.array(res + [float(np.sqrt(np.mean(ra * ra)))]), 1e-5)
    return np.concatenate([v, np.log(sig), np.log(dl), [0.0]]).astype(np.float32)
