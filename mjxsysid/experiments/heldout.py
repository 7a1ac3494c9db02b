"""Held-out evaluation: every policy against the oracle on vehicles no method trains on.

The sets (:data:`SETS`): the default prior, the stress prior, ``stress_wide`` and the held-out
families of :data:`mjxsysid.theta.HELDOUT_FAMILIES` (one motor at η 0.5, τ_m 0.08–0.10 s,
thrust-to-weight 1.6–1.8, a constant roll/pitch torque as from an off-centre payload, a large
constant yaw torque). Each set's vehicles are drawn once and flown by the oracle (the lag-aware
K_θ with each vehicle's true θ, ``rollout.flight.make_low_level('oracle')``) and by every policy,
on a ``period`` s lemniscate; per set and policy:

- ``success_policy`` / ``success_oracle``: the fraction of vehicles not lost;
- ``rmse_ratio``: the policy's mean position RMSE over the oracle's, on the vehicles both flew;
- ``lost_beyond_oracle``: vehicles the oracle flies and the policy loses (the failures that are
  the policy's own); ``fails_more_than_oracle``: the policy loses more vehicles than the oracle.

Targets (checked per policy by :func:`heldout_targets`): every held-out family at ≤ 1.3× the
oracle and none failing more than the oracle.

``mjxsysid evaluate-policy --held-out`` runs it from the command line.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Mapping

import jax
import numpy as np

from mjxsysid import theta as P
from mjxsysid.experiments.common import markdown_table, mean_std, write_results
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.rollout.flight import fly_vehicles

PRIOR_SETS = ("default", "stress", "stress_wide")
FAMILIES = tuple(P.HELDOUT_FAMILIES)
SETS = PRIOR_SETS + FAMILIES
RATIO_TARGET = 1.3


def set_vehicles(name: str, n: int, seed: int = 0) -> np.ndarray:
    """θ (n, 19) of an evaluation set: a held-out family's own seeded vehicles
    (:meth:`~mjxsysid.theta.HeldOutFamily.vehicles`), a prior's draws (seeded by ``seed`` and the
    set's place in :data:`SETS`), or the paper vehicle (``'paper'``, n ignored)."""
    if name == "paper":
        return P.PAPER_HARDWARE[None].copy()
    if name in P.HELDOUT_FAMILIES:
        return P.HELDOUT_FAMILIES[name].vehicles(n)
    if name not in P.PRIORS:
        raise ValueError(f"unknown evaluation set {name!r}; choose from {list(SETS) + ['paper']}")
    key = jax.random.fold_in(jax.random.PRNGKey(seed + 17), SETS.index(name) if name in SETS else len(SETS))
    return np.asarray(P.get_prior(name).sample(key, n))


def compare_with_oracle(policy_metrics: Mapping, oracle_metrics: Mapping) -> dict:
    """A policy's flights against the oracle's on the same vehicles: metrics dicts of
    :func:`~mjxsysid.rollout.flight.fly_vehicles` ((B,) ``failed`` and ``pos_rmse_m``) -> success
    of each, the RMSE ratio on the vehicles both flew (None if none), the policy's own losses."""
    fp, fo = np.asarray(policy_metrics["failed"]) > 0.5, np.asarray(oracle_metrics["failed"]) > 0.5
    both = ~fp & ~fo
    rp, ro = np.asarray(policy_metrics["pos_rmse_m"]), np.asarray(oracle_metrics["pos_rmse_m"])
    return {"n": int(len(fp)), "success_policy": float(1 - fp.mean()), "success_oracle": float(1 - fo.mean()),
            "success_policy_where_oracle_flies": float(1 - fp[~fo].mean()) if (~fo).any() else None,
            "pos_rmse_policy": mean_std(rp[both]), "pos_rmse_oracle": mean_std(ro[both]),
            "rmse_ratio": float(rp[both].mean() / ro[both].mean()) if both.any() else None,
            "n_both": int(both.sum()), "lost_beyond_oracle": int((fp & ~fo).sum()),
            "fails_more_than_oracle": bool(fp.sum() > fo.sum())}


def evaluate_policies(policies: Mapping, *, sets=SETS, vehicles: int = 64, period: float = 10.0, seed: int = 0,
                      log=None) -> dict:
    """Every policy of ``policies`` (label -> name, path or resolved policy) and the oracle on
    ``vehicles`` vehicles of each set, a ``period`` s lemniscate -> {set: {"vehicles": summary,
    "oracle": success, label: :func:`compare_with_oracle`}}. The oracle flies each set once."""
    log = log or (lambda m: None)
    if not policies:
        raise ValueError("policies: give at least one policy to evaluate")
    if not isinstance(vehicles, (int, np.integer)) or isinstance(vehicles, bool) or vehicles < 1:
        raise ValueError(f"vehicles must be a positive integer, got {vehicles!r}")
    if not period > 0:
        raise ValueError(f"period must be > 0 s, got {period}")
    bad = [s for s in sets if s != "paper" and s not in P.HELDOUT_FAMILIES and s not in P.PRIORS]
    if bad:
        raise ValueError(f"sets: unknown {bad}; choose from {list(SETS) + ['paper']}")
    refs = {label: resolve_policy(p) for label, p in policies.items()}
    res = {}
    for s in sets:
        theta = set_vehicles(s, vehicles, seed)
        t = time.time()
        _, mo, _ = fly_vehicles(theta, controller="oracle", reference="lemniscate", period=period, seed=seed)
        res[s] = {"vehicles": {"n": int(len(theta)),
                               "thrust_to_weight_median": float(np.median(np.asarray(P.thrust_to_weight(theta)))),
                               "tau_m_median_s": float(np.median(theta[:, P.TAU_M]))},
                  "oracle_success": float(1 - (np.asarray(mo["failed"]) > 0.5).mean())}
        for label, ref in refs.items():
            _, mp, _ = fly_vehicles(theta, controller="policy", policy=ref, reference="lemniscate", period=period,
                                    seed=seed)
            res[s][label] = compare_with_oracle(mp, mo)
        log(f"held-out: {s}: oracle {res[s]['oracle_success']:.1%}; "
            + ", ".join(f"{k} {_cell(res[s][k])}" for k in refs) + f" ({time.time() - t:.0f} s)")
    return res


