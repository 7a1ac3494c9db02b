"""The information gap: what the decoders (the policy's latent) say against what the log shows,
per log-identifiable quantity (:data:`~mjxsysid.identify.coords.LOG_NAMES`)."""
from __future__ import annotations

import numpy as np

from mjxsysid.identify.coords import LOG_NAMES, LOG_UNITS, log_quantities


def _band(q):
    lo, med, hi = np.percentile(q, [5, 50, 95], 0)
    return lo, med, hi


def information_gap(decoded_theta, grounded_theta, truth=None) -> dict:
    """Decoded samples θ (S, 19) and log-grounded samples θ (S', 19) (and the truth (19,)) ->
    {quantity: {decoder_q05, decoder_q95, log_q05, log_median, log_q95, width_ratio (decoder
    width / log width; log-scale for positive quantities), decoder_holds_log_median[, true,
    log_inside, decoder_inside]}}."""
    qd, qg = log_quantities(decoded_theta), log_quantities(grounded_theta)
    dlo, _, dhi = _band(qd)
    glo, gmed, ghi = _band(qg)
    tq = None if truth is None else log_quantities(np.asarray(truth)[None])[0]
    out = {}
    for j, name in enumerate(LOG_NAMES):
        pos = np.all(qd[:, j] > 0) and np.all(qg[:, j] > 0)
        wd = np.log(dhi[j] / dlo[j]) if pos else dhi[j] - dlo[j]
        wg = np.log(ghi[j] / glo[j]) if pos else ghi[j] - glo[j]
        d = {"unit": LOG_UNITS[j], "decoder_q05": float(dlo[j]), "decoder_q95": float(dhi[j]),
             "log_q05": float(glo[j]), "log_median": float(gmed[j]), "log_q95": float(ghi[j]),
             "width_ratio": float(wd / wg) if wg > 0 else float("inf"),
             "decoder_holds_log_median": bool(dlo[j] <= gmed[j] <= dhi[j])}
        if tq is not None:
            d.update(true=float(tq[j]), log_inside=bool(glo[j] <= tq[j] <= ghi[j]),
                     decoder_inside=bool(dlo[j] <= tq[j] <= dhi[j]))
        out[name] = d
    return out


def gap_markdown(gap: dict) -> list[str]:
    """The gap as summary.md lines (a table)."""
    has_truth = any("true" in v for v in gap.values())
    head = "| quantity | decoder 5–95 % | log-grounded 5–95 % (median) | width ratio | decoder holds log median |"
    lines = [head + (" true |" if has_truth else ""), "|---" * (5 + has_truth) + "|"]
    for k, v in gap.items():
        row = (f"| {k} ({v['unit']}) | {v['decoder_q05']:.4g} – {v['decoder_q95']:.4g} | {v['log_q05']:.4g} – "
               f"{v['log_q95']:.4g} ({v['log_median']:.4g}) | {v['width_ratio']:.3g} | "
               f"{'yes' if v['decoder_holds_log_median'] else 'no'} |")
        if has_truth:
            row += f" {v['true']:.4g} |"
        lines.append(row)
    return lines
