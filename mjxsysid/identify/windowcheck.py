"""The window-length check: does the fit of the rate coordinates move with the rate windows' length?

The rate term's equation error (:mod:`.likelihood`) holds for any window length where the model holds: a
window's rate change is the commands' integral whatever its span. Physics the model lacks does not
average out the same way at every length: a rate loop that answers a disturbance within the window
makes the commands carry the disturbance with the opposite sign, and the longer the window the more of
that the fit takes for a weak actuator (a Crazyflie's roll authority: 151 rad/s² from 20 ms windows,
117 from 100 ms, 63 from 200 ms). So:

- the log is reduced again with windows of :data:`WINDOW_FACTORS` × :data:`~.logdata.WINDOW_STEPS`
  steps, padded to the default reduction's window and block counts (the same shapes: the mode's compiled
  least squares serves them);
- from the posterior's mode, the visible coordinates are re-fitted on each (Levenberg–Marquardt of the
  mode, :func:`~.mode._fit_ls`, with σ held and δ re-set from the residuals, :data:`ROUNDS` times);
- the statistic is the largest shift of the :data:`CHECKED` coordinates (log units) from the mode's
  values, each over the shift the IMU noise explains: a closed loop reacts to the gyro's noise, and that
  too moves the fit with the window's length (on simulated flights at the hardware-like noise, the yaw
  authority by up to a factor 3). Its scale is the noise's share of the axis's window signal
  (:func:`noise_share`, σ-based: not the discrepancy, which a misfit inflates) plus a floor
  (:data:`SCALE_FLOOR`): ``shift = max_c,k |v_c(k W) − v_c(W)| / (floor + share_c)``.

The threshold is the statistic's :data:`QUANTILE` quantile over simulated flights
(vehicles of the prior, several flights and noise levels: ``benchmarks/window_check.py``), stored in the
calibration table (``window_check``). A log above it fails the model check's rate features
(:func:`~.calibrate.model_check`).
"""
from __future__ import annotations

import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify import thresholds

WINDOW_FACTORS = (2, 4)
"""The other window lengths, as multiples of the default's (:data:`~.logdata.WINDOW_STEPS`)."""

CHECKED = (("tau_m", L.LOG_TAU_M, None), ("A_x", L.LOG_AUTH_X, L.CHANNELS.index("gyro_x")),
           ("A_y", L.LOG_AUTH_Y, L.CHANNELS.index("gyro_y")), ("yaw", L.LOG_YAW, L.CHANNELS.index("gyro_z")))
"""The coordinates the check compares (short name, index into v, the gyro axis whose noise share scales its
shifts; None: the axes' mean): τ_m and the roll, pitch and yaw authorities, what the rate windows inform most."""

SCALE_FLOOR = 0.05
"""log units: the shift a log without noise may show (5 %): the windows' own approximations (the gyroscopic
term from measured rates, the relative model floor)."""

ROUNDS = 2
"""Least-squares fits per window length, δ re-set from the residuals before each (:func:`~.mode.find_modes`'s
rule: δ is the log's and the window's, not the vehicle's)."""

QUANTILE = 0.99
"""The threshold's quantile of the statistic over simulated logs: a simulated log is flagged about 1 % of
the time."""

KEY = "window_check"
"""The calibration table's entry holding the threshold and its provenance."""

MIN_LOGS = 200
"""Simulated logs the statistic ran on that a threshold is fitted from (:func:`threshold_entry`): the 99 %
quantile of fewer is one log or none."""

SPEED_SKIP = ("tau_m not compared: the posterior takes it from the measured rotor speeds (the least squares "
              "re-fit it from the windows alone)")
"""Why a log with rotor speeds is checked on the authorities alone."""

WHY = ("the rate changes depend on the window length: physics the model lacks (e.g. feedback within a "
       "window, another motor model)")


def threshold(shifts, quantile: float = QUANTILE) -> float:
    """The ``quantile`` quantile (numpy's "higher": a statistic a log had) of the statistic ``shifts`` (the
    logs the check ran on)."""
    return thresholds.quantile_of(shifts, quantile, "window check")


