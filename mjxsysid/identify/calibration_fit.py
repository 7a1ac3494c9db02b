"""Fitting the calibration table (:mod:`.calibrate` applies it) from simulated logs' rows: per visible
coordinate, groups of logs by what they show (bins, or overlapping windows) and, per group and side of the
median, the split-conformal extent a·w + b (after Vovk et al.; :func:`fit`)."""
from __future__ import annotations

import numpy as np

from mjxsysid.identify import logspace as L
from mjxsysid.identify.calibrate import (BINS, COORD_FEATURE, FEATURE_NAMES, LEVEL, MIN_SIDE, RATE_COORDS,
                                         VELOCITY_COORDS, group_of)
from mjxsysid.identify.logspace import N_V, V_NAMES

WINDOWED = {"smc_nuts": {"windows": 16, "logs": 300, "relative": 0.3, "least": 0.1}}
"""The samplers whose tables are fitted in windows (:func:`fit` ``windows``; by
:func:`~mjxsysid.experiments.posterior_calibration.fit_file`): ``windows`` quantiles of the feature, each
fitted on its ``logs`` nearest calibration logs, each side at least ``relative`` × the other side's extent and
``least`` × the raw side (:func:`~.calibrate.side_factors`). NUTS's, chosen on a three-fold split of its 3,970
training rows (cells within 0.85–0.95, of 180): the interpolated bins 114 (3 under 0.85); this 157 (9 under,
the worst 0.825); 12 or 20 windows, 400 logs, a relative 0.5 or least 0.2: 145–155. Both parts count (the same
split on 4,027 rows): windows with both tails at 95 % and the bins' :data:`MIN_SIDE` 121, with the shares 136,
with this guard 136, with both 156. The SMC's table stays in bins with :data:`MIN_SIDE` (on its split, 140 →
136 of 180 with this guard)."""

MIN_FAMILY = 20
"""The fewest logs of a family that :func:`_sides` holds at the level on its own (a window's group holds 150)."""

B_GRID_QUANTILES = np.linspace(0.0, 0.95, 20)
"""The floors b tried: these quantiles of the group's errors (0 included)."""


def conformal_quantile(scores, level: float = LEVEL) -> float:
    """The split-conformal quantile of ``scores`` (n,): the ⌈(n + 1) level⌉-th smallest (inf when
    n is too small for that level)."""
    s = np.sort(np.asarray(scores, np.float64))
    k = int(np.ceil((len(s) + 1) * level))
    return float(s[k - 1]) if k <= len(s) else float("inf")


def fit_scale_floor(err, half, level=LEVEL, families=None) -> tuple[float, float]:
    """Errors beyond the median on one side (n,) (0 where the truth is on the other side) and the raw
    band's extent on that side (n,) of one group -> (a, b): the calibrated extent a·w + b that holds
    the truth with probability ``level`` (split conformal), the narrowest median over the floors of
    :data:`B_GRID_QUANTILES`. ``families`` (n,) labels: a holds each family's logs at its own level
    (``level``: {label: level}), the largest of their quantiles."""
    err, half = np.asarray(err, np.float64), np.maximum(np.asarray(half, np.float64), 1e-12)
    parts = [(np.ones(len(err), bool), level)] if families is None else \
        [(np.asarray(families) == f, lv) for f, lv in level.items()]
    best = None
    for b in np.quantile(err, B_GRID_QUANTILES):
        a = max(conformal_quantile(np.maximum(err[m] - b, 0.0) / half[m], lv) for m, lv in parts)
        width = float(np.median(a * half + b))
        if best is None or width < best[0]:
            best = (width, a, float(b))
    return float(best[1]), float(best[2])


