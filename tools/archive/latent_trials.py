"""Short controlled trials on the policy latent (issue 11 §2): one factor changed at a time from
the shipped TrainConfig, each trained for the same reduced number of iterations (the control is
the shipped config at that length) and scored with :func:`mjxsysid.policy.adaptive.evaluate.fast_eval`.

    python tools/latent_trials.py --out OUT [--iterations 400] [--budget-s 430] [--full-eval]

Trials that differ only in loss weights share one compiled iteration (Trainer.reweighted); the
others compile their own. After each trial OUT/trials.json is rewritten (so a run cut short
still returns the finished trials); trials that would not finish inside ``--budget-s`` are
skipped and listed. The best trial that keeps control (fast-eval success ≥ 99 %, RMSE ≤ 1.1 ×
oracle; ranked by the probe R² of thrust-to-weight) has its weights and log copied to
OUT/best_*; with ``--full-eval`` it is also evaluated with ``evaluate_policy`` on 1,000
vehicles if ``--full-eval-s`` are left in the budget (OUT/best_eval.json).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import jax
import numpy as np

from mjxsysid.policy.adaptive.config import EnvConfig, TrainConfig
from mjxsysid.policy.adaptive.env import TrainEnv
from mjxsysid.policy.adaptive.evaluate import evaluate_policy, fast_eval
from mjxsysid.policy.adaptive.losses import LOSS_WEIGHT_FIELDS
from mjxsysid.policy.adaptive.train import train
from mjxsysid.policy.adaptive.trainer import Trainer
from mjxsysid.policy.adaptive.weights import load_policy_params
from mjxsysid.sim import Quadrotor

BASE_ENV = EnvConfig()
# The trials were run against the config shipped before 2026-11-24 (no identifiable-combination
# reconstruction); the winner (rec_ident + yaw authority) is today's TrainConfig default.
TRIAL_BASE = TrainConfig(rec_ident_coef=0.0, ident_yaw_authority=False)
# name -> (what changes and why, TrainConfig overrides; "env" overrides EnvConfig fields)
TRIALS = {
    "control": ("shipped config (same length)", {}),
    "rec_ident": ("+ reconstruction of log T/W, log κ, log authority, log τ_m (weight 1)",
                  {"rec_ident_coef": 1.0}),
    "rec_ident_only": ("reconstruct the identifiable combinations instead of θ (rec 0, ident 1)",
                       {"rec_ident_coef": 1.0, "rec_coef": 0.0}),
    "rec_x10": ("θ reconstruction weight 0.1 → 1", {"rec_coef": 1.0}),
    "lambda1_0.1": ("λ1 (μ pulled towards ẑ) 1 → 0.1", {"lambda1": 0.1}),
    "var_0.3": ("variance hinge 0.1 → 0.3 (latent scale)", {"var_target": 0.3}),
    "excite_x2": ("command excitation ×2 (rates 4, 4, 2 rad/s; thrust 4 m/s²)",
                  {"env": {"excite_rate": (4.0, 4.0, 2.0), "excite_thrust": 4.0}}),
    "rec_ident_lambda1_0.1": ("rec_ident and λ1 0.1 together", {"rec_ident_coef": 1.0, "lambda1": 0.1}),
}


def trial_config(base: TrainConfig, overrides: dict) -> TrainConfig:
    over = dict(overrides)
    env = dataclasses.replace(base.env, **over.pop("env", {}))
    return dataclasses.replace(base, env=env, **over)


def rank_key(summary: dict) -> float:
    """Higher is better: mean probe R² of thrust-to-weight (training commands and flight)."""
    return 0.5 * (summary["train_cmds"]["r2_thrust_to_weight"] + summary["flight"]["r2_thrust_to_weight"])


def keeps_control(summary: dict) -> bool:
    return summary["success_policy"] >= 0.99 and (summary["rmse_ratio"] or np.inf) <= 1.1


def render_table(report: dict) -> str:
    """Markdown table of a trials.json report."""
    f = lambda x: "—" if x is None else f"{x:.3f}" if isinstance(x, float) else str(x)
    lines = ["| trial | change | R² T/W (cmds / flight) | R² κ (flight) | R² authority (flight) | "
             "R² τ_m (flight) | z_err_rel (cmds / flight) | success | RMSE / oracle |",
             "|---|---|---|---|---|---|---|---|---|"]
    for t in report["trials"]:
        s, c, fl = t["summary"], t["summary"]["train_cmds"], t["summary"]["flight"]
        lines.append(f"| {t['name']} | {t['change']} | {f(c['r2_thrust_to_weight'])} / {f(fl['r2_thrust_to_weight'])} "
                     f"| {f(fl['r2_kappa'])} | {f(fl['r2_authority'])} | {f(fl['r2_tau_m'])} "
                     f"| {f(c['z_err_rel'])} / {f(fl['z_err_rel'])} | {f(s['success_policy'])} | {f(s['rmse_ratio'])} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--table", type=Path, default=None, help="only render this trials.json as OUT (markdown)")
    ap.add_argument("--runs", type=Path, default=None, help="trial run folders (default OUT/runs)")
    ap.add_argument("--trials", default=",".join(TRIALS), help="comma-separated, in order")
    ap.add_argument("--iterations", type=int, default=400)
    ap.add_argument("--num-envs", type=int, default=None)
    ap.add_argument("--unroll", type=int, default=None)
    ap.add_argument("--n-probe", type=int, default=2000)
    ap.add_argument("--n-lem", type=int, default=1000)
    ap.add_argument("--eval-steps", type=int, default=1000)
    ap.add_argument("--flight-steps", type=int, default=1500)
    ap.add_argument("--period", type=float, default=10.0, help="lemniscate period of the fast evaluation, s")
    ap.add_argument("--any-best", action="store_true", help="(rehearsal) pick a best trial even if it loses control")
    ap.add_argument("--budget-s", type=float, default=430.0, help="wall-clock budget for the whole script")
    ap.add_argument("--full-eval", action="store_true")
    ap.add_argument("--full-eval-vehicles", type=int, default=1000)
    ap.add_argument("--full-eval-s", type=float, default=120.0, help="time the full evaluation needs")
    args = ap.parse_args(argv)
    if args.table is not None:
        args.out.write_text(render_table(json.loads(args.table.read_text())))
        return 0
    t0 = time.time()
    names = [t for t in args.trials.split(",") if t]
    bad = [t for t in names if t not in TRIALS]
    if bad:
        print(f"unknown trial(s) {bad}; known: {list(TRIALS)}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    runs = args.runs or args.out / "runs"
    over = {k: v for k, v in (("iterations", args.iterations), ("num_envs", args.num_envs),
                               ("unroll", args.unroll)) if v is not None}
    base = dataclasses.replace(TRIAL_BASE, **over)
    # Loss-weight-only trials share one compile; the others compile their own.
    shared = [t for t in names if set(TRIALS[t][1]) <= set(LOSS_WEIGHT_FIELDS)]
    log = lambda m: print(f"[{time.time() - t0:6.1f}s] {m}", flush=True)
    log(f"device {jax.devices()[0]}, jax {jax.__version__}; trials {names}; base {over}")

    eval_env = TrainEnv(EnvConfig(episode_steps=args.eval_steps + 1))
    sim, cache = Quadrotor(), {}
    report = {"base_overrides": over, "device": str(jax.devices()[0]), "jax": jax.__version__,
              "n_probe": args.n_probe, "n_lem": args.n_lem, "trials": [], "skipped": []}
    trainer0, durations = None, []

    def dump():
        report["wall_s"] = time.time() - t0
        (args.out / "trials.json").write_text(json.dumps(report, indent=1, default=float) + "\n")

    for name in names:
        what, ov = TRIALS[name]
        cfg = trial_config(base, ov)
        # A trial costs about the cheapest one so far, plus the first one's compile overhead if it
        # cannot reuse the shared compile (the GPU run of 2026-11-23 used max(): it skipped 3
        # trials that would have fit).
        est = min(durations) if durations else 0.0
        if durations and (name not in shared or trainer0 is None):
            est += max(durations) - min(durations)
        if durations and time.time() - t0 + est > args.budget_s:
            log(f"skip {name}: {est:.0f} s would overrun the budget")
            report["skipped"].append(name)
            continue
        ts = time.time()
        if name in shared:
            trainer0 = trainer0 or Trainer(base)
            trainer = trainer0.reweighted(cfg)
        else:
            trainer = Trainer(cfg)
        log(f"trial {name}: {what}")
        res = train(cfg, runs / name, resume=False, trainer=trainer,
                    log=lambda m: log("  " + m) if m.startswith(("it     1/", f"it {cfg.iterations:5d}")) else None)
        t_train = time.time() - ts
        params, _ = load_policy_params(runs / name / "policy.npz")
        ev = fast_eval(params, n_probe=args.n_probe, n_lem=args.n_lem, steps=args.eval_steps,
                       flight_steps=args.flight_steps, period=args.period, phi_every=cfg.env.phi_every,
                       env=eval_env, sim=sim,
                       cache=cache, log=log)
        rows = [json.loads(x) for x in (runs / name / "train_log.jsonl").read_text().splitlines()]
        report["trials"].append({"name": name, "change": what, "overrides": ov, "train_s": t_train,
                                 "eval_s": time.time() - ts - t_train, "final_train_stats": res["stats"],
                                 "train_log": rows[::max(1, len(rows) // 20)] + rows[-1:],
                                 "summary": ev["summary"], "eval": ev})
        durations.append(time.time() - ts)
        s = ev["summary"]
        log(f"  {name}: R² T/W {s['train_cmds']['r2_thrust_to_weight']:.3f} (flight "
            f"{s['flight']['r2_thrust_to_weight']:.3f}), κ {s['flight']['r2_kappa']:.3f}, z_err_rel "
            f"{s['train_cmds']['z_err_rel']:.3f}, success {s['success_policy']:.3f}, RMSE ratio {s['rmse_ratio']}")
        dump()

    ok = [t for t in report["trials"] if args.any_best or keeps_control(t["summary"])]
    if ok:
        best = max(ok, key=lambda t: rank_key(t["summary"]))
        report["best"] = best["name"]
        log(f"best trial that keeps control: {best['name']}")
        for f in ("policy.npz", "train_log.jsonl"):
            shutil.copyfile(runs / best["name"] / f, args.out / f"best_{f}")
        if args.full_eval and time.time() - t0 + args.full_eval_s <= args.budget_s:
            log(f"full evaluation of {best['name']} on {args.full_eval_vehicles} vehicles")
            full = evaluate_policy(runs / best["name"] / "policy.npz", n=args.full_eval_vehicles, sim=sim, log=log)
            (args.out / "best_eval.json").write_text(json.dumps(full, indent=2, default=float) + "\n")
            report["best_full_eval_s"] = time.time() - t0
    dump()
    log("done")
    return 0


if __name__ == "__main__":
    sys.exit(main())
