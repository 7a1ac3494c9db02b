"""The motor-map check: does the log fit better under another command→speed map?

The likelihood's rotors spin at the command times Ω_max (:mod:`.likelihood`): thrust ∝ u². Real motors
idle (Ω = Ω_max (ι + (1 − ι) u)) or follow a curved map, concave (Ω ∝ √u) or convex (a reader's thrust model
that is not the motors': PX4's THR_MDL_FAC 0 on motors whose speed is linear in the command reads as Ω ∝ u²):
the simulator's family is Ω = Ω_max (ι + (1 − ι) s(u)), s = √(κ u² + (1 − κ) u) for κ ≤ 1 and
u √(2 − κ + (κ − 1) u²) beyond (:func:`mapped`). At one command level any of them differs
from u² by a factor the fit takes into thrust-to-weight and the authorities, so a log flown about one level
(a hover) cannot tell them apart, and the posterior is sharp and wrong: an idle of 0.1 Ω_max put
thrust-to-weight 15–25 % high, and a √u map 2–3 times. A flight whose commands move shows the map:

- the log is reduced again with its commands mapped through each map of :data:`MAPS` (linear ones with the
  idles of :data:`GRID`, the curved ones of :data:`CURVED`; the same shapes: the mode's compiled least
  squares serves them), and the visible coordinates re-fitted from the mode moved to the equivalent
  vehicle at the log's mean command (:func:`equivalent`), σ and δ held at the mode's; the linear map is
  re-fitted from each of those optima too (its best, not a local one);
- the statistic is how much the best map lowers the standardised residuals' sum of squares, each channel's
  discounted for its residuals' correlation as the likelihood's are (w): ``gain = SS(0, 1) − min SS(ι, κ)``
  (0 where none does). Under the model it stays near 0; the threshold is its :data:`QUANTILE` quantile over
  simulated logs with the linear map (``benchmarks/window_check.py``, stored in the calibration table
  under :data:`KEY`).
- The log shows the map only about the commands it flew; thrust-to-weight and Ω_max are its value at full
  command, an extrapolation each map makes differently. Every map whose sum of squares lies within
  :data:`SPAN_TOL` of the best is plausible, the linear map too where the gain is within it. On a log above
  the threshold, each visible coordinate's calibrated band becomes the union of the band moved to each
  plausible map (:func:`widening`; ``idle_span``): thrust-to-weight and the authorities to their values
  under it, the others by their shifts. A band widened past
  the "seen" rule's width is reported as not seen. A flagged log without the span (rows collected before
  it) is widened toward the best map's shift alone; one without either fails whole.

A log whose rotor speeds were measured is not checked: :mod:`.speeds` fits its command→speed map,
idle offset included.
"""
from __future__ import annotations

import jax
import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify import thresholds

GRID = (-0.1, 0.05, 0.1, 0.2)
"""The idle offsets (shares of Ω_max) of the linear maps (κ 1) the log is re-fitted under."""

CURVED = tuple((iota, kappa) for kappa in (0.5, 0.0, 1.5, 2.0) for iota in (-0.1, 0.0, 0.1))
"""The curved maps (ι, κ) the log is re-fitted under: concave (κ 0.5 and 0: √u) and convex (κ 2: u², the speed of
an ESC linear in its command read through a thrust model that takes thrust as linear in it, as PX4's THR_MDL_FAC 0
does: Gazebo-classic's motors; κ 1.5: between, as a Crazyflie's thrust, quadratic and linear in its PWM, read as
linear)."""

MAPS = tuple((iota, 1.0) for iota in GRID) + CURVED
"""Every map (ι, κ) of the check (:func:`mapped`), beside the likelihood's own (0, 1)."""

MIN_SPEED = 0.05
"""A map whose speed at the log's mean command is below this share of Ω_max (a dead band the log flew above)
cannot carry the log: it is not re-fitted (its gain None, never plausible)."""

