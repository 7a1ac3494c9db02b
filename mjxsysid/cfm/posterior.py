"""Summaries of decoded posteriors: per-parameter and identifiable-combination means and 5–95 %
bands, and whether a known truth lies inside."""
from __future__ import annotations

import numpy as np

from mjxsysid import theta as P


def summarize_posterior(samples, truth=None) -> dict:
    """samples (S, 19) (+ truth (19,)) -> {name: {mean, q05, q95[, true, inside]}}: θ's 19 parameters
    and the derived quantities of :data:`~mjxsysid.theta.DERIVED_NAMES` (thrust-to-weight, κ, the
    angular authorities)."""
    q05, q95 = np.percentile(samples, [5, 95], 0)
    out = {}
    for j, n in enumerate(P.PARAM_NAMES):
        d = {"mean": float(samples[:, j].mean()), "q05": float(q05[j]), "q95": float(q95[j])}
        if truth is not None:
            d.update(true=float(truth[j]), inside=bool(q05[j] <= truth[j] <= q95[j]))
        out[n] = d
    ident = np.asarray(P.derived(samples))
    iq05, iq95 = np.percentile(ident, [5, 95], 0)
    ti = None if truth is None else np.asarray(P.derived(truth))
    for j, n in enumerate(P.DERIVED_NAMES):
        d = {"mean": float(ident[:, j].mean()), "q05": float(iq05[j]), "q95": float(iq95[j])}
        if ti is not None:
            d.update(true=float(ti[j]), inside=bool(iq05[j] <= ti[j] <= iq95[j]))
        out[n] = d
    return out
