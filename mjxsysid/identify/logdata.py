"""A flight log reduced to what the log-grounded likelihood reads (:mod:`.likelihood`, whose doc
describes the model): the equation error's windows and accelerometer blocks cut from the log, the
rotor lag's features computed once per log on a grid of τ_m (:data:`TAU_GRID`), the IMU noise's
evidence (second differences) and, for the innovations' rate term, the gain-filtered regressors'
Gram factors — all in NumPy (float64) on the host, handed to the compiled likelihood as one
:class:`LogData` pytree whose window and block counts are padded to a power of two (:func:`bucket`:
one compiled program serves every log of a bucket).
"""
from __future__ import annotations

import dataclasses
import functools

import jax
import numpy as np
from scipy.signal import lfilter

from mjxsysid.identify.logspace import GYRO, N_CHANNELS
from mjxsysid.identify.vibration import detected_axes, gyro_whiteners
from mjxsysid.identify.speeds import (model_features, model_step_integrals, report, speed_features,
                                      speed_step_integrals, speed_term)
from mjxsysid.logs.speedmap import SKIP_S, first_row, lag_steps, speed_fit

DT = 0.002
"""s: the log's row spacing (500 Hz)."""
WINDOW_STEPS = 25
"""Control steps per half window (50 ms; a window is 100 ms). The equation error does not drift
with the window's length (the commands drive it all along; only the small gyroscopic term uses
measured rates), so the length trades the feedback bias (a controller reacts to the gyro noise:
its share falls with the samples averaged) against the rotor lag's visibility (shorter windows
see τ_m better). Measured at 5× white noise, 4 MJX flights, the log-target gap between the fitted
mode and the truth: 17–21 nats at 10 steps, 2–9 at 25, 2–11 at 50."""
DRAG_MAX = 3.0
"""1/s: the largest body drag per mass D = d / m the accelerometer's terms fit (a racing quadrotor's
is about 0.3; the simulator's priors stay below 3)."""
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
TAU_GRID = np.exp(np.linspace(np.log(0.0015), np.log(0.35), 64))
"""s: the motor time constants the window features are computed at (log-spaced)."""
RATES = "windows"
"""The rate term by default: "windows" (the windowed equation error) or "innovations" (a steady-state
Kalman filter's one-step prediction errors of the gyro, a detected rotor vibration whitened: module doc of
:mod:`.likelihood`). Measured on MJX flights of the oracle (docs/identify.md, "The rate term"): the
innovations remove the windows' closed-loop bias (τ_m's median error at × 20: 41 % -> 6 %; at × 5
vibration, whitened, 1.7 %) but their bands are too narrow and NUTS often does not mix on them, so the
windows, on whose rows the shipped calibration table was fitted, stay the default."""
KF_LOGIT_GRID = np.linspace(np.log(1e-4 / (1 - 1e-4)), np.log(0.995 / 0.005), 20)
"""logit of the Kalman gains the innovations' statistics are computed at (K from 1e-4, an almost
open-loop prediction, to 0.995, nearly the next sample's difference); a candidate's K is
interpolated between them."""
MAX_RATE_S = 30.0
"""s: the contiguous stretch of the log (after :data:`SKIP_S`) whose gyro innovations enter: the
filter needs consecutive samples; a longer log's rates only narrow bands that the process noise
already sets, and its accelerometer blocks still cover all of it."""




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
    regressors' Gram matrix with the start offset profiled out; kf_n () the innovations counted;
    kf_rscale (3,) per axis the filter's measurement-noise variance relative to σ² (1; where a rotor
    vibration was detected and whitened, :mod:`.vibration`, the whitened noise's variance over the second
    differences' σ²).
    vz (Wa,) m/s the mean velocity along body z over each accelerometer block, for the body drag's
    term (0 where the log carries no velocity: the term then vanishes). Measured rotor speeds
    (:mod:`.speeds`): speed_ll (Gs,) their evidence on τ_m at :data:`~.speeds.SPEED_TAU_GRID`, speed (3,)
    [n_eff, mean, sd of log τ under that term alone]; zeros and [0, 0, 1] without speeds (fg and fa are
    then the commands' lag features; with speeds, the fitted command→speed map's, per τ).
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
    kf_rscale: jax.Array
    vz: jax.Array
    speed_ll: jax.Array
    speed: jax.Array
    rates: str = dataclasses.field(default=RATES, metadata={"static": True})