SPAN_TOL = 4.61
"""A map is plausible where its sum of squares lies within this of the best map's: χ²'s 0.90 quantile with two
degrees of freedom (the map's ι and κ), the likelihood-ratio set at the bands' level."""

QUANTILE = 0.99
"""The threshold's quantile of the statistic over simulated logs without idle."""

STILL_FLIGHTS = ("hover",)
"""Flights (the rows' ``flight`` name) that do not set the threshold: a hover holds its collective still, so an
IMU bias fits an idle offset as well (hovers at × 1: a 99th percentile of 18.4 against 4.8 for the slow
figure-eight's worst level; benchmarks/calibration_by_flight.py). With them the threshold was 6.331 (968 logs); without, 4.687
(530), which flags 14 of 438 linear-map hovers (their bands widen) and 26 of 27 u² logs instead of 20
(docs/identify.md, "The motor-map check", both ways); 5.166 on the 1,170 logs with the min-snap set's 80 paths (13 hovers
and 26 of 27 u² logs)."""

KEY = "idle_check"
"""The calibration table's entry holding the threshold and its provenance."""

MIN_LOGS = 200
"""Simulated logs the statistic ran on that a threshold is fitted from (:func:`threshold_entry`)."""

SCALED = (L.LOG_AUTH_X, L.LOG_AUTH_Y, L.LOG_YAW)
"""The coordinates a command differential drives (roll, pitch and yaw authority): scaled by
:func:`equivalent` as thrust-to-weight is."""

MAPPED = (L.LOG_TW,) + SCALED
"""The coordinates the map acts on: on a flagged log their bands move to their values under the plausible
maps (:func:`widening`)."""

WHY = ("another command→speed map fits the log better; thrust-to-weight and the authorities depend on it, so "
       "each band moves to hold its value under every map that fits about as well")

WIDENED = "to hold its value under every command→speed map that fits the log about as well as the best"
"""What a band's reason says where the check moved its edges (:func:`widening`; fleet tables mark it)."""

SPEED_SKIP = "not run: the measured rotor speeds fit the command→speed map, idle offset included"


def mapped(u, iota: float, kappa: float = 1.0) -> np.ndarray:
    """Commands u (T, 4) in [0, 1] -> the speeds' share of Ω_max under idle ``iota`` and curvature ``kappa``:
    max(0, ι + (1 − ι) s), s = √(κ u² + (1 − κ) u) for κ ≤ 1 (concave: √u at 0), u √(2 − κ + (κ − 1) u²) for
    κ > 1 (convex: u² at 2), the simulator's map (:func:`mjxsysid.sim.motors.commanded_speed`)."""
    u = np.clip(np.asarray(u, np.float64), 0.0, 1.0)
    shape = (u if kappa == 1.0 else np.sqrt(kappa * u * u + (1.0 - kappa) * u) if kappa < 1.0
             else u * np.sqrt(2.0 - kappa + (kappa - 1.0) * u * u))
    return np.maximum(iota + (1.0 - iota) * shape, 0.0)


def _slope(u: float, iota: float, kappa: float) -> float:
    """d mapped / du at the command u (0, 1]: (1 − ι) (2 κ u + 1 − κ) / (2 √(κ u² + (1 − κ) u)) for κ ≤ 1,
    (1 − ι) (2 − κ + 2 (κ − 1) u²) / √(2 − κ + (κ − 1) u²) beyond."""
    if kappa > 1.0:
        r = 2.0 - kappa + (kappa - 1.0) * u * u
        return (1.0 - iota) * (r + (kappa - 1.0) * u * u) / np.sqrt(r)
    return (1.0 - iota) * (2.0 * kappa * u + 1.0 - kappa) / (2.0 * np.sqrt(kappa * u * u + (1.0 - kappa) * u))


