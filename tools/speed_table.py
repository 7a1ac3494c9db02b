"""Wall time against quality of policy-training configurations (issue 30): a table and a figure.

    python tools/speed_table.py RUNS_DIR [RUNS_DIR ...] --reference shipped=EVAL.json --out docs/runs/benchmarks/speed

Each run folder (as `tools/gpu_speed.sh` leaves them) holds ``policy.npz`` (or its metadata alone as
``policy_meta.json``, as kept in docs/runs) (its metadata: the
config, wall time and, since issue 30, the phase timings), ``train.txt`` (the command's wall time,
``command_wall_s``) and ``eval_fast/eval.json`` (``mjxsysid evaluate-policy --fast``). The
``--reference`` evaluations (e.g. the shipped policy's, same command) are rows without a training.
Runs whose names differ only in ``_seedN`` are seeds of one configuration: the summary table and
the figure give each configuration's mean and range. Writes OUT/speed.json, OUT/speed.md (the
summary, then every run) and OUT/speed.png (success and RMSE ratio against wall time).
"""
from __future__ import annotations

import argparse
import json
import re
from pathlib import Path


def run_row(d: Path) -> dict:
    if (d / "policy.npz").is_file():
        from mjxsysid.checkpoint import load_meta
        meta = load_meta(d / "policy.npz")
    else:   # runs kept in docs/runs without their weights: the metadata alone
        meta = json.loads((d / "policy_meta.json").read_text())
    cfg = meta["config"]
    ev = json.loads((d / "eval_fast" / "eval.json").read_text())
    m = re.search(r"command_wall_s (\d+) ms", (d / "train.txt").read_text()) if (d / "train.txt").exists() else None
    sm = ev["summary"]
    return {"name": d.name, "num_envs": cfg["num_envs"], "unroll": cfg["unroll"], "iterations": cfg["iterations"],
            "epochs": cfg["epochs"], "minibatches": cfg["minibatches"], "seed": cfg["seed"],
            "reset_per_unroll": cfg.get("reset_per_unroll", False), "lr_decay": cfg.get("lr_decay", False),
            "sensor_randomized": bool(cfg["env"].get("randomize_imu", False)),
            "env_steps": meta.get("env_steps"), "updates": cfg["iterations"] * cfg["epochs"] * cfg["minibatches"],
            "train_wall_s": meta.get("wall_s"), "command_wall_s": int(m.group(1)) / 1e3 if m else None,
            "timing": meta.get("timing"), "device": meta.get("device"),
            # the card: recorded by train-policy since 2026-11-26, or in device.txt beside older runs
            "device_kind": meta.get("device_kind") or ((d / "device.txt").read_text().strip()
                                                        if (d / "device.txt").is_file() else None),
            "success": sm["success_policy"], "rmse_ratio": sm["rmse_ratio"],
            "r2_tw_cmds": sm["train_cmds"]["r2_thrust_to_weight"], "r2_tw_flight": sm["flight"]["r2_thrust_to_weight"]}


def reference_row(name: str, path: Path) -> dict:
    sm = json.loads(path.read_text())["summary"]
    return {"name": name, "success": sm["success_policy"], "rmse_ratio": sm["rmse_ratio"],
            "r2_tw_cmds": sm["train_cmds"]["r2_thrust_to_weight"], "r2_tw_flight": sm["flight"]["r2_thrust_to_weight"]}


def fmt(x, spec):
    return "—" if x is None else format(x, spec)


def table(rows: list[dict]) -> str:
    head = ("| run | envs × unroll × iterations | epochs × minibatches (updates) | episode starts | env steps | "
            "learning rate | device | training loop | command (compile, start-up incl.) | success | RMSE / oracle | "
            "R² T/W (cmds / flight) |\n|---|---|---|---|---|---|---|---|---|---|---|---|\n")
    out = []
    for r in rows:
        if "num_envs" not in r:
            out.append(f"| {r['name']} | | | | | | | | | {r['success']:.1%} | {r['rmse_ratio']:.3f} | "
                       f"{r['r2_tw_cmds']:.3f} / {r['r2_tw_flight']:.3f} |")
            continue
        out.append(f"| {r['name']} | {r['num_envs']} × {r['unroll']} × {r['iterations']} | {r['epochs']} × "
                   f"{r['minibatches']} ({r['updates'] / 1e3:.0f} k) | "
                   f"{'once per unroll' if r['reset_per_unroll'] else 'every step'} | {r['env_steps'] / 1e6:.0f} M | "
                   f"{'linear decay' if r['lr_decay'] else 'constant'} | {r.get('device_kind') or '—'} | "
                   f"{fmt(r['train_wall_s'], '.0f')} s | {fmt(r['command_wall_s'], '.0f')} s | {r['success']:.1%} | "
                   f"{r['rmse_ratio']:.3f} | {r['r2_tw_cmds']:.3f} / {r['r2_tw_flight']:.3f} |")
    return head + "\n".join(out) + "\n"