def fit(rows: list[dict], *, level: float = LEVEL, bins: int = BINS, min_group: int = 30,
        windows: dict | None = None, vibration: tuple = ()) -> dict:
    """Calibration rows (one per simulated log: ``truth_v`` (12,), ``bands`` (3, 12) from
    :func:`~.calibrate.raw_bands`, ``features`` from :func:`~.calibrate.log_features`) -> the calibration table: per
    coordinate, the feature's groups and (a, b) per group and side; the features' ranges and the residual
    correlation the set covers (the model check's limits). Logs whose rates were not used are left
    out of the rate coordinates. ``windows`` None: ``bins`` quantile bins, a bin of fewer than ``min_group``
    logs (tied features) taking the pooled fit (:func:`_fit_bins`); else a :data:`WINDOWED` entry
    (:func:`_fit_windows`). The coordinates in ``vibration`` are fitted apart on the logs whose gyro shows a
    rotor vibration (``features["vibration"]``) where there are enough of them (``vibration_coords``), and
    thrust-to-weight on the remaining logs with velocity (``velocity_coords``). ValueError if a coordinate has
    too few logs for either."""
    if not rows:
        raise ValueError("posterior calibration: no rows to fit")
    truth = np.array([r["truth_v"] for r in rows], np.float64)
    bands = np.array([r["bands"] for r in rows], np.float64)
    feats = np.array([[r["features"][f] for f in FEATURE_NAMES] for r in rows], np.float64)
    used = np.array([r["features"]["rates_used"] for r in rows], bool)
    vel = np.array([bool(r["features"].get("velocity_used", False)) for r in rows], bool)
    vib = np.array([bool(r["features"].get("vibration", False)) for r in rows], bool)
    weights = np.array([r.get("weights", [1.0] * L.N_CHANNELS) for r in rows], np.float64)
    need = min_group * bins if windows is None else windows["logs"]

    def one(j: int, keep) -> dict:
        if keep.sum() < need:
            raise ValueError(f"posterior calibration: {int(keep.sum())} logs for {V_NAMES[j]}; need {need} ("
                             + (f"{bins} bins of {min_group})" if windows is None else "one window)"))
        args = (j, truth[keep], bands[keep], feats[keep, COORD_FEATURE[j]], level)
        return _fit_bins(*args, bins, min_group) if windows is None else _fit_windows(*args, **windows)
    strata = vel.sum() >= need                       # enough logs with velocity for a stratum of their own
    table, vel_table, vib_table = [], {}, {}
    for j in range(N_V):
        keep = used if RATE_COORDS[j] else np.ones(len(rows), bool)
        if (keep & vib).sum() >= need and j in vibration:
            vib_table[str(j)] = one(j, keep & vib)
            keep = keep & ~vib
        if strata and j in VELOCITY_COORDS:
            vel_table[str(j)] = one(j, keep & vel)
            keep = keep & ~vel
        table.append(one(j, keep))
    rng = {f: [float(np.min(feats[:, i])), float(np.max(feats[:, i]))] for i, f in enumerate(FEATURE_NAMES)}
    min_weight = np.full(L.N_CHANNELS, np.quantile(weights[used][:, L.GYRO], 0.005))
    min_weight[L.ACC_Z] = np.quantile(weights[:, L.ACC_Z], 0.005)
    return {"level": level, "coords": table, "velocity_coords": vel_table, "vibration_coords": vib_table,
            "feature_range": rng,
            "min_weight": min_weight.tolist(), "logs": len(rows)}


def _sides(d, below, above, level: float, shares: bool,
           families=None) -> tuple[tuple[float, float], tuple[float, float]]:
    """One group's truths beyond the median d (n,) (> 0 above) and raw extents below and above (n,) -> the
    (a, b) of :func:`fit_scale_floor` below and above. Each side misses half of 1 − ``level`` (inf where the
    group is too small for that), or with ``shares`` the share of it that the truths on that side hold: a group
    whose truths all lie below misses its 10 % below, instead of holding 95 % there and every truth above.
    ``families`` (n,) labels (with ``shares``): each family of :data:`MIN_FAMILY` logs or more is held at
    ``level`` on its own, its shares its own (:func:`fit_scale_floor`)."""
    if not shares:
        lv = 1 - (1 - level) / 2
        return fit_scale_floor(np.maximum(-d, 0), below, lv), fit_scale_floor(np.maximum(d, 0), above, lv)
    fam = np.zeros(len(d), int) if families is None else np.asarray(families)
    every = list(dict.fromkeys(fam.tolist()))
    labels = [f for f in every if (fam == f).sum() >= MIN_FAMILY] or every
    lv = {}
    for f in labels:
        m = fam == f
        p_hi = float(np.mean(d[m] > 0))
        cap = m.sum() / (m.sum() + 1.0)  # a side few truths lie on: its largest score, not inf (0 where none does)
        lv[f] = tuple(min(1 - (1 - level) * p, cap) for p in (1 - p_hi, p_hi))
    return tuple(fit_scale_floor(e, h, {f: v[i] for f, v in lv.items()}, fam)
                 for i, (e, h) in enumerate(((np.maximum(-d, 0), below), (np.maximum(d, 0), above))))