def equivalent(y, u_mean: float, iota: float, inverse: bool = False, kappa: float = 1.0) -> np.ndarray:
    """The vehicle y (..., 17) fitted with the linear map, moved to the one under the map (``iota``, ``kappa``)
    that has the same thrust and the same torque per command differential at the mean command ``u_mean``:
    thrust-to-weight × (u / s)², the authorities × u / (s s'), s the map at u (:func:`mapped`) and s' its
    slope there (1 − ι where κ is 1). ``inverse``: back."""
    s = float(mapped(u_mean, iota, kappa))
    k = -1.0 if inverse else 1.0
    out = np.array(y, np.float32, copy=True)
    out[..., L.LOG_TW] += k * 2.0 * np.log(u_mean / s)
    for j in SCALED:
        out[..., j] += k * np.log(u_mean / (s * _slope(u_mean, iota, kappa)))
    return out


def variant(data, iota: float, kappa: float = 1.0):
    """The log of ``data`` (prepared in this process: it keeps the log's arrays) reduced again with its
    commands mapped through idle ``iota`` and curvature ``kappa`` (:func:`mapped`), padded to its shapes: the
    arrays alone (no ``_rows``)."""
    return _reduced(*_job(data), iota, kappa)


def _job(data) -> tuple:
    """What :func:`_reduced` needs of the log of ``data``: its arrays, prepare's settings and its padding."""
    rows = data._rows
    return rows["rec"], rows["rec_args"], (int(data.wmask.shape[0]), int(data.bmask.shape[0]))


def _reduced(rec: dict, rec_args: dict, pad: tuple, iota: float, kappa: float = 1.0):
    """The log's arrays ``rec`` reduced (:func:`~.logdata.prepare` with ``rec_args``, padded to ``pad``) with its
    commands mapped through (``iota``, ``kappa``). A module-level function: it runs in another process too."""
    from mjxsysid.identify.logdata import prepare
    rec = dict(rec)
    rec["motor"] = mapped(rec["motor"], iota, kappa)
    if (rec.get("native") or {}).get("motor") is not None:     # a slowly logged motor: prepare reads its samples
        t_nat, u_nat = rec["native"]["motor"]
        rec["native"] = dict(rec["native"]) | {"motor": (t_nat, mapped(u_nat, iota, kappa))}
    return prepare(rec, pad_to=pad, rows=False, **rec_args)


VARIANTS_AT_ONCE = 64
"""The most reduced variants (:func:`variant`, about 0.2 MB each for a 10 s log, 0.9 MB with the innovations)
held at once by :func:`_variants`."""


