"""A model check's threshold from simulated logs and its verdict on one log: shared by the window-length
check (:mod:`.windowcheck`) and the motor-map check (:mod:`.idlecheck`)."""
from __future__ import annotations

import numpy as np


def quantile_of(values, quantile: float, name: str) -> float:
    """The ``quantile`` quantile (numpy's "higher": a statistic a log had) of the statistic ``values`` (None: a
    log the check did not run on, left out); ValueError naming the check ``name`` where none ran."""
    s = np.asarray([x for x in values if x is not None], np.float64)
    if len(s) == 0:
        raise ValueError(f"{name}: no simulated log the check ran on")
    return float(np.quantile(s, quantile, method="higher"))


def entry(rows, feature: str, quantile: float, min_logs: int) -> dict | None:
    """The table's entry from calibration rows whose ``features[feature]`` holds the statistic -> {threshold
    (the ``quantile`` quantile, numpy's "higher"), quantile, logs, above, levels}, or None where fewer than
    ``min_logs`` rows carry it (rows collected before the check)."""
    ran = [r for r in rows if (r.get("features") or {}).get(feature) is not None]
    if len(ran) < min_logs:
        return None
    s = np.asarray([float(r["features"][feature]) for r in ran], np.float64)
    thr = quantile_of(s, quantile, feature)
    return {"threshold": round(thr, 4), "quantile": quantile, "logs": len(ran), "above": int(np.sum(s > thr)),
            "levels": sorted({r["level"] for r in ran})}


def verdict(value, at: str, table_entry: dict | None, name: str, label: str, fmt: str, why: str) -> dict:
    """A log's statistic ``value`` (None: the check did not run; ``at``: where it is largest, or why it did not
    run) against the table's entry -> {value, threshold, ok (None: not run), why}. ``name``: the check's name,
    ``label``: the statistic's, ``fmt``: its format, ``why``: what a log above the threshold lacks."""
    e = table_entry or {}
    thr = e.get("threshold")
    if thr is None or value is None:
        said = "no threshold in the calibration table" if thr is None else (at or "").removeprefix("not run: ") or "?"
        return {"value": value, "threshold": thr, "ok": None, "why": f"{name} not run: {said}"}
    if value <= thr:
        return {"value": value, "threshold": thr, "ok": True,
                "why": f"{label} {value:{fmt}} ({at}) within the threshold {thr:{fmt}}"}
    return {"value": value, "threshold": thr, "ok": False,
            "why": f"{label} {value:{fmt}} ({at}) above the threshold {thr:{fmt}} (the {e.get('quantile', 0.99):g} "
                   f"quantile over {e.get('logs', '?')} simulated logs): {why}"}
