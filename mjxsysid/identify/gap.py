"""The information gap: what the decoders (the policy's latent) say against what the log shows,
per log-identifiable quantity (:data:`~mjxsysid.identify.logspace.QUANTITIES`); the log quantities'
summary, and one summary of them with θ's (each quantity once, by one name)."""
from __future__ import annotations

import warnings

import numpy as np

from mjxsysid.identify.coords import PHYSICAL_PRIOR, PhysicalPrior, log_quantities
from mjxsysid.identify.logspace import LOG_NAMES, LOG_UNITS, QUANTITIES, QUANTITY, RENAMED, V_OF_QUANTITY

UNSEEN_FRACTION = 0.5
"""A log-grounded 90 % band wider than this share of the prior's range: the log did not see the
quantity (it stays as broad as the prior says)."""


class Summary(dict):
    """A summary keyed by quantity name that still answers an old name of :data:`~.logspace.RENAMED`,
    with a FutureWarning naming the new one."""

    def __missing__(self, key):
        new = RENAMED.get(key)
        if new is None or new not in self:
            raise KeyError(key)
        warnings.warn(f"{key!r} is now {new!r} (one name per quantity); the old name goes in the next release",
                      FutureWarning, stacklevel=2)
        return self[new]

    def get(self, key, default=None):
        return self[key] if key in self or RENAMED.get(key) in self else default


def prior_ranges(prior: PhysicalPrior = PHYSICAL_PRIOR) -> tuple[np.ndarray, np.ndarray]:
    """Each quantity's (:data:`LOG_NAMES`) range under the prior -> lo (13,), hi (13,): its coordinate's
    box, exponentiated for a log coordinate; ρ_4's the truncation's (``rel_eff``)."""
    vlo, vhi = prior.v_bounds()
    rows = []
    for q, idx in zip(QUANTITIES, V_OF_QUANTITY):
        if q.form == "rest":
            rows.append(prior.rel_eff)
        else:
            r = (vlo[idx[0]], vhi[idx[0]])
            rows.append(np.exp(r) if q.form == "exp" else r)
    b = np.asarray(rows, np.float64)
    return b[:, 0], b[:, 1]


def prior_widths(prior: PhysicalPrior = PHYSICAL_PRIOR) -> np.ndarray:
    """Each quantity's prior range, in the units the gap measures widths in (log for the
    positive ones, plain for τ_ext/J) -> (13,)."""
    lo, hi = prior_ranges(prior)
    return np.where(lo > 0, np.log(np.abs(hi / lo)), hi - lo)


def _band(q):
    lo, med, hi = np.percentile(q, [5, 50, 95], 0)
    return lo, med, hi


def log_summary(samples, truth=None) -> dict:
    """θ samples (S, 19) (+ truth (19,)) -> {quantity of LOG_NAMES: {mean, q05, q95[, true, inside]}},
    the form of :func:`~mjxsysid.cfm.posterior.summarize_posterior`."""
    q = log_quantities(samples)
    lo, hi = np.percentile(q, [5, 95], 0)
    tq = None if truth is None else log_quantities(np.asarray(truth)[None])[0]
    out = {}
    for j, n in enumerate(LOG_NAMES):
        d = {"mean": float(q[:, j].mean()), "q05": float(lo[j]), "q95": float(hi[j])}
        if tq is not None:
            d.update(true=float(tq[j]), inside=bool(lo[j] <= tq[j] <= hi[j]))
        out[n] = d
    return Summary(out)


HIDDEN_WHY = ("made of the hidden coordinates (mass, arm length, Ω_max, η̄, drag), which an IMU log does not "
              "change with: as broad as the prior")
"""Why a quantity of θ's summary that is not a log quantity is not seen by the log."""


def joint_summary(theta_summary: dict, log_summary: dict, seen: dict | None = None) -> dict:
    """θ's summary (:func:`~mjxsysid.cfm.posterior.summarize_posterior`: 19 parameters and the derived
    quantities) and the log quantities' (:func:`log_summary`) as one, each quantity once by its one name.
    A quantity both tables give (``in_theta`` of :data:`~.logspace.QUANTITIES`: the same definition) is
    θ's entry; any other name in both raises ValueError instead of overwriting one with the other.

    ``seen`` ({log quantity: (seen, why)}, a log-grounded posterior's): every entry then says whether
    the log saw it (``seen_by_log``) and why; θ's other entries are not seen (:data:`HIDDEN_WHY`)."""
    clash = sorted(k for k in log_summary if k in theta_summary and not (k in QUANTITY and QUANTITY[k].in_theta))
    if clash:
        raise ValueError(f"the log's and θ's summaries both name {clash} as different quantities: one name per "
                         f"quantity (identify/logspace.py QUANTITIES, theta DERIVED_NAMES)")
    out = Summary({**theta_summary, **{k: v for k, v in log_summary.items() if k not in theta_summary}})
    if seen is not None:
        for k, v in out.items():
            ok, why = seen[k] if k in QUANTITY else (False, HIDDEN_WHY)
            out[k] = {**v, "seen_by_log": bool(ok), "why": why}
    return out