def threshold_entry(rows, quantile: float = QUANTILE) -> dict | None:
    """The table's :data:`KEY` entry from calibration rows (their features' ``window_shift``) -> {threshold,
    quantile, logs, above, levels}, or None where fewer than :data:`MIN_LOGS` rows carry the statistic (rows
    collected before the check)."""
    return thresholds.entry(rows, "window_shift", quantile, MIN_LOGS)


def variants(data, factors=WINDOW_FACTORS) -> list:
    """The log of ``data`` (a :class:`~.logdata.LogData` that :func:`~.logdata.prepare` made in this process:
    it keeps the log's arrays) reduced again with windows ``factors`` × as long, padded to its shapes ->
    [(factor, LogData: the arrays alone)], the lengths the log is long enough for; [] where it cannot be reduced again (the
    innovations' rate term, or a LogData built otherwise)."""
    job = _job(data)
    return [] if job is None else _reduced(*job, factors)


def _job(data) -> tuple | None:
    """What :func:`_reduced` needs of the log of ``data``: its arrays, prepare's settings, its window in steps
    and its padding; None where it cannot be reduced again."""
    from mjxsysid.identify.logdata import DT
    rows = getattr(data, "_rows", None) or {}
    rec = rows.get("rec")
    if rec is None or data.rates != "windows" or not np.any(np.asarray(data.use)[L.GYRO] > 0):
        return None
    return (rec, rows.get("rec_args", {}), int(round(float(data.span) / DT)),
            (int(data.wmask.shape[0]), int(data.bmask.shape[0])))


def _reduced(rec: dict, rec_args: dict, w: int, pad: tuple, factors=WINDOW_FACTORS) -> list:
    """The log's arrays ``rec`` reduced (:func:`~.logdata.prepare` with ``rec_args``, padded to ``pad``) with
    windows ``factors`` × ``w`` steps -> [(factor, LogData)], up to the first the log is too short for. A
    module-level function: it runs in another process too."""
    from mjxsysid.identify.logdata import LogTooShort, prepare
    out = []
    for k in factors:
        try:
            out.append((k, prepare(rec, window_steps=k * w, pad_to=pad, rows=False, **rec_args)))
        except LogTooShort:
            break
    return out


def refits(make_logs, datas, ys, prior, starts: int = 1) -> np.ndarray:
    """Logs of one shape ``datas`` (m) re-fitted from their modes ys (m, 17), log δ re-set from the residuals
    before each of :data:`ROUNDS` fits -> y (m, 17). ``make_logs``: datas -> the posterior's
    batched evaluator (:class:`~.batched._Logs`); ``starts``: the starts per log its batched fit was
    compiled for (the mode's; one where the logs are fitted one at a time)."""
    from mjxsysid.identify.mode import _discrepancies, _project
    from mjxsysid.identify.target import NUIS_BOUNDS, full_x
    logs = make_logs(datas)
    ys = np.asarray(ys, np.float32)
    ls = ys[:, L.Y_LOG_NOISE]
    k = 1 if len(datas) == 1 else starts
    for _ in range(ROUNDS):
        ld = np.clip(_discrepancies(logs, ys), NUIS_BOUNDS[2], NUIS_BOUNDS[3]).astype(np.float32)
        z = np.repeat(L.z_from_y(ys)[:, None], k, 1)
        z = np.asarray(logs.fit(z, ld, ls))[:, 0]
        ys = L.y_from_x(_project(np.asarray(full_x(L.y_from_z(z, ls), ld)), prior))
    return ys


