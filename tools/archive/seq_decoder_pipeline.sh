#!/usr/bin/env bash
# Flight-level decoding (issue 11 §1) for any policy, in three CLI calls: collect 10 s latent
# trajectories (10 Hz, random lemniscates / min-snap / hover with force steps), train the
# sequence CFM p(θ | ẑ_1..ẑ_W), evaluate it (flight-level at 4 s vs single latent vs the prior).
# GPU recommended (collect + train + evaluate ≈ 2–3 min on one H100 at the defaults).
#
#   tools/seq_decoder_pipeline.sh OUT [POLICY_ARGS...]
#
# OUT: output folder (OUT/data/pairs.npz, OUT/dec/cfm_seq.npz, OUT/dec/decoder_eval.json).
# POLICY_ARGS: e.g. --policy xadap --weights DIR (default: the shipped mjxsysid policy).
# Sizes from the environment: TRAIN (20000), TEST (2000), FLIGHT_S (10), BATCH (5500),
# EPOCHS (100, of the sequence decoder), CASES (1000), SAMPLES (200), WIDTH (512), COORDS (the
# decoder's flow coordinates: CFMConfig's default identifiable, or theta),
# PAPER (1: also fly the paper vehicle on a 10 s lemniscate for its posterior; 0: skip).
# The single-latent CFM shipped for the policy (CFM_DIR, default mjxsysid/pretrained) is scored
# on the same latents for comparison. Ship with
#   python tools/ship_decoders.py OUT/dec --kinds cfm_seq --dest mjxsysid/pretrained --command ...
set -euo pipefail
OUT=${1:?usage: tools/seq_decoder_pipeline.sh OUT [POLICY_ARGS...]}
shift
M="python3 -m mjxsysid.cli"
mkdir -p "$OUT/dec"
t() { local s=$SECONDS; "$@"; echo "[$(( SECONDS - s )) s] $*" >&2; }
t $M collect --out "$OUT/data" --train "${TRAIN:-20000}" --test "${TEST:-2000}" --seconds "${FLIGHT_S:-10}" \
  --batch "${BATCH:-5500}" "$@"
t $M train-cfm --pairs "$OUT/data" --out "$OUT/dec" --kinds cfm_seq --seq-epochs "${EPOCHS:-100}" \
  --width "${WIDTH:-512}" ${COORDS:+--coords "$COORDS"} "$@"
if [[ -f "${CFM_DIR:-mjxsysid/pretrained}/cfm.npz" ]]; then
  cp "${CFM_DIR:-mjxsysid/pretrained}/cfm.npz" "$OUT/dec/cfm.npz"   # single-latent reference only
fi
t $M evaluate-decoder --decoders "$OUT/dec" --pairs "$OUT/data" --cases "${CASES:-1000}" \
  --samples "${SAMPLES:-200}" $([[ "${PAPER:-1}" == 0 ]] && echo --no-paper-flight) "$@"