def family(name: str) -> str:
    """A run's configuration: its name without ``_seedN`` (seeds of one config share a family)."""
    return re.sub(r"_seed\d+$", "", name)


def families(rows: list[dict]) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for r in rows:
        out.setdefault(family(r["name"]), []).append(r)
    return out


def summary(rows: list[dict]) -> str:
    """One line per configuration: its seeds' spread of wall time and quality."""
    head = ("| configuration | runs | command wall (mean, range) | training loop (mean) | RMSE / oracle: mean (range) | "
            "runs ≤ 1.05 | success (lowest) | R² T/W cmds (lowest) |\n|---|---|---|---|---|---|---|---|\n")
    out = []
    for fam, rs in families(rows).items():
        cmd = [r["command_wall_s"] for r in rs if r.get("command_wall_s") is not None]
        loop = [r["train_wall_s"] for r in rs if r.get("train_wall_s") is not None]
        q = [r["rmse_ratio"] for r in rs]
        out.append(f"| {fam} | {len(rs)} | " + (f"{sum(cmd) / len(cmd):.0f} s ({min(cmd):.0f}–{max(cmd):.0f})" if cmd else "—")
                   + f" | {(f'{sum(loop) / len(loop):.0f} s' if loop else '—')} | {sum(q) / len(q):.3f} ({min(q):.3f}–{max(q):.3f}) | "
                   f"{sum(x <= 1.05 for x in q)}/{len(q)} | {min(r['success'] for r in rs):.1%} | "
                   f"{min(r['r2_tw_cmds'] for r in rs):.3f} |")
    return head + "\n".join(out) + "\n"


def figure(rows: list[dict], path: Path) -> None:
    """Per configuration: its runs (small dots, at their command time or, without one, at the
    configuration's mean) and the mean with the seeds' range as bars."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, (fam, rs) in enumerate(families(rows).items()):
        cmd = [r["command_wall_s"] for r in rs if r.get("command_wall_s") is not None]
        if not cmd:
            continue
        c = f"C{i % 10}"
        xm = sum(cmd) / len(cmd)
        for a, k in zip(ax, ("rmse_ratio", "success")):
            v = [r[k] for r in rs]
            xs = [r["command_wall_s"] if r.get("command_wall_s") is not None else xm for r in rs]
            a.plot(xs, v, ".", c=c, alpha=0.5)
            ym = sum(v) / len(v)
            a.errorbar([xm], [ym], yerr=[[ym - min(v)], [max(v) - ym]], xerr=[[xm - min(cmd)], [max(cmd) - xm]],
                       fmt="o", c=c, capsize=3, label=f"{fam} ({len(rs)} run{'s' if len(rs) > 1 else ''})")
    ax[0].axhline(1.05, c="r", lw=1)
    ax[0].set(xlabel="training command wall time (s, compile and start-up included)", ylabel="RMSE / oracle (lemniscate)",
              title="tracking on the default prior (target ≤ 1.05)")
    ax[1].axhline(0.99, c="r", lw=1)
    ax[1].set(xlabel="training command wall time (s)", ylabel="success", title="success (target ≥ 99 %)")
    for a in ax:
        a.axvline(60, c="r", lw=1, ls=":")
    ax[0].legend(fontsize=7, loc="upper right")
    fig.suptitle("mean and range over seeds (bars), each run a dot; runs without a command time drawn at their "
                 "configuration's mean time", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", type=Path, nargs="+")
    ap.add_argument("--reference", action="append", default=[], metavar="NAME=EVAL.json")
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    rows = []
    for spec in args.reference:
        name, _, path = spec.partition("=")
        rows.append(reference_row(name, Path(path)))
    for d in args.runs:
        if not any((d / f).is_file() for f in ("policy.npz", "policy_meta.json")) or \
                not (d / "eval_fast" / "eval.json").is_file():
            raise SystemExit(f"{d}: expected policy.npz (or policy_meta.json) and eval_fast/eval.json "
                             "(a tools/gpu_speed.sh run)")
        rows.append(run_row(d))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "speed.json").write_text(json.dumps(rows, indent=2) + "\n")
    (args.out / "speed.md").write_text(summary(rows) + "\n" + table(rows))
    figure(rows, args.out / "speed.png")
    print(summary(rows) + "\n" + table(rows))


if __name__ == "__main__":
    main()