def seen_by_name(report: dict) -> dict:
    """A calibration report (:func:`~.calibrate.calibrate`: ``seen`` (12,), ``why`` (12,)) -> {LOG_NAMES
    quantity: (seen, why)}; a quantity made of several coordinates is seen when all of them are."""
    out = {}
    for name, js in zip(LOG_NAMES, V_OF_QUANTITY):
        bad = [k for k in js if not report["seen"][k]]
        out[name] = (not bad, report["why"][bad[0] if bad else js[0]])
    return out


def information_gap(decoded_theta, grounded_theta, truth=None, prior: PhysicalPrior = PHYSICAL_PRIOR,
                    seen: dict | None = None) -> dict:
    """Decoded samples θ (S, 19) and log-grounded samples θ (S', 19) (and the truth (19,)) ->
    {quantity: {decoder_q05, decoder_q95, log_q05, log_median, log_q95, width_ratio (decoder
    width / log width; log-scale for positive quantities), decoder_holds_log_median[, true,
    log_inside, decoder_inside], prior_fraction (the log band's width over the prior's range),
    seen_by_log, seen_why}}: ``seen`` {quantity: (bool, why)} from the calibration
    (:func:`seen_by_name`: a calibrated band narrower than half the prior's range and a model check
    passed), else prior_fraction < :data:`UNSEEN_FRACTION`."""
    qd, qg = log_quantities(decoded_theta), log_quantities(grounded_theta)
    dlo, _, dhi = _band(qd)
    glo, gmed, ghi = _band(qg)
    tq = None if truth is None else log_quantities(np.asarray(truth)[None])[0]
    pw = prior_widths(prior)
    out = {}
    for j, name in enumerate(LOG_NAMES):
        pos = np.all(qd[:, j] > 0) and np.all(qg[:, j] > 0)
        wd = np.log(dhi[j] / dlo[j]) if pos else dhi[j] - dlo[j]
        wg = np.log(ghi[j] / glo[j]) if pos else ghi[j] - glo[j]
        d = {"unit": LOG_UNITS[j], "decoder_q05": float(dlo[j]), "decoder_q95": float(dhi[j]),
             "log_q05": float(glo[j]), "log_median": float(gmed[j]), "log_q95": float(ghi[j]),
             "width_ratio": float(wd / wg) if wg > 0 else float("inf"),
             "decoder_holds_log_median": bool(dlo[j] <= gmed[j] <= dhi[j]),
             "prior_fraction": float(wg / pw[j])}
        if seen is not None and name in seen:
            d["seen_by_log"], d["seen_why"] = bool(seen[name][0]), seen[name][1]
        else:
            d["seen_by_log"] = d["prior_fraction"] < UNSEEN_FRACTION
            d["seen_why"] = f"the band is {d['prior_fraction']:.2g} of the prior's range"
        if tq is not None:
            d.update(true=float(tq[j]), log_inside=bool(glo[j] <= tq[j] <= ghi[j]),
                     decoder_inside=bool(dlo[j] <= tq[j] <= dhi[j]))
        out[name] = d
    return Summary(out)


def gap_markdown(gap: dict) -> list[str]:
    """The gap as summary.md lines (a table)."""
    has_truth = any("true" in v for v in gap.values())
    head = ("| quantity | decoder 5–95 % | log-grounded 5–95 % (median) | width ratio | decoder holds log median "
            "| seen by the log |")
    lines = [head + (" true |" if has_truth else ""), "|---" * (6 + has_truth) + "|"]
    for k, v in gap.items():
        row = (f"| {k} ({v['unit']}) | {v['decoder_q05']:.4g} – {v['decoder_q95']:.4g} | {v['log_q05']:.4g} – "
               f"{v['log_q95']:.4g} ({v['log_median']:.4g}) | {v['width_ratio']:.3g} | "
               f"{'yes' if v['decoder_holds_log_median'] else 'no'} | "
               f"{'yes' if v['seen_by_log'] else 'no: as broad as the prior'} |")
        if has_truth:
            row += f" {v['true']:.4g} |"
        lines.append(row)
    return lines
