"""The motor-map check (:mod:`mjxsysid.identify.idlecheck`) on the committed simulated logs: how many it flags
or is blind on, and what rules for a flagged log's bands give, from the rows alone (no flight, no posterior).

    python benchmarks/idle_check_rules.py

The sets: ``docs/runs/measurements/log-grounded/idle-check`` (CPU: idle 0.1; no idle with rotor aerodynamics;
the Crazyflie-like √u map; Gazebo-classic's u² read through PX4's thrust model) and the GPU misfit rows
(idle 0.1, every piece in rows/misfit). The rules, on a flagged log:

- none: the check ignored;
- drop all: every coordinate not seen (a flagged log without shifts, the check's first version);
- drop moved: a coordinate whose value under the best map lies outside its calibrated band is not seen;
- widen best: each band widened on one side by its shift under the best map (the check's second version);
- widen span, shifts only: the union of the band moved by each plausible map's shift;
- widen span, values only: the union of the band moved to each plausible map's value, every coordinate;
- widen span (shipped): values for the coordinates the map acts on, shifts for the others
  (:func:`~mjxsysid.identify.idlecheck.widening`, :func:`~mjxsysid.identify.calibrate.checked_stretch`);
- widen span, linear kept: the shipped band joined with the unwidened one.

Coverage is over the coordinates each rule leaves seen (:func:`~mjxsysid.experiments.posterior_calibration.calibrated_bands`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

RUNS = Path("docs/runs/measurements/log-grounded")
SETS = {"CPU, idle 0.1 (seed 78)": RUNS / "idle-check/cpu_idle.json.gz",
        "CPU, no idle, aero (seed 79)": RUNS / "idle-check/cpu_aero.json.gz",
        "CPU, √u map, idle −0.115 (seed 80)": RUNS / "idle-check/cpu_kappa0.json.gz",
        "CPU, u² map, idle 0.09 (seed 81)": RUNS / "idle-check/cpu_convex.json.gz",
        "GPU misfit, idle 0.1": RUNS / "nuts-calibration/rows/misfit"}


def _rows(path: Path) -> list[dict]:
    from mjxsysid.experiments.posterior_calibration import read_rows
    return read_rows(sorted(path.glob("*.json*")) if path.is_dir() else [path])


def rule_bands(row: dict, table: dict, rule: str) -> tuple[np.ndarray, np.ndarray]:
    """A row's calibrated band (2, 12) and seen mask (12,) under ``rule`` (module doc)."""
    from mjxsysid.experiments.posterior_calibration import calibrated_bands
    f = row["features"]
    if rule == "none":
        return calibrated_bands(row | {"features": f | {"idle_gain": 0.0}}, table)
    if rule == "drop all":
        return calibrated_bands(row | {"features": f | {"idle_shift": None, "idle_span": None}}, table)
    if rule == "widen span":
        return calibrated_bands(row, table)
    if rule == "widen best":
        return calibrated_bands(row | {"features": f | {"idle_span": None}}, table)
    if rule == "widen span, shifts only":
        return calibrated_bands(row | {"features": f | {"idle_origin": None}}, table)
    if rule == "widen span, values only":
        from mjxsysid.identify import idlecheck
        mapped, idlecheck.MAPPED = idlecheck.MAPPED, tuple(range(len(row["truth_v"])))
        try:
            return calibrated_bands(row, table)
        finally:
            idlecheck.MAPPED = mapped
    if rule == "widen span, linear kept":
        band, ok = calibrated_bands(row, table)
        b0 = calibrated_bands(row | {"features": f | {"idle_gain": 0.0}}, table)[0]
        return np.stack([np.minimum(band[0], b0[0]), np.maximum(band[1], b0[1])]), ok
    band, ok = calibrated_bands(row | {"features": f | {"idle_gain": 0.0}}, table)      # drop moved
    flagged = (f.get("idle_gain") or 0.0) > table["idle_check"]["threshold"]
    if flagged and f.get("idle_shift") is not None:
        v = np.asarray(row["bands"], np.float64)[1] + np.asarray(f["idle_shift"], np.float64)
        ok = ok & (band[0] <= v) & (v <= band[1])
    elif flagged:
        ok = np.zeros_like(ok)
    return band, ok