def _entry(j: int, x, sides: list, guard: tuple[float, float], **entry) -> dict:
    """Coordinate j's table entry from its feature values x (n,), each group's :func:`_sides` and ``guard``
    (relative, least: :func:`side_factors`)."""
    (scale_below, floor_below), (scale_above, floor_above) = (map(list, zip(*side)) for side in zip(*sides))
    return {"name": V_NAMES[j], "feature": FEATURE_NAMES[COORD_FEATURE[j]], **entry, "feature_max": float(np.max(x)),
            "scale_below": scale_below, "floor_below": floor_below, "scale_above": scale_above,
            "floor_above": floor_above, "guard": list(guard)}


def _errors(truth, bands, j: int) -> tuple:
    """Coordinate j's raw 90 % width, the truth beyond the median (> 0 above) and the raw extents below and
    above, each (n,), from the logs' truths (n, 12) and raw bands (n, 3, 12)."""
    q = bands[:, :, j]
    return q[:, 2] - q[:, 0], truth[:, j] - q[:, 1], q[:, 1] - q[:, 0], q[:, 2] - q[:, 1]


def _fit_bins(j: int, truth, bands, x, level: float, bins: int, min_group: int) -> dict:
    """Coordinate j's entry from its logs' truths (n, 12), raw bands (n, 3, 12) and feature x (n,): ``bins``
    quantile bins of x, each split at its median raw width (:func:`group_of`), both tails at 95 %, guarded
    by :data:`MIN_SIDE`."""
    edges = np.quantile(x, np.linspace(0, 1, bins + 1)[1:-1])
    k = np.searchsorted(edges, x)
    width, d, below, above = _errors(truth, bands, j)
    split = [float(np.median(width[k == i])) if (k == i).any() else 0.0 for i in range(bins)]
    entry = {"edges": edges.tolist(), "width_split": split}
    grp = np.array([group_of(entry, xi, wi) for xi, wi in zip(x, width)])
    groups = [grp == i if (grp == i).sum() >= min_group else k == i // 2 for i in range(2 * bins)]
    sides = [_sides(d[g], below[g], above[g], level, shares=False) for g in groups]
    return _entry(j, x, sides, (0.0, MIN_SIDE), **entry, logs=[int((grp == i).sum()) for i in range(2 * bins)])


def _fit_windows(j: int, truth, bands, x, level: float, windows: int, logs: int, relative: float,
                 least: float, families=None) -> dict:
    """Coordinate j's entry from its logs' truths (n, 12), raw bands (n, 3, 12) and feature x (n,) in
    ``windows`` windows: at the quantiles (i + ½) / windows of x, the ``logs`` logs nearest in x's rank, split at
    their median raw width into two groups, each side's tail given its truths' share of the miss
    (:func:`_sides`; ``families`` (n,): each family held at ``level`` apart). The windows' centres (their
    median x) are what :func:`stretch` interpolates between; ``edges`` (midway between centres) only name a
    log's group."""
    n = len(x)
    order = np.argsort(x, kind="stable")
    width, d, below, above = _errors(truth, bands, j)
    centres, split, sides, counts = [], [], [], []
    for q in (np.arange(windows) + 0.5) / windows:
        start = min(max(int(q * n) - logs // 2, 0), n - logs)
        idx = order[start:start + logs]
        centres.append(float(np.median(x[idx])))
        split.append(float(np.median(width[idx])))
        for g in (idx[width[idx] <= split[-1]], idx[width[idx] > split[-1]]):
            g = g if len(g) else idx                 # tied widths: the window whole
            sides.append(_sides(d[g], below[g], above[g], level, shares=True,
                                families=None if families is None else np.asarray(families)[g]))
            counts.append(len(g))
    centres = np.maximum.accumulate(centres)
    return _entry(j, x, sides, (relative, least), edges=((centres[1:] + centres[:-1]) / 2).tolist(),
                  width_split=split, centres=centres.tolist(), logs=counts)