def heldout_targets(res: dict, label: str) -> dict:
    """Per held-out family in ``res``: the policy ``label`` at ≤ 1.3× the oracle, and not failing
    more than the oracle; ``all``: every family meets both."""
    t = {}
    for s in res:
        if s in P.HELDOUT_FAMILIES:
            e = res[s][label]
            t[s] = {"ratio_le_1.3x": e["rmse_ratio"] is not None and e["rmse_ratio"] <= RATIO_TARGET,
                    "fails_no_more_than_oracle": not e["fails_more_than_oracle"]}
    t["all"] = all(v["ratio_le_1.3x"] and v["fails_no_more_than_oracle"] for v in t.values())
    return t


def _cell(e: dict) -> str:
    ratio = "–" if e["rmse_ratio"] is None else f"{e['rmse_ratio']:.2f}×"
    lost = f", {e['lost_beyond_oracle']} lost" if e["lost_beyond_oracle"] else ""
    s = e["success_policy"]
    return f"{s:.0%}, {ratio}{lost}" if s in (0.0, 1.0) else f"{s:.1%}, {ratio}{lost}"


def heldout_table(res: dict, labels) -> str:
    """Markdown: a row per policy, a column per set (success, RMSE ratio, vehicles lost that the
    oracle flies), the oracle's success in the header; then each policy's targets."""
    sets = list(res)
    header = ["policy"] + [f"{s} (oracle {res[s]['oracle_success']:.1%})" for s in sets] + ["held-out targets"]
    rows = []
    for label in labels:
        tg = heldout_targets(res, label)
        n_fam = len([s for s in sets if s in P.HELDOUT_FAMILIES])
        met = sum(v["ratio_le_1.3x"] and v["fails_no_more_than_oracle"] for k, v in tg.items() if k != "all")
        rows.append([label] + [_cell(res[s][label]) for s in sets] + [f"{met}/{n_fam} families"])
    return markdown_table(header, rows)


def parse_policies(items) -> dict:
    """``LABEL=PATH`` or ``PATH`` items (a path's label: its folder's name for a policy.npz, else
    its stem; ``mjxsysid`` or nothing: the shipped policy) -> {label: name or path}."""
    out = {}
    for it in items or ["shipped=mjxsysid"]:
        it = str(it)
        label, _, path = it.partition("=") if "=" in it else ("", "", it)
        if not label:
            p = Path(path)
            label = "shipped" if path == "mjxsysid" else (p.parent.name if p.name == "policy.npz" else p.stem)
        if label in out:
            raise ValueError(f"--weights: two policies labelled {label!r}; name them LABEL=PATH")
        out[label] = path
    return out


def run(out, policies: Mapping | None = None, *, sets=SETS, vehicles: int = 64, period: float = 10.0,
        seed: int = 0, progress: bool = True) -> dict:
    """:func:`evaluate_policies` written to OUT/results.json and OUT/results.md (table,
    targets, provenance); returns the results dict."""
    t0 = time.time()
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if progress else None
    policies = dict(policies or {"shipped": "mjxsysid"})
    res = evaluate_policies(policies, sets=sets, vehicles=vehicles, period=period, seed=seed, log=log)
    refs = {k: resolve_policy(v) for k, v in policies.items()}
    config = {"vehicles": vehicles, "period_s": period, "sets": list(sets),   # no quick mode: the size is in the notes
              "oracle": "lag-aware K_θ (true θ)",
              "families": {k: P.HELDOUT_FAMILIES[k].description for k in sets if k in P.HELDOUT_FAMILIES},
              "policies": {k: {"kind": r.kind, "weights": str(r.weights), "sha256": r.sha256()} for k, r in refs.items()}}
    numbers = {"evaluation": res, "targets": {k: heldout_targets(res, k) for k in policies}}
    notes = (f"{vehicles} vehicles per set, {period:g} s lemniscate; cell: success, RMSE over the oracle's on the "
             f"vehicles both flew, vehicles lost that the oracle flies. Targets: every held-out family ≤ "
             f"{RATIO_TARGET}× the oracle and none failing more than the oracle.")
    return write_results(out, "held-out", config=config, seeds={"seed": seed}, numbers=numbers,
                         table_md=heldout_table(res, list(policies)), t0=t0, notes=notes)