def summary(rows: list[dict], table: dict, rule: str) -> dict:
    """{inside_by_coord, seen_by_coord (12,: counts), coverage (over the seen coordinates), seen (share), tw
    (thrust-to-weight inside, where seen), tw_seen, tw_width (the median of thrust-to-weight's band, ± % of its
    centre, where seen)}."""
    ins, seen, tw_w = [], [], []
    for r in rows:
        band, ok = rule_bands(r, table, rule)
        if ok[0]:
            tw_w.append(100 * np.expm1((band[1, 0] - band[0, 0]) / 2))
        tv = np.asarray(r["truth_v"], np.float64)
        ins.append((band[0] <= tv) & (tv <= band[1]))
        seen.append(ok)
    ins, seen = np.array(ins), np.array(seen)
    cov = float((ins & seen).sum() / max(seen.sum(), 1))
    tw_seen = float(seen[:, 0].mean())
    return {"inside_by_coord": (ins & seen).sum(0), "seen_by_coord": seen.sum(0),
            "coverage": round(cov, 3), "seen": round(float(seen.mean()), 2),
            "tw": round(float((ins[:, 0] & seen[:, 0]).sum() / max(seen[:, 0].sum(), 1)), 2), "tw_seen": round(tw_seen, 2),
            "tw_width": round(float(np.median(tw_w)) if tw_w else float("nan"), 1)}


def blind_counts(thr: float) -> dict:
    """The window check's 200 simulated logs without idle (``benchmarks/window_check.py``): per flight, how many
    the motor-map check is blind on (``idle_power`` at most the threshold, :func:`~mjxsysid.identify.idlecheck.blind`)."""
    from mjxsysid.experiments.posterior_calibration import read_json
    rows = read_json(RUNS / "window-check/simulated.json.gz")["rows"]
    return {fl: f"{sum(r['idle_power'] <= thr for r in rows if r['flight'] == fl)} of "
                f"{sum(r['flight'] == fl for r in rows)}" for fl in sorted({r["flight"] for r in rows})}


def main() -> None:
    from mjxsysid.identify.calibrate import for_method, load
    base = load()
    thr = base["idle_check"]["threshold"]
    print(f"blind (no map moves the fit beyond {thr:g}), 200 simulated logs without idle: {blind_counts(thr)}")
    for name, path in SETS.items():
        rows = _rows(path)
        gains = [r["features"].get("idle_gain") for r in rows]
        flights = sorted({r.get("flight", "?").split(" ")[0] for r in rows})
        flags = {fl: f"{sum((g or 0) > thr for g, r in zip(gains, rows) if r.get('flight', '?').startswith(fl))} of "
                     f"{sum(r.get('flight', '?').startswith(fl) for r in rows)}" for fl in flights}
        print(f"{name}: {len(rows)} logs, flagged at {thr:g}: {flags}")
        shifts = all(r["features"].get("idle_shift") is not None for r in rows)
        rules = (("none", "drop all", "drop moved", "widen best", "widen span, linear kept", "widen span, shifts only",
                  "widen span, values only", "widen span") if shifts
                 else ("none", "drop all"))
        for rule in rules:
            t = {m: for_method(base, m) for m in ("smc", "smc_nuts")}
            rs = {m: [r for r in rows if r.get("method") == m] for m in t}
            parts = [summary(rs[m], t[m], rule) | {"n": len(rs[m])} for m in t if rs[m]]
            n = sum(p["n"] for p in parts)
            avg = {k: round(sum(p[k] * p["n"] for p in parts) / n, 3)
                   for k in ("coverage", "seen", "tw", "tw_seen", "tw_width")}
            print(f"  {rule:>23}: inside {avg['coverage']:.2f} of the seen, {100 * avg['seen']:.0f} % seen; "
                  f"thrust-to-weight {avg['tw']:.2f} where seen ({100 * avg['tw_seen']:.0f} % seen, "
                  f"median band ±{avg['tw_width']:.0f} %)")
            if rule.startswith("widen span"):           # per coordinate: inside of seen
                from mjxsysid.experiments.posterior_calibration import V_NAMES
                ins, seen = sum(p["inside_by_coord"] for p in parts), sum(p["seen_by_coord"] for p in parts)
                print(" " * 27 + " ".join(f"{v}:{i}/{k}" for v, i, k in zip(V_NAMES, ins, seen)))


if __name__ == "__main__":
    main()
