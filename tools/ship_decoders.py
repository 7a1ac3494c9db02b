"""Ship trained decoders (cfm.npz, regression.npz) with their provenance.

    python tools/ship_decoders.py DEC_DIR --dest mjxsysid/pretrained/xadap \
        --what "of the released Xadap policy's latent" --command "tools/xadap_pipeline.sh W OUT"

DEC_DIR holds the output of `mjxsysid train-cfm` and `mjxsysid evaluate-decoder` (cfm.npz,
regression.npz, decoder_eval.json; with ``--kinds cfm_seq`` the sequence decoder cfm_seq.npz,
whose cfm_seq.json carries the ``sequence`` part of the evaluation). Copies the weights to --dest and writes cfm.json and
regression.json beside them: config, seed, commit, device, wall time, training losses, the data
they were trained on (pairs hash, policy hash, prior, seed) and the evaluation figures, all read
from the files given
(:func:`mjxsysid.release.provenance.decoder_provenance`; `mjxsysid release` ships the same way).
"""
import argparse
import json
import shutil
from pathlib import Path

from mjxsysid.release.provenance import decoder_provenance


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
    args.dest.mkdir(parents=True, exist_ok=True)
    for kind in [k.strip() for k in args.kinds.split(",") if k.strip()]:
        src = args.dec / f"{kind}.npz"
        prov = decoder_provenance(src, kind, ev, what=args.what, command=args.command, note=args.note,
                                  evaluation_command=f"mjxsysid evaluate-decoder --decoders {args.dec} --pairs DATA",
                                  commit=args.commit)
        if src.resolve() != (args.dest / src.name).resolve():
            shutil.copy(src, args.dest / src.name)
        (args.dest / f"{kind}.json").write_text(json.dumps(prov, indent=2, ensure_ascii=False) + "\n")
        print(f"wrote {args.dest / src.name} and {kind}.json")


if __name__ == "__main__":
    main()
