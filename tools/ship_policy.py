"""Ship trained policy weights into mjxsysid/pretrained/ with their provenance.

    python tools/ship_policy.py RUN/policy.npz EVAL/eval.json --train-log RUN/train_log.jsonl

Copies the weights to mjxsysid/pretrained/policy.npz and writes policy.json beside them:
config, seed, commit, device, wall time, env steps, the command that reproduces them, and the
evaluation figures (from `mjxsysid evaluate-policy`), all read from the files given
(:func:`mjxsysid.release.provenance.policy_provenance`; `mjxsysid release` ships the same way, with a
``release`` section added).
"""
import argparse
import json
import shutil
from pathlib import Path

from mjxsysid.release.provenance import policy_provenance

ROOT = Path(__file__).resolve().parents[1]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("weights", type=Path)
    ap.add_argument("eval", type=Path)
    ap.add_argument("--train-log", type=Path, default=None)
    ap.add_argument("--dest", type=Path, default=ROOT / "mjxsysid" / "pretrained")
    args = ap.parse_args()
    prov = policy_provenance(args.weights, json.loads(args.eval.read_text()), train_log=args.train_log,
                             command="mjxsysid train-policy --out runs/policy  (default TrainConfig)")
    args.dest.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(args.weights, args.dest / "policy.npz")
    (args.dest / "policy.json").write_text(json.dumps(prov, indent=2) + "\n")
    print(f"shipped {args.dest / 'policy.npz'} ({(args.dest / 'policy.npz').stat().st_size / 1e3:.0f} kB) + policy.json")


if __name__ == "__main__":
    main()
