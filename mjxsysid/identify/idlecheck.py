"""The motor-map check: does the log fit better with an idle offset in the command→speed map?

The likelihood's rotors spin at the command times Ω_max (:mod:`.likelihood`): thrust ∝ u². A motor that
idles, Ω = Ω_max (ι + (1 − ι) u), makes thrust ∝ (ι + (1 − ι) u)². At one command level the two differ by
a factor the fit takes into thrust-to-weight and the authorities, so a log flown about one level (a hover)
cannot tell them apart, and the posterior is sharp and wrong: an idle of 0.1 Ω_max put thrust-to-weight
15–25 % high, and simulated logs with it held the truth 0.10–0.22 of the time (the calibration's
``misfit`` set). A flight whose commands move shows the curvature:

- the log is reduced again with its commands mapped through each idle of :data:`GRID` (the same shapes:
  the mode's compiled least squares serves them), and the visible coordinates re-fitted from the mode
  moved to the equivalent vehicle at the log's mean command (:func:`equivalent`), σ and δ held at the
  mode's; the map without idle is re-fitted from each of those optima too (its best, not a local one);
- the statistic is how much the best idle lowers the standardised residuals' sum of squares, each
  channel's discounted for its residuals' correlation as the likelihood's are (w):
  ``gain = SS(0) − min_ι SS(ι)`` (0 where none does). Under the model it stays near 0; the threshold is
  its :data:`QUANTILE` quantile over simulated logs without idle (``benchmarks/window_check.py``, stored
  in the calibration table under :data:`KEY`). On a log above it, each visible coordinate's calibrated
  band is widened on one side by how far the best idle moves it (:func:`widening`): the band then holds the
  quantity under the map the likelihood assumes and under the one the log prefers. A band widened past
  the "seen" rule's width is reported as not seen. A flagged log without the shifts (rows collected
  before them) fails whole.

A log whose rotor speeds were measured is not checked: :mod:`.speeds` fits its command→speed map,
idle offset included.
"""
from __future__ import annotations

import jax
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify import thresholds

GRID = (-0.1, 0.05, 0.1, 0.2)
"""The idle offsets (shares of Ω_max) the log is re-fitted under."""

QUANTILE = 0.99
"""The threshold's quantile of the statistic over simulated logs without idle."""

KEY = "idle_check"
"""The calibration table's entry holding the threshold and its provenance."""

MIN_LOGS = 200
"""Simulated logs the statistic ran on that a threshold is fitted from (:func:`threshold_entry`)."""

SCALED = (L.LOG_AUTH_X, L.LOG_AUTH_Y, L.LOG_YAW)
"""The coordinates a command differential drives (roll, pitch and yaw authority): scaled by
:func:`equivalent` as thrust-to-weight is."""

WHY = ("an idle offset in the command→speed map fits the log better; thrust-to-weight and the authorities "
       "depend on it, so their bands are widened toward their values under it")

SPEED_SKIP = "not run: the measured rotor speeds fit the command→speed map, idle offset included"


def mapped(u, iota: float) -> np.ndarray:
    """Commands u (T, 4) in [0, 1] -> the speeds' share of Ω_max under idle ``iota``: max(0, ι + (1 − ι) u)."""
    return np.maximum(iota + (1.0 - iota) * np.clip(np.asarray(u, np.float64), 0.0, 1.0), 0.0)


def equivalent(y, u_mean: float, iota: float, inverse: bool = False) -> np.ndarray:
    """The vehicle y (..., 17) fitted without idle, moved to the one with idle ``iota`` that has the same
    thrust and the same torque per command differential at the mean command ``u_mean``: thrust-to-weight ×
    (u / s)², the authorities × u / (s (1 − ι)), s = ι + (1 − ι) u. ``inverse``: back."""
    s = iota + (1.0 - iota) * u_mean
    k = -1.0 if inverse else 1.0
    out = np.array(y, np.float32, copy=True)
    out[..., L.LOG_TW] += k * 2.0 * np.log(u_mean / s)
    for j in SCALED:
        out[..., j] += k * np.log(u_mean / (s * (1.0 - iota)))
    return out