def _lagged(u, tau, rows=None):
    """Motor commands u (T, 4) through the lag of time constant ``tau``, s_0 = u_0 -> the exact mean
    of s² over each step (the rows ``rows``, default all) and s at each step's end (T, 4)."""
    _, s_end, _, ms = lag_steps(u, tau)
    return ms[slice(None) if rows is None else rows], s_end


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


def kf_gains(logit=KF_LOGIT_GRID):
    """The Kalman gains K (H,) of logits (default :data:`KF_LOGIT_GRID`)."""
    return 1.0 / (1.0 + np.exp(-np.asarray(logit, np.float64)))


def gain_filter(x, gain):
    """(H x)_0 = 0, (H x)_{k+1} = (1 − K) (H x)_k + x_k along axis 0: the steady-state Kalman
    predictor's memory of the inputs it has seen."""
    return lfilter([0.0, 1.0], [1.0, -(1.0 - gain)], x, axis=0)


def gyro_rows(imu, start: int, n: int):
    """The rows the innovations read: gyro y (n, 3) and each step's gyroscopic products × dt (n, 3)."""
    g = imu[start:start + n, :3]
    return g, np.stack([g[:, 1] * g[:, 2], g[:, 2] * g[:, 0], g[:, 0] * g[:, 1]], -1) * DT


def step_lag(u, tau: float, start: int, n: int):
    """Each step's ∫ s_i² dt (n, 4) of the rows the innovations read, under τ_m = ``tau``."""
    return _lagged(u, tau, slice(start, start + n))[0] * DT


def _whitener(whiten, a: int):
    """Axis a's whitening A (:mod:`.vibration`) as a function of columns (n, ...) -> (n − p, ...): the
    polynomial's first p rows (its start) dropped; the identity where ``whiten`` is (3, 1)."""
    p = whiten.shape[1] - 1
    return (lambda x: x) if p == 0 else (lambda x: lfilter(whiten[a], [1.0], x, axis=0)[p:])


def _axis_columns(a: int):
    """Columns of :func:`_columns`' 12 for axis a: ψ, H f_1..4, H q_a, H 1, ỹ_a."""
    return [0, 1, 2, 3, 4, 5 + a, 8, 9 + a]


def _columns(y, q, f, gain: float):
    """The innovation columns (m, 12) of every axis at Kalman gain K, from gyro y (m, 3), products q (m, 3)
    and f (m, 4) (whitened where the log has a vibration): the start ψ_k = (1 − K)^k, H f (4: ∫ s_i² dt per
    rotor), H q (3: the gyroscopic products × dt), H dt (the rate bias), ỹ = y − K H y (3)."""
    m = len(y)
    psi = (1.0 - gain) ** np.arange(m)
    return np.concatenate([psi[:, None], gain_filter(f, gain), gain_filter(q, gain),
                           gain_filter(np.full((m, 1), DT), gain), y - gain * gain_filter(y, gain)], 1)


def whitened_columns(y, q, f, whiten, gain: float, a: int):
    """Axis a's innovation columns (m, 8) at Kalman gain K, m = n − p: ψ, H A f (4), H A q_a, H A dt, A ỹ_a
    (:func:`_columns`), from gyro y (n, 3), products q (n, 3) and f (n, 4); ``whiten`` (3, p + 1) the axes'
    whitening polynomials A (:mod:`.vibration`; (3, 1) ones: none), whose first p rows (the polynomial's
    start) are dropped."""
    A = _whitener(whiten, a)
    return _columns(A(y), A(q), A(f), gain)[:, _axis_columns(a)]