def _variants(base, maps, pool):
    """Each map of ``maps`` with the logs of ``base`` reduced again under it (:func:`variant`), in the maps'
    order: (map, [LogData, ...]), :data:`VARIANTS_AT_ONCE` at a time, the next chunk reduced while the caller
    fits the last (two chunks held at once); the results are the same as one by one.
    ``pool``: a :class:`~mjxsysid.runtime.hostpool.HostPool`, whose processes take them where it has enough
    work for them (beside an accelerator: a reduction is many small NumPy calls, and threads wait on each
    other's interpreter lock); else threads (scipy's filters release the interpreter: 1.65× on 2
    cores)."""
    step = max(1, VARIANTS_AT_ONCE // max(len(base), 1))
    jobs = [_job(d) for d in base]
    procs = pool.processes(len(base) * len(maps))
    chunks = [maps[k:k + step] for k in range(0, len(maps), step)]

    def start(chunk):
        return pool.later(_reduced, *zip(*[j + m for m in chunk for j in jobs]), threads=True, processes=procs)
    pending = start(chunks[0]) if chunks else None
    for k, chunk in enumerate(chunks):
        done = pending()
        pending = start(chunks[k + 1]) if k + 1 < len(chunks) else None     # reduced while the caller fits these
        for j, m in enumerate(chunk):
            yield m, done[j * len(base):(j + 1) * len(base)]


def _residual_ss(res, z, use, w) -> float:
    """The least squares' objective from a log's residuals ``res`` (:func:`~.likelihood.residuals`' four arrays)
    at z (13,) (:func:`~.mode._ls_residuals`' standardised residuals; ``use`` (4,) the channels the log uses), each
    channel's squares × its correlation discount w (4,) (:func:`~.likelihood.residual_weights`: the evidence the
    tempered likelihood gives them, not the count of correlated residuals); on the host, in float64."""
    from mjxsysid.identify.mode import standardised
    g, a, b = standardised(*(np.asarray(r, np.float64) for r in res), np.asarray(use, np.float64),
                           float(np.asarray(z)[L.Z_BIAS]))
    w = np.asarray(w, np.float64)
    return float(np.sum(g ** 2 * w[L.GYRO]) + w[L.ACC_Z] * np.sum(a ** 2) + b ** 2)


def _fit_and_ss(make_logs, datas, ys, lds, lss, ws, starts: int):
    """Logs of one shape re-fitted from ys (m, 17), δ and σ held -> (z (m, 13), SS (m,)); ``ws`` (m, 4) the
    correlation discounts. The residuals come from the programs the mode already built (one call for the logs
    together, :meth:`~.batched._Logs.residuals`): the check compiles nothing new."""
    logs = make_logs(datas)
    k = 1 if len(datas) == 1 else starts
    z0 = np.repeat(L.z_from_y(np.asarray(ys, np.float32))[:, None], k, 1)
    z = np.asarray(logs.fit(z0, lds, lss))[:, 0]
    res = logs.residuals(L.x_from_y(L.y_from_z(z.astype(np.float32), np.asarray(lss, np.float32)),
                                    np.asarray(lds, np.float32)))
    ss = np.array([_residual_ss([r[i] for r in res], z[i], d.use, ws[i]) for i, d in enumerate(datas)])
    return z, ss


def checkable(data) -> str | None:
    """None where the check can run on ``data``, else why not."""
    rows = getattr(data, "_rows", None) or {}
    if rows.get("rec") is None:
        return "not run: the log's arrays are not at hand (a LogData built without prepare)"
    if float(np.asarray(data.speed)[0]) > 0:
        return SPEED_SKIP
    return None


def run(make_logs, datas, modes, starts: int = 1, shared=(), pool=None) -> list:
    """The check of every log of ``datas`` from its mode (``modes``: :func:`~.mode.find_modes`' tuples) ->
    per log {gain (the statistic), map (the best (ι, κ) of :data:`MAPS`, None where none gains), gains {(ι, κ) (None
    where the map cannot carry the log, :data:`MIN_SPEED`):
    SS(linear) − SS(ι, κ)}, thrust_to_weight {None: under the linear map from the mode, (ι, κ): under the best}, shift (12,:
    v under the best map less v under the linear one re-fitted from the mode, log units; the statistic takes
    the best of the linear map's re-fits instead), span (2, 12: the least and the largest shift over the
    plausible maps of :data:`MAPS`,
    :data:`SPAN_TOL`; 0 where none is), origin (12,: v under the linear map re-fitted from the mode), plausible
    [(ι, κ), ...], shared [(ι, κ), ...] (the maps of ``shared`` the log's own fit did not find plausible, in the
    span too), power (the largest |gain|)}, or {gain: None, why} where it cannot run. ``shared``: maps other
    flights of the vehicle showed (:data:`~.posterior_config.PosteriorConfig.shared_maps`): a map the vehicle
    has is plausible for each of its flights, whatever one flight's fit says, where it carries the log. Logs of
    one shape are re-fitted together (``make_logs``: :class:`~.batched._Logs`; ``starts``: the starts per log
    its batched fit was compiled for; ``pool``: the :class:`~mjxsysid.runtime.hostpool.HostPool` that reduces the
    logs under each map, :func:`_variants`; default: one here, on threads)."""
    from mjxsysid.runtime.hostpool import HostPool
    pool = HostPool(1) if pool is None else pool
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
        z_mode = z0                                  # the linear map re-fitted from the mode: the shifts' origin
        ss, zs = {}, {}
        for (iota, kappa), var in _variants(base, MAPS, pool):
            fits = mapped(um, iota, kappa) >= MIN_SPEED      # the map carries each log at its mean command
            y_m = np.stack([equivalent(y, u, iota, kappa=kappa) if f else y for y, u, f in zip(ys, um, fits)])
            zs[iota, kappa], ss[iota, kappa] = _fit_and_ss(make_logs, var, y_m, lds, lss, ws, starts)
            ss[iota, kappa] = np.where(fits, ss[iota, kappa], np.inf)
            back = np.stack([equivalent(L.y_from_z(z, ls), u, iota, inverse=True, kappa=kappa) if f else y
                             for z, ls, u, f, y in zip(zs[iota, kappa], lss, um, fits, ys)])
            zb, ssb = _fit_and_ss(make_logs, base, back, lds, lss, ws, starts)
            better = fits & (ssb < ss0)
            ss0, z0 = np.where(better, ssb, ss0), np.where(better[:, None], zb, z0)
        for j, i in enumerate(g):
            gains = {m: float(ss0[j] - ss[m][j]) for m in MAPS}
            best = max(gains, key=gains.get)
            gain = max(gains[best], 0.0)
            shifts = {m: np.asarray(zs[m][j][L.Z_V], np.float64) - np.asarray(z_mode[j][L.Z_V], np.float64) for m in MAPS}
            plausible = [m for m in MAPS if gains[m] >= gain - SPAN_TOL]
            extra = [tuple(m) for m in shared if tuple(m) not in plausible and np.isfinite(gains[tuple(m)])]
            moved = np.stack([shifts[m] for m in plausible + extra] or [np.zeros(L.N_V)])
            finite = [x for x in gains.values() if np.isfinite(x)]
            out[i] = {"gain": gain, "map": best if gain > 0 else None,
                      "gains": {m: (x if np.isfinite(x) else None) for m, x in gains.items()},
                      "thrust_to_weight": {None: float(np.exp(z_mode[j][L.LOG_TW])),
                                           best: float(np.exp(zs[best][j][L.LOG_TW]))},
                      "shift": shifts[best].tolist(),
                      "span": [moved.min(0).tolist(), moved.max(0).tolist()],
                      "origin": np.asarray(z_mode[j][L.Z_V], np.float64).tolist(),
                      "plausible": plausible, "shared": extra,
                      "power": float(max((abs(x) for x in finite), default=0.0))}
    return out


def describe(m) -> str:
    """A map (ι, κ) in words: 'idle +0.10 Ω_max' for a linear one, 'idle −0.10 Ω_max, κ 0 (curved)' else."""
    return f"idle {m[0]:+.2f} Ω_max" + ("" if m[1] == 1.0 else f", κ {m[1]:g} (curved)")


def features(check: dict | None) -> dict:
    """A log's check (:func:`run`'s dict, or None) -> the model check's features: idle_gain (the statistic,
    None where it did not run), idle_at (the best map and thrust-to-weight under it, or why it did not run),
    idle_map ([ι, κ] of the best map, None where none fits better or it did not run),
    idle_shift (12,: the visible coordinates re-fitted under the best map less those under the linear one, log
    units), idle_span (2, 12: the least and the largest such shift over the plausible maps), idle_origin (12,:
    the linear map's re-fit from the mode, the shifts' origin), idle_power (the largest change of the fit any map of :data:`MAPS` makes, either way: :func:`blind`),
    idle_maps (how many maps the statistic is the best of: its version, :func:`threshold_entry`), idle_plausible
    ([[ι, κ], ...]: the maps the span covers, the shared ones after the log's own)."""
    if not check or check.get("gain") is None:
        return {"idle_gain": None, "idle_at": (check or {}).get("why", "not run"), "idle_map": None, "idle_shift": None,
                "idle_span": None, "idle_origin": None, "idle_power": None, "idle_maps": None, "idle_plausible": None}
    at = "no other map fits better"
    if check.get("map") is not None:
        tw = check["thrust_to_weight"]
        at = f"{describe(check['map'])}: thrust-to-weight {tw[check['map']]:.3g} against {tw[None]:.3g} under the linear map"
    best = check.get("map")
    return {"idle_gain": float(check["gain"]), "idle_at": at, "idle_map": None if best is None else list(best),
            "idle_shift": check.get("shift"),
            "idle_span": check.get("span"), "idle_origin": check.get("origin"), "idle_power": check.get("power"),
            "idle_maps": len(check["gains"]),
            "idle_plausible": [list(m) for m in list(check.get("plausible", [])) + list(check.get("shared", []))]}


def threshold_entry(rows, quantile: float = QUANTILE) -> dict | None:
    """The table's :data:`KEY` entry from rows carrying the statistic over :data:`MAPS` (``features.idle_gain``
    with ``idle_maps`` as many: rows without it carry the linear maps' statistic, collected before the curved
    maps, and are left out; so are :data:`STILL_FLIGHTS`) -> {threshold, quantile, logs, above, levels}, or None where fewer than
    :data:`MIN_LOGS` carry it."""
    current = [r for r in rows if (r.get("features") or {}).get("idle_maps") == len(MAPS)
               and not str(r.get("flight", "")).startswith(STILL_FLIGHTS)]
    return thresholds.entry(current, "idle_gain", quantile, MIN_LOGS)


def verdict(feats: dict, table: dict) -> dict:
    """The check's verdict for a log's features against the table's threshold -> {value, threshold, ok (None:
    not run), why}."""
    return thresholds.verdict(feats.get("idle_gain"), feats.get("idle_at", ""), table.get(KEY), "motor-map check",
                              "map gain", ".1f", WHY)


def widening(verdict_: dict, feats: dict, j: int, median: float) -> tuple[float, float] | None:
    """How visible coordinate j's calibrated band moves on a log whose posterior median there is ``median``
    (log units: (its lower edge's move, its upper edge's move)): none unless the log is flagged (``verdict_``:
    :func:`verdict`'s). On a flagged log the band becomes the union of the band moved to each plausible map
    (``feats["idle_span"]``: the least and the largest shift) and, where the linear map is plausible too (the
    gain within :data:`SPAN_TOL`), the band itself. A coordinate the map acts on (:data:`MAPPED`) moves to its
    value under the map (``idle_origin`` + shift: a map that fits re-fits it where the posterior would sit,
    while under the linear map, which does not, the re-fit and the posterior part by up to 0.16); another
    moves by the shift alone (its re-fits follow the map, not the data). Where a row carries no span, the band
    is widened toward the best map's shift (``idle_shift``); None where it carries neither (rows collected
    before them): every coordinate fails."""
    if verdict_.get("ok") is not False:
        return 0.0, 0.0
    span, shift, origin = feats.get("idle_span"), feats.get("idle_shift"), feats.get("idle_origin")
    if span is not None:
        lo, hi = float(span[0][j]), float(span[1][j])
        if origin is not None and j in MAPPED:
            lo, hi = lo + float(origin[j]) - median, hi + float(origin[j]) - median
        if (feats.get("idle_gain") or 0.0) <= SPAN_TOL:
            lo, hi = min(lo, 0.0), max(hi, 0.0)
        return lo, hi
    if shift is None:
        return None
    return min(float(shift[j]), 0.0), max(float(shift[j]), 0.0)


BLIND_WHY = ("thrust-to-weight assumes thrust ∝ command²: this flight's collective varied too little to test it "
             "(no other command→speed map, idle offsets {grid} Ω_max or curved, changes the fit by more than the "
             "motor-map check's threshold), and another map would move thrust-to-weight without changing the fit")
"""What the report adds to thrust-to-weight on a log the check cannot test (:func:`blind`)."""


def blind(verdict_: dict, feats: dict) -> bool:
    """Is the check blind on a log: it ran and passed, and no map of :data:`MAPS` changes the fit by more than
    the threshold either way (``idle_power``; a hover: its collective barely moves, so the map and
    thrust-to-weight trade off exactly)?"""
    power = feats.get("idle_power")
    return verdict_.get("ok") is True and power is not None and power <= verdict_["threshold"]