def variant(data, iota: float):
    """The log of ``data`` (prepared in this process: it keeps the log's arrays) reduced again with its
    commands mapped through idle ``iota`` (:func:`mapped`), padded to its shapes."""
    from mjxsysid.identify.logdata import prepare
    rows = data._rows
    rec = dict(rows["rec"])
    rec["motor"] = mapped(rec["motor"], iota)
    if (rec.get("native") or {}).get("motor") is not None:     # a slowly logged motor: prepare reads its samples
        t_nat, u_nat = rec["native"]["motor"]
        rec["native"] = dict(rec["native"]) | {"motor": (t_nat, mapped(u_nat, iota))}
    pad = (int(data.wmask.shape[0]), int(data.bmask.shape[0]))
    return prepare(rec, pad_to=pad, **rows["rec_args"])


def _residual_ss(z, data, ld, ls, w) -> float:
    """The least squares' objective at z (13,) (:func:`~.mode._ls_residuals`' standardised residuals), each
    channel's squares × its correlation discount w (4,) (:func:`~.likelihood.residual_weights`: the evidence the
    tempered likelihood gives them, not the count of correlated residuals). On the host, from the compiled
    residuals the mode already built (:data:`~.likelihood.residuals_jit`): the check compiles nothing new."""
    from mjxsysid.identify.likelihood import residuals_jit
    from mjxsysid.identify.mode import standardised
    z = np.asarray(z, np.float32)
    x = L.x_from_y(L.y_from_z(z, np.asarray(ls, np.float32)), np.asarray(ld, np.float32))
    res = (np.asarray(a, np.float64) for a in residuals_jit(x, data))
    g, a, b = standardised(*res, np.asarray(data.use, np.float64), float(z[L.Z_BIAS]))
    w = np.asarray(w, np.float64)
    return float(np.sum(g ** 2 * w[L.GYRO]) + w[L.ACC_Z] * np.sum(a ** 2) + b ** 2)


def _fit_and_ss(make_logs, datas, ys, lds, lss, ws, starts: int):
    """Logs of one shape re-fitted from ys (m, 17), δ and σ held -> (z (m, 13), SS (m,)); ``ws`` (m, 4) the
    correlation discounts."""
    logs = make_logs(datas)
    k = 1 if len(datas) == 1 else starts
    z0 = np.repeat(L.z_from_y(np.asarray(ys, np.float32))[:, None], k, 1)
    z = np.asarray(logs.fit(z0, lds, lss))[:, 0]
    ss = np.array([_residual_ss(zi, d, a, b, c) for zi, d, a, b, c in zip(z, datas, lds, lss, ws)])
    return z, ss


def checkable(data) -> str | None:
    """None where the check can run on ``data``, else why not."""
    rows = getattr(data, "_rows", None) or {}
    if rows.get("rec") is None:
        return "not run: the log's arrays are not at hand (a LogData built without prepare)"
    if float(np.asarray(data.speed)[0]) > 0:
        return SPEED_SKIP
    return None


def run(make_logs, datas, modes, starts: int = 1) -> list:
    """The check of every log of ``datas`` from its mode (``modes``: :func:`~.mode.find_modes`' tuples) ->
    per log {gain (the statistic), idle (the best ι of :data:`GRID`, None where none gains), gains {ι: SS(0) −
    SS(ι)}, thrust_to_weight {0: at no idle, ι: at the best idle}, shift (12,: v under the best idle less v
    without, log units), power (the largest |gain|)}, or {gain: None, why} where it cannot run. Logs of one
    shape are re-fitted together (``make_logs``: :class:`~.inference._Logs`; ``starts``:
    the starts per log its batched fit was compiled for)."""
    out = [None] * len(datas)
    idx = []
    for i, d in enumerate(datas):
        why = checkable(d)
        if why is None:
            idx.append(i)
        else:
            out[i] = {"gain": None, "why": why}
    groups: dict = {}
    for i in idx:
        groups.setdefault(tuple(np.shape(a) for a in jax.tree.leaves(datas[i])), []).append(i)
    for g in groups.values():
        ys = np.stack([np.asarray(modes[i][3], np.float32) for i in g])
        lds = np.stack([np.asarray(modes[i][1], np.float32) for i in g])
        lss = ys[:, L.Y_LOG_NOISE]
        ws = np.stack([np.asarray(modes[i][2], np.float32) for i in g])
        um = np.array([float(np.mean(datas[i]._rows["motor"])) for i in g])
        base = [datas[i] for i in g]
        z0, ss0 = _fit_and_ss(make_logs, base, ys, lds, lss, ws, starts)
        ss, zs = {}, {}
        for iota in GRID:
            var = [variant(d, iota) for d in base]
            y_i = np.stack([equivalent(y, u, iota) for y, u in zip(ys, um)])
            zs[iota], ss[iota] = _fit_and_ss(make_logs, var, y_i, lds, lss, ws, starts)
            back = np.stack([equivalent(L.y_from_z(z, ls), u, iota, inverse=True) for z, ls, u in zip(zs[iota], lss, um)])
            zb, ssb = _fit_and_ss(make_logs, base, back, lds, lss, ws, starts)
            better = ssb < ss0
            ss0, z0 = np.where(better, ssb, ss0), np.where(better[:, None], zb, z0)
        for j, i in enumerate(g):
            gains = {iota: float(ss0[j] - ss[iota][j]) for iota in GRID}
            best = max(gains, key=gains.get)
            gain = max(gains[best], 0.0)
            shift = np.asarray(zs[best][j][L.Z_V], np.float64) - np.asarray(z0[j][L.Z_V], np.float64)
            out[i] = {"gain": gain, "idle": best if gain > 0 else None, "gains": gains,
                      "thrust_to_weight": {0.0: float(np.exp(z0[j][L.LOG_TW])), best: float(np.exp(zs[best][j][L.LOG_TW]))},
                      "shift": shift.tolist(), "power": float(max(abs(x) for x in gains.values()))}
    return out


