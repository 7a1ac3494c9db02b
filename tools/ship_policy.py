"""Ship trained policy weights into mjxsysid/pretrained/ with their provenance.

    python tools/ship_policy.py RUN/policy.npz EVAL/eval.json --train-log RUN/train_log.jsonl

Copies the weights to mjxsysid/pretrained/policy.npz and writes policy.json beside them:
config, seed, commit, device, wall time, env steps, the command that reproduces them, and the
evaluation figures (from `mjxsysid evaluate-policy`), all read from the files given.
"""
import argparse
import json
import shutil
import subprocess
from pathlib import Path

from mjxsysid.checkpoint import load_meta

ROOT = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("weights", type=Path)
    ap.add_argument("eval", type=Path)
    ap.add_argument("--train-log", type=Path, default=None)
    ap.add_argument("--dest", type=Path, default=ROOT / "mjxsysid" / "pretrained")
    args = ap.parse_args()
    meta = load_meta(args.weights)
    ev = json.loads(args.eval.read_text())
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    sps = None
    if args.train_log and args.train_log.exists():
        rows = [json.loads(x) for x in args.train_log.read_text().splitlines()]
        sps = sum(r["steps_per_s"] for r in rows[1:]) / max(len(rows) - 1, 1)
    prov = {
        "what": "unified latent-conditioned adaptive policy (μ, φ, π, aux decoder)",
        "command": "mjxsysid train-policy --out runs/policy  (default TrainConfig)",
        "config": meta["config"], "seed": meta["config"]["seed"], "commit": commit,
        "device": meta.get("device"), "jax": meta.get("jax"), "wall_s": meta.get("wall_s"),
        "env_steps": meta.get("env_steps"), "mean_train_steps_per_s": sps,
        "normalizer": meta.get("normalizer"), "final_train_stats": meta.get("final_stats"),
        "evaluation": ev, "evaluation_command": "mjxsysid evaluate-policy --vehicles 1000 --out OUT",
    }
    args.dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(args.weights, args.dest / "policy.npz")
    (args.dest / "policy.json").write_text(json.dumps(prov, indent=2) + "\n")
    print(f"shipped {args.dest / 'policy.npz'} ({(args.dest / 'policy.npz').stat().st_size / 1e3:.0f} kB) + policy.json")


if __name__ == "__main__":
    main()
