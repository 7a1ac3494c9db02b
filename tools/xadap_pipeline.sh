#!/usr/bin/env bash
# The released Xadap policy end to end (issue 6): fly 1,000 in-distribution vehicles beside the
# oracle, collect (θ, ẑ) pairs from its adaptation module, train and calibrate its decoders, and
# run the action replay. GPU recommended (about 7.5 min on one H100); every stage is a plain CLI call.
#
#   tools/xadap_pipeline.sh WEIGHTS OUT [STAGES]
#
# WEIGHTS: the folder of the released files (encoder.onnx, mlp.onnx, mean.csv, var.csv) or a
# converted .npz (mjxsysid.policy.xadap.network.save_npz; no onnx needed then). OUT: output folder.
# STAGES: any of "fly collect train evaluate replay" (default: all). Ship the decoders with
#   cp OUT/dec/{cfm,regression}.{npz,json} mjxsysid/pretrained/xadap/
set -euo pipefail
W=${1:?usage: tools/xadap_pipeline.sh WEIGHTS OUT [STAGES]}
OUT=${2:?usage: tools/xadap_pipeline.sh WEIGHTS OUT [STAGES]}
STAGES=${3:-"fly collect train evaluate replay"}
M="python3 -m mjxsysid.cli"
mkdir -p "$OUT"
has() { [[ " $STAGES " == *" $1 "* ]]; }
t() { local s=$SECONDS; "$@"; echo "[$(( SECONDS - s )) s] $*" >&2; }

if has fly; then
  t $M fly --prior xadap --vehicles 1000 --policy xadap --weights "$W" --out "$OUT/fly_xadap"
  t $M fly --prior xadap --vehicles 1000 --controller oracle --out "$OUT/fly_oracle"
  t $M fly --prior xadap --vehicles 1000 --controller nominal --out "$OUT/fly_nominal"
  t $M fly --policy xadap --weights "$W" --out "$OUT/fly_paper_xadap"
  t $M fly --prior xadap --vehicles 1000 --policy xadap --weights "$W" --reference hover --out "$OUT/hover_xadap"
  t $M fly --prior xadap --vehicles 1000 --controller oracle --reference hover --out "$OUT/hover_oracle"
fi
if has collect; then
  t $M collect --single-latent --policy xadap --weights "$W" --out "$OUT/data"  # the shipped decoders: 1.5 s pairs
fi
if has train; then
  t $M train-cfm --pairs "$OUT/data" --policy xadap --weights "$W" --out "$OUT/dec"
fi
if has evaluate; then
  t $M evaluate-decoder --decoders "$OUT/dec" --pairs "$OUT/data" --policy xadap --weights "$W"
fi
if has replay; then
  t $M replay --policy xadap --weights "$W" --decoders "$OUT/dec" --vehicles 32 --out "$OUT/replay"
fi