def features(check: dict | None) -> dict:
    """A log's check (:func:`run`'s dict, or None) -> the model check's features: idle_gain (the statistic,
    None where it did not run), idle_at (the best idle and thrust-to-weight under it, or why it did not run),
    idle_shift (12,: the visible coordinates re-fitted under the best idle less those without, log units),
    idle_power (the largest change of the fit any idle of the grid makes, either way: :func:`blind`)."""
    if not check or check.get("gain") is None:
        return {"idle_gain": None, "idle_at": (check or {}).get("why", "not run"), "idle_shift": None, "idle_power": None}
    at = "no idle fits better"
    if check.get("idle") is not None:
        tw = check["thrust_to_weight"]
        at = (f"idle {check['idle']:+.2f} Ω_max: thrust-to-weight {tw[check['idle']]:.3g} against "
              f"{tw[0.0]:.3g} without")
    return {"idle_gain": float(check["gain"]), "idle_at": at, "idle_shift": check.get("shift"),
            "idle_power": check.get("power")}


def threshold_entry(rows, quantile: float = QUANTILE) -> dict | None:
    """The table's :data:`KEY` entry from rows carrying the statistic (``features.idle_gain``) -> {threshold,
    quantile, logs, above, levels}, or None where fewer than :data:`MIN_LOGS` carry it."""
    return thresholds.entry(rows, "idle_gain", quantile, MIN_LOGS)


def verdict(feats: dict, table: dict) -> dict:
    """The check's verdict for a log's features against the table's threshold -> {value, threshold, ok (None:
    not run), why}."""
    return thresholds.verdict(feats.get("idle_gain"), feats.get("idle_at", ""), table.get(KEY), "motor-map check",
                              "idle gain", ".1f", WHY)


def widening(verdict_: dict, feats: dict, j: int) -> float | None:
    """How visible coordinate j's calibrated band is widened on a log (log units, signed: the side it is
    widened on): 0 unless the log is flagged (``verdict_``: :func:`verdict`'s); on a flagged log its shift
    under the best idle (``feats["idle_shift"][j]``), so that the band holds the value under either map; None
    where a flagged log carries no shifts (rows collected before them): every coordinate fails."""
    if verdict_.get("ok") is not False:
        return 0.0
    shift = feats.get("idle_shift")
    return None if shift is None else float(shift[j])


BLIND_WHY = ("thrust-to-weight assumes thrust ∝ command²: this flight's collective varied too little to test it "
             "(no idle offset of {grid} Ω_max changes the fit by more than the motor-map check's threshold), and an "
             "idle would move thrust-to-weight without changing the fit")
"""What the report adds to thrust-to-weight on a log the check cannot test (:func:`blind`)."""


def blind(verdict_: dict, feats: dict) -> bool:
    """Is the check blind on a log: it ran and passed, and no idle of :data:`GRID` changes the fit by more than
    the threshold either way (``idle_power``; a hover: its collective barely moves, so an idle and
    thrust-to-weight trade off exactly)?"""
    power = feats.get("idle_power")
    return verdict_.get("ok") is True and power is not None and power <= verdict_["threshold"]
