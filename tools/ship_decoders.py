"""Ship trained decoders (cfm.npz, regression.npz) with their provenance.

    python tools/ship_decoders.py DEC_DIR --dest mjxsysid/pretrained/xadap \
        --what "of the released Xadap policy's latent" --command "tools/xadap_pipeline.sh W OUT"

DEC_DIR holds the output of `mjxsysid train-cfm` and `mjxsysid evaluate-decoder` (cfm.npz,
regression.npz, decoder_eval.json; with ``--kinds cfm_seq`` the sequence decoder cfm_seq.npz,
whose cfm_seq.json carries the ``sequence`` part of the evaluation). Copies the weights to --dest and writes cfm.json and
regression.json beside them: config, seed, commit, device, wall time, training losses, the data
they were trained on (pairs hash, policy hash, prior, seed) and the evaluation figures, all read
from the files given.
"""
import argparse
import json
import shutil
import subprocess
from pathlib import Path

from mjxsysid.cfm.sample import Decoder
from mjxsysid.cfm.sequence import SequenceDecoder

ROOT = Path(__file__).resolve().parent.parent


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dec", type=Path)
    ap.add_argument("--dest", type=Path, required=True)
    ap.add_argument("--what", default="of the shipped policy's latent")
    ap.add_argument("--command", required=True, help="the command that reproduces them")
    ap.add_argument("--commit", default=None, help="default: git HEAD")
    ap.add_argument("--kinds", default="cfm,regression", help="comma-separated: cfm, regression, cfm_seq")
    ap.add_argument("--note", default=None, help="free text added to the provenance (e.g. where extra figures come from)")
    args = ap.parse_args()
    ev_path = args.dec / "decoder_eval.json"
    if not ev_path.is_file():
        raise SystemExit(f"{ev_path} not found: run `mjxsysid evaluate-decoder --decoders {args.dec}` first")
    ev = json.loads(ev_path.read_text())
    commit = args.commit or subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                                           text=True).stdout.strip()
    args.dest.mkdir(parents=True, exist_ok=True)
    for kind in [k.strip() for k in args.kinds.split(",") if k.strip()]:
        src = args.dec / f"{kind}.npz"
        dec = SequenceDecoder.load(src) if kind == "cfm_seq" else Decoder.load(src)
        m = dec.meta
        what = "p(θ | ẑ_1..ẑ_W) (flight-level, W = 1 latent up to a whole flight)" if kind == "cfm_seq" else "p(θ | ẑ)"
        prov = {"what": f"{kind} decoder {what} {args.what}", "command": args.command,
                "config": {k: getattr(dec.cfg, k) for k in dec.cfg.__dataclass_fields__},
                "seed": dec.cfg.seed, "commit": commit, "device": f"{m.get('device')}, jax {m.get('jax')}",
                "wall_s": m.get("wall_s"), "steps_per_s": m.get("steps_per_s"),
                "final_train_loss": m.get("final_train_loss"), "final_val_loss": m.get("final_val_loss"),
                "data": m.get("data"), **({"early_stopping": m["early_stopping"]} if "early_stopping" in m else {}), "stored_dtype": "float16 (evaluated after rounding)",
                "evaluation": ev.get("sequence") if kind == "cfm_seq" else ev if kind == "cfm" else {
                    "energy_score": ev.get("energy_score"), "rmse_norm": ev.get("rmse_norm")},
                "evaluation_command": f"mjxsysid evaluate-decoder --decoders {args.dec} --pairs DATA"}
        if kind == "cfm_seq":
            prov.update(n_params=m.get("n_params"), val_loss_min=m.get("val_loss_min"),
                        val_loss_argmin_epoch=m.get("val_loss_argmin_epoch"))
        if args.note:
            prov["note"] = args.note
        if src.resolve() != (args.dest / src.name).resolve():
            shutil.copy(src, args.dest / src.name)
        (args.dest / f"{kind}.json").write_text(json.dumps(prov, indent=2, ensure_ascii=False) + "\n")
        print(f"wrote {args.dest / src.name} and {kind}.json")


if __name__ == "__main__":
    main()