def _innovation_factors(imu, u, start: int, n: int, step_f=None, whiten=None) -> np.ndarray:
    """The innovations' sufficient statistics (G, H, 3, 7, 7), float64.

    With x̂ the predicted rate, the steady-state filter x̂_{k+1} = x̂_k + K (y_k − x̂_k) + α_k makes
    the innovations e_k = y_k − x̂_k linear in the model's coefficients: e = ỹ − Σ_j c_j H φ_j − x̂_0 ψ,
    ỹ = y − K H y, ψ_k = (1 − K)^k, φ the per-step regressors (∫ s_i² dt per rotor, the gyroscopic
    product, dt for the rate bias). Per τ_m of :data:`TAU_GRID`, gain of :data:`KF_LOGIT_GRID` and
    axis: the Gram matrix of [ψ, H φ (6), ỹ], the start x̂_0 profiled out (its Schur complement),
    as its upper Cholesky factor R (7, 7), so that Σ e² = ‖R β‖² for β = [c (6), −1]. Float64
    Gram matrices, a float32 factor: the sums of squares are formed without cancellation. ``step_f``:
    τ -> each step's ∫ s_i² dt (n, 4) from the rotor speeds (None: :func:`step_lag`'s). ``whiten``
    (3, p + 1): each axis's vibration-whitening polynomial A, applied to y and to every regressor before
    the filter (:func:`whitened_columns`; None: none, A = 1)."""
    gains = kf_gains()
    whiten = np.ones((3, 1)) if whiten is None else np.asarray(whiten, np.float64)
    y, q = gyro_rows(imu, start, n)
    shared = whiten.shape[1] == 1 or bool(np.all(whiten == whiten[:1]))     # one A for the three axes
    out = np.zeros((len(TAU_GRID), len(gains), 3, 7, 7))
    lag = (lambda tau: step_lag(u, tau, start, n)) if step_f is None else step_f
    fs = None if shared else [lag(tau) for tau in TAU_GRID]      # (n, 4) per τ, once for the three axes
    for axes in ([0, 1, 2],) if shared else ([0], [1], [2]):
        A = _whitener(whiten, axes[0])
        yw, qw = A(y), A(q)
        kcols = [_columns(yw, qw, np.zeros((len(yw), 4)), K) for K in gains]
        for gi, tau in enumerate(TAU_GRID):
            fw = A(lag(tau) if fs is None else fs[gi])
            for h, K in enumerate(gains):
                X = kcols[h]
                X[:, 1:5] = gain_filter(fw, K)
                G = X.T @ X
                for a in axes:
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
            rates: str = RATES, speeds: str = "model", vibration: bool = True,
            pad_to: tuple[int, int] | None = None, rows: bool = True) -> LogData:
    """A log's arrays (``imu`` (T, 6) the reading each row's motor command was given, ``motor``
    (T, 4) normalised rotor-speed commands, optional ``native``, ``rotor_speed``) -> :class:`LogData`.
    ``rates``: the rate term (:data:`RATES`). ``speeds``: what the thrust and torque terms read where the
    rotor speeds are used: "model", the fitted command→speed maps' speeds per τ
    (:func:`~.speeds.model_features`: a map per rotor), "shared", one map for the four rotors (a diagnostic),
    or "raw", the measured samples at every τ (a diagnostic). ``vibration``: whether the innovations whiten a
    rotor vibration detected in the gyro (:mod:`.vibration`; False, the white-noise filter alone: a diagnostic).
    ``pad_to``: (windows, blocks) padded to at least these counts (another log's: one compiled program serves
    both, :mod:`.windowcheck`). ``rows``: keep the log's rows and the host diagnostics beside the arrays
    (``_rows``: what the model checks and the report read); False, the arrays alone (a motor-map variant,
    :func:`~.idlecheck.variant`: the vibration's spectra and the body drag are not computed)."""
    if speeds not in ("model", "shared", "raw"):
        raise ValueError(f"speeds must be 'model', 'shared' or 'raw', got {speeds!r}")
    if rates not in ("innovations", "windows"):
        raise ValueError(f"rates must be 'innovations' or 'windows', got {rates!r}")
    imu = np.asarray(rec["imu"], np.float64)
    u = np.clip(np.asarray(rec["motor"], np.float64), 0.0, 1.0)
    T = len(u)
    motor_rate = motor_rate_hz(rec)
    use = np.ones(N_CHANNELS)
    if motor_rate < MIN_MOTOR_RATE_HZ:
        t_nat, u_nat = (np.asarray(a, np.float64) for a in rec["native"]["motor"])
        u = np.clip(np.stack([np.interp(rec["t"], t_nat, u_nat[:, i]) for i in range(4)], -1), 0.0, 1.0)
        use[GYRO] = 0.0
    W = int(window_steps)
    start = first_row(T)
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
    speed = speed_fit(rec, start, per_rotor=speeds != "shared")
    raw = speed["used"] and speeds == "raw"
    if raw:                  # the measured speeds, the same at every τ_m (the speed term reads τ_m)
        s = np.asarray(rec["rotor_speed"], np.float64) / speed["omega_ref_rad_s"]
        fg, fa = (np.broadcast_to(f, (len(TAU_GRID),) + f.shape) for f in speed_features(s, steps, tri, bsteps))
    elif speed["used"]:      # the fitted map's speeds per τ; the speed term pins τ_m
        fg, fa = model_features(u, speed, TAU_GRID, steps, tri, bsteps)
    else:
        fg, fa = _lag_features(u, TAU_GRID, steps, tri, bsteps)   # (G, n, 4), (G, nb, 4)
    speed_ll, speed_sum = speed_term(speed)
    g = imu[:, :3]
    half = np.arange(W)
    dgyro = g[k0[:, None] + W + half].mean(1) - g[k0[:, None] + half].mean(1)
    prod = np.stack([g[:, 1] * g[:, 2], g[:, 2] * g[:, 0], g[:, 0] * g[:, 1]], -1)
    gyq = np.einsum("nsa,s->na", prod[steps], tri) * DT
    acc = imu[bsteps + 1, 5].mean(1)
    vz = block_velocity_z(rec, bsteps + 1)
    n2, s2, ratio = noise_statistics(rec)
    kvar = np.array([2.0 * ratio / W] * 3 + [ratio / B])
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731   host arrays: a reduction sent to another process stays NumPy
    nw, nb = bucket(len(k0)), bucket(len(acc))
    if pad_to is not None:
        nw, nb = max(nw, int(pad_to[0])), max(nb, int(pad_to[1]))
    n_kf = int(min(T - 1 - start, round(MAX_RATE_S / DT)))
    step_f = None            # τ -> (n_kf, 4); picklable: a LogData may come from another process
    if raw:
        step_f = functools.partial(speed_step_integrals, s, start, n_kf)
    elif speed["used"]:
        step_f = functools.partial(model_step_integrals, u, speed, start=start, n=n_kf)
    nyquist = 0.5 * native_rate_hz(rec, "imu")     # above it a resampled gyro holds images, not rotors
    if rates == "innovations" and vibration:
        whiten, rscale = innovation_whitening(imu, start, n_kf, n2, s2, nyquist)
    else:
        whiten, rscale = np.ones((3, 1)), np.ones(3)
    kf = (_innovation_factors(imu, u, start, n_kf, step_f, whiten) if rates == "innovations"
          else np.zeros((1, 1, 3, 7, 7)))
    data = LogData(f32(np.log(TAU_GRID)), f32(_pad(fg, nw, 1)), f32(_pad(fa, nb, 1)), f32(_pad(dgyro, nw)),
                   f32(_pad(gyq, nw)), f32(_pad(acc, nb)), f32(W * DT), f32(kvar), f32(n2), f32(s2), f32(use),
                   f32(_pad(np.ones(len(k0)), nw)), f32(_pad(np.ones(len(acc)), nb)),
                   f32(_pad(REL_DISCREPANCY * np.abs(dgyro), nw)), f32(kf),
                   f32(KF_LOGIT_GRID if rates == "innovations" else KF_LOGIT_GRID[:1]), f32(n_kf - (whiten.shape[1] - 1)),
                   f32(rscale), f32(_pad(vz, nb)),
                   f32(speed_ll), f32(speed_sum), rates)
    if not rows:
        return data
    # the log's rows, for host-side diagnostics of the innovations (residual_weights): not a
    # pytree field, so never passed into a compiled program
    object.__setattr__(data, "_rows", {"imu": imu, "motor": u, "start": start, "n": n_kf,
                                       "drag_xy": drag_per_mass_xy(rec, bsteps + 1), "step_f": step_f, "whiten": whiten,
                                       "vibration": detected_axes(imu[start:start + n_kf, :3], DT, nyquist),
                                       "speed": report(speed), "rec": rec, "rec_args":
                                       {"max_windows": max_windows, "rates": rates, "speeds": speeds,
                                        "vibration": vibration}})
    return data