def statistic(mode_v, fitted: dict, noise_share, skip=()) -> dict:
    """The mode's visible coordinates (12,), {factor: re-fitted v (12,)} and the noise's share of each gyro
    axis's signal (3,) (:func:`noise_share`) -> {shift (the statistic), coord, factor (where it is
    largest), shifts {coord: {factor: log ratio}}, scale {coord: what its shifts are divided by}}. ``skip``:
    names of :data:`CHECKED` left out of the statistic (their shifts still reported)."""
    mode_v = np.asarray(mode_v, np.float64)
    share = np.asarray(noise_share, np.float64)
    shifts = {name: {int(k): float(np.asarray(v, np.float64)[j] - mode_v[j]) for k, v in fitted.items()}
              for name, j, _ in CHECKED}
    scale = {name: float(SCALE_FLOOR + (np.mean(share) if axis is None else share[axis])) for name, _, axis in CHECKED}
    best = (0.0, None, None)
    for name in (n for n, _, _ in CHECKED if n not in skip):
        for k, d in shifts[name].items():
            if abs(d) / scale[name] > best[0]:
                best = (abs(d) / scale[name], name, k)
    return {"shift": float(best[0]), "coord": best[1], "factor": best[2], "shifts": shifts, "scale": scale,
            "noise_share": share.tolist()}


def run(make_logs, datas, modes, prior, starts: int = 1, pool=None) -> list:
    """The check of every log of ``datas`` from its mode (``modes``: :func:`~.mode.find_modes`' tuples) ->
    per log :func:`statistic`'s dict, or {"shift": None, "why": ...} where the log cannot be reduced again.
    Logs whose reductions share a shape are re-fitted together (``make_logs``, ``starts``: :func:`refits`');
    ``pool``: a :class:`~mjxsysid.runtime.hostpool.HostPool` that reduces the logs again."""
    import jax
    from mjxsysid.runtime.hostpool import HostPool
    jobs = [_job(d) for d in datas]
    todo = [i for i, j in enumerate(jobs) if j is not None]
    done = (HostPool(1) if pool is None else pool).map(_reduced, *zip(*(jobs[i] for i in todo))) if todo else []
    var = [{} for _ in datas]
    for i, v in zip(todo, done):
        var[i] = dict(v)
    fitted = [{} for _ in datas]
    for k in WINDOW_FACTORS:
        groups: dict = {}
        for i, v in enumerate(var):
            if k in v:
                groups.setdefault(tuple(np.shape(a) for a in jax.tree.leaves(v[k])), []).append(i)
        for g in groups.values():
            ys = refits(make_logs, [var[i][k] for i in g], np.stack([modes[i][3] for i in g]), prior, starts)
            for i, y in zip(g, ys):
                fitted[i][k] = y[L.Y_V]
    out = []
    for i, d in enumerate(datas):
        if not fitted[i]:
            out.append({"shift": None, "why": _not_run(d)})
            continue
        y = np.asarray(modes[i][3])
        speeds = float(np.asarray(d.speed)[0]) > 0          # τ_m from the measured rotor speeds, not the windows
        out.append(statistic(y[L.Y_V], fitted[i], noise_share(d, y), skip=("tau_m",) if speeds else ())
                   | ({"skipped": SPEED_SKIP} if speeds else {}))
    return out


def noise_share(data, y) -> np.ndarray:
    """The IMU noise's share of each gyro axis's window signal (3,) at the mode y (17,): the white noise σ
    through a difference of two half-window means (√k σ) over the windows' RMS rate change. What a
    controller's reaction to the noise, and so the fit's drift with the window length where the model
    holds, scales with; not what the model lacks (δ, which :func:`~.calibrate.log_features` includes)."""
    sig = np.exp(np.asarray(y, np.float64)[L.Y_LOG_NOISE][L.GYRO])
    noise = np.sqrt(np.asarray(data.kvar, np.float64)[L.GYRO]) * sig
    wm = np.asarray(data.wmask, bool)
    gsig = np.maximum(np.sqrt(np.mean(np.asarray(data.dgyro, np.float64)[wm] ** 2, 0)), 1e-9)
    return noise / gsig


def _not_run(data) -> str:
    """Why a log's window check did not run."""
    if data.rates != "windows":
        return "not run: the innovations' rate term has no windows"
    if not np.any(np.asarray(data.use)[L.GYRO] > 0):
        return "not run: the rate windows were not used (motors logged too slowly)"
    if (getattr(data, "_rows", None) or {}).get("rec") is None:
        return "not run: the log's arrays are not at hand (a LogData built without prepare)"
    return f"not run: the log is too short for windows {WINDOW_FACTORS[0]}× as long"
