"""`mjxsysid experiment replay` (paper §VI, action-prediction table): the action replay of
:func:`mjxsysid.uses.replay.run_replay` in the common experiment format, with the paper's
numbers beside ours. The payload row of the paper's table is `mjxsysid experiment payload`.

Writes results.json, results.md and run_replay's own replay.json, replay.md,
replay_<flight>.png and replay_summary.png.
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

from mjxsysid.experiments.common import markdown_table, write_results
from mjxsysid.policy.interface import resolve_policy
from mjxsysid.uses.replay import run_replay

PAPER = {  # paper Table (action prediction on hardware): flight -> method -> (RMSE, PCC)
    "lemniscate_5s": {"random": (0.141, 0.202), "regression": (0.059, 0.077), "cfm": (0.032, 0.723)},
    "lemniscate_10s": {"random": (0.151, 0.080), "regression": (0.064, 0.145), "cfm": (0.034, 0.710)},
    "lemniscate_15s": {"random": (0.154, 0.103), "regression": (0.073, 0.172), "cfm": (0.032, 0.775)},
}
LABELS = {"random": "Random", "regression": "Regression", "cfm": "CFM (1 sample)", "cfm_mean": "CFM (mean action)",
          "true": "true θ (reference)"}


@dataclasses.dataclass(frozen=True)
class ReplayConfig:
    """Arguments of :func:`~mjxsysid.uses.replay.run_replay`: vehicles of the policy's prior
    beside the paper vehicle, flights, decode rate (Hz), CFM samples for the mean action, PCC
    low-pass cutoff (Hz)."""
    vehicles: int = 32
    flights: tuple = ("lemniscate_5s", "lemniscate_10s", "lemniscate_15s", "hover")
    rate: float = 10.0
    samples: int = 16
    cutoff_hz: float = 5.0


FULL = ReplayConfig()
QUICK = ReplayConfig(vehicles=2, flights=("lemniscate_5s",), samples=4)


def run(out, *, quick: bool = False, policy=None, seed: int = 0, progress: bool = True, decoders=None,
        cfg: ReplayConfig | None = None) -> dict:
    """Run the action replay into ``out``; returns the results dict."""
    t0 = time.time()
    log = (lambda m: print(m, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    cfg = cfg or (QUICK if quick else FULL)
    ref = resolve_policy(policy or "mjxsysid")
    res = run_replay(out, policy=ref, decoders=decoders, vehicles=cfg.vehicles, flights=tuple(cfg.flights),
                     rate=cfg.rate, samples=cfg.samples, cutoff_hz=cfg.cutoff_hz, seed=seed, log=log)
    numbers = {"flights": res["flights"], "paper": {f: {m: {"rmse": v[0], "pcc": v[1]} for m, v in d.items()}
                                                   for f, d in PAPER.items()}}
    head = {}
    for f, e in res["flights"].items():
        pv = e.get("paper_vehicle")
        if pv:
            for m in ("cfm", "cfm_mean", "regression", "random"):
                head[f"{f}_{m}_rmse"] = pv[m]["rmse"]
            head[f"{f}_cfm_pcc"] = pv["cfm"]["pcc"]
    numbers["headline"] = head
    numbers["cfm_best"] = cfm_best(res)
    config = {"quick": quick, **dataclasses.asdict(cfg)}
    dec_dir = Path(decoders) if decoders is not None else ref.decoders_dir
    return write_results(out, "replay", config=config, seeds={"seed": seed, "prior_key": f"PRNGKey({seed + 7})"},
                         numbers=numbers, table_md=table_md(res), t0=t0, policy=ref, decoders=dec_dir,
                         notes=NOTES)


NOTES = """
Paper: hardware flights of its own policy. Ours: simulated flights of the paper vehicle (and prior
vehicles, mean ± std) with the chosen policy; K_θ̂ is fed the recorded gyro and commands, θ̂ decoded at
10 Hz; RMSE on raw Ω/Ω_max, PCC after a zero-phase 5 Hz low-pass, mean over motors. "CFM (1 sample)" is
the paper's protocol; "CFM (mean action)" averages K_θ̂ over samples. The payload row is in the payload
experiment.
"""


def cfm_best(res: dict) -> dict:
    """Per flight (paper vehicle): does CFM (1 sample / mean action) beat Regression and Random on
    RMSE and on PCC?"""
    out = {}
    for f, e in res["flights"].items():
        pv = e.get("paper_vehicle")
        if not pv:
            continue
        others_r = min(pv["regression"]["rmse"], pv["random"]["rmse"])
        others_p = max(np.nan_to_num(pv["regression"]["pcc"], nan=-1), np.nan_to_num(pv["random"]["pcc"], nan=-1))
        out[f] = {m: {"rmse": pv[m]["rmse"] < others_r, "pcc": bool(np.nan_to_num(pv[m]["pcc"], nan=-1) > others_p)}
                  for m in ("cfm", "cfm_mean")}
    return out


def _p(x, d):
    return "–" if x is None or not np.isfinite(x) else f"{x:.{d}f}"


def table_md(res: dict) -> str:
    rows = []
    for f, e in res["flights"].items():
        pv, pr = e.get("paper_vehicle"), e.get("prior_vehicles")
        for m, lab in LABELS.items():
            p = PAPER.get(f, {}).get(m)
            ours = f"{pv[m]['rmse']:.3f} / {_p(pv[m]['pcc'], 2)}" if pv else "crashed"
            pri = (f"{pr[m]['rmse']['mean']:.3f} ± {pr[m]['rmse']['std']:.3f} / "
                   f"{_p(pr[m]['pcc']['mean'], 2)} ± {_p(pr[m]['pcc']['std'], 2)}") if pr else "–"
            rows.append([f.replace("_", " "), lab, f"{p[0]:.3f} / {p[1]:.3f}" if p else "–", ours, pri])
    n = next((e["prior_vehicles"]["n"] for e in res["flights"].values() if e.get("prior_vehicles")), 0)
    return ("## Action replay: motor-command RMSE ↓ / PCC ↑\n\n"
            + markdown_table(["flight", "method", "paper (hardware)", "ours: paper vehicle",
                              f"ours: {n} prior vehicles (mean ± std)"], rows))