def innovation_whitening(imu, start: int, n: int, n2, s2, max_hz: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The innovations' vibration whitening of gyro rows [start, start + n) of ``imu`` -> (the axes'
    polynomials (3, p + 1), (3, 1) ones where no axis has a vibration; the filter's measurement-noise
    variance relative to σ² per axis (3,)), σ² the second differences' (count ``n2``, sums ``s2``, (4,)); a vibration
    looked for below ``max_hz`` only (:func:`~.vibration.noise_spectrum`)."""
    whiten, eps, found = gyro_whiteners(imu[start:start + n, :3], DT, max_hz=max_hz)
    sig2 = np.asarray(s2, np.float64)[GYRO] / np.maximum(np.asarray(n2, np.float64)[GYRO], 1) / 6.0
    rscale = np.where(found & (sig2 > 0), eps / np.maximum(sig2, 1e-30), 1.0)
    return whiten, rscale


def vibrating(data: LogData) -> bool:
    """Whether a prepared log's gyro shows a rotor vibration on any axis (:func:`~.vibration.detected_axes`,
    whichever rate term reads it); False for a LogData not prepared in this process."""
    return bool(np.any(getattr(data, "_rows", {}).get("vibration", False)))


def has_velocity(rec: dict) -> bool:
    """Whether a log carries a usable body-frame velocity (``velocity_body`` (T, 3), finite)."""
    vb = rec.get("velocity_body")
    return vb is not None and np.shape(vb) == (len(rec["motor"]), 3) and bool(np.all(np.isfinite(vb)))


def block_velocity_z(rec: dict, rows) -> np.ndarray:
    """The mean body-z velocity (m/s) over each block of ``rows`` (nb, B) -> (nb,); zeros where the log
    carries no velocity (:func:`has_velocity`)."""
    if not has_velocity(rec):
        return np.zeros(len(rows))
    return np.asarray(rec["velocity_body"], np.float64)[rows, 2].mean(1)


def drag_per_mass_xy(rec: dict, rows) -> np.ndarray | None:
    """The body x and y drag per mass (2,) 1/s, in [0, :data:`DRAG_MAX`]: the accelerometer's x and y read
    −D v in the body frame (plus a bias and whatever else pushes sideways), so least squares of their
    block means (``rows`` (nb, B)) on the log's body velocity and a constant; None without velocity."""
    if not has_velocity(rec) or len(rows) < 3:
        return None
    imu, vb = np.asarray(rec["imu"], np.float64), np.asarray(rec["velocity_body"], np.float64)
    out = []
    for a in (0, 1):
        v = vb[rows, a].mean(1)
        k, *_ = np.linalg.lstsq(np.stack([-v, np.ones_like(v)], 1), imu[rows, 3 + a].mean(1), rcond=None)
        out.append(float(np.clip(k[0], 0.0, DRAG_MAX)))
    return np.array(out)


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
    return native_rate_hz(rec, "motor")


def native_rate_hz(rec: dict, name: str) -> float:
    """The rate (Hz) column ``name`` ("motor", "imu") was logged at: its native samples' where the log
    carries them (``rec["native"][name]``), else 500."""
    nat = (rec.get("native") or {}).get(name)
    if nat is None or len(nat[0]) < 3:
        return 1.0 / DT
    return float(1.0 / max(np.median(np.diff(np.asarray(nat[0], np.float64))), 1e-9))
