#!/usr/bin/env bash
# Issue 22 (fair comparisons): re-run at full size what the fixes change, on one GPU.
#
#   tools/fair_baselines.sh OUT STAGE...      (stages run in the order given)
#
#   regression  collect the shipped decoders' single-latent pairs again (checked against the
#               pairs sha256 in mjxsysid/pretrained/cfm.json), retrain the Regression baseline
#               with early stopping, evaluate it beside the shipped CFM  -> OUT/regression/dec
#               (ship: python tools/ship_decoders.py OUT/regression/dec --kinds regression ...)
#   tune        tune-nominal and tune-slow (Nominal+CEM on each vehicle's own nominal θ; the
#               paper's cost)                                               -> OUT/tune_*
#   heading     tune-slow --variant heading_cost (the cost with a heading term) -> OUT/tune_slow_heading_cost
#   lemniscate  tune-lemniscate with the hover lead-in and --variant no_lead_in -> OUT/tune_lemniscate*
#   robustness  robustness (flight-level decoder) and --variant single_latent -> OUT/robustness*
#   replay      the replay experiment (action replay with the early-stopped Regression)
#   fidelity    closed-loop fidelity on a held-out identification flight, and on the test flight
#   xadap       the released XAdap policy's Regression again, with early stopping (its pairs
#               collected again, checked against the shipped decoders' sha256; the flow coordinates
#               of the shipped XAdap decoders, theta), evaluated beside its shipped CFM, and its
#               action replay. XADAP_WEIGHTS: the released folder or a converted .npz -> OUT/xadap
#               (ship: cp OUT/xadap/dec/regression.* mjxsysid/pretrained/xadap/)
#   nobc        a policy trained without imitation at the end (tools/configs/policy_no_bc.json),
#               evaluated like the shipped one, its decoders, and action replay with them
#
# Each stage takes 1-5 min on one H100. Environment: M (the CLI, default `python3 -m mjxsysid.cli`).
set -euo pipefail
OUT=${1:?usage: tools/fair_baselines.sh OUT STAGE...}
shift
M=${M:-python3 -m mjxsysid.cli}
mkdir -p "$OUT"
t() { local s=$SECONDS; "$@"; echo "[$(( SECONDS - s )) s] $*" >&2; }
same_pairs() {  # PAIRS PROVENANCE_JSON: are the re-collected pairs bitwise the shipped decoders'?
  python3 - "$1" "$2" <<'PY'
import hashlib, json, sys
got = hashlib.sha256(open(sys.argv[1], "rb").read()).hexdigest()
want = json.load(open(sys.argv[2]))["data"]["pairs_sha256"]
print(f"pairs sha256 {got[:16]}… {'==' if got == want else '!='} the shipped CFM's {want[:16]}…", file=sys.stderr)
PY
}
for stage in "$@"; do
  case $stage in
    regression)
      t $M collect --single-latent --out "$OUT/regression/data" -q
      same_pairs "$OUT/regression/data/pairs.npz" mjxsysid/pretrained/cfm.json
      t $M train-cfm --pairs "$OUT/regression/data" --out "$OUT/regression/dec" --kinds regression -q
      cp mjxsysid/pretrained/cfm.npz "$OUT/regression/dec/cfm.npz"
      t $M evaluate-decoder --decoders "$OUT/regression/dec" --pairs "$OUT/regression/data" --cases 1000 --samples 200 -q ;;
    tune)
      t $M experiment tune-nominal --out "$OUT/tune_nominal" -q
      t $M experiment tune-slow --out "$OUT/tune_slow" -q ;;
    heading)
      t $M experiment tune-slow --variant heading_cost --out "$OUT/tune_slow_heading_cost" -q ;;
    lemniscate)
      t $M experiment tune-lemniscate --out "$OUT/tune_lemniscate" -q
      t $M experiment tune-lemniscate --variant no_lead_in --out "$OUT/tune_lemniscate_no_lead_in" -q ;;
    robustness)
      t $M experiment robustness --out "$OUT/robustness" -q
      t $M experiment robustness --variant single_latent --out "$OUT/robustness_single_latent" -q ;;
    replay)
      t $M experiment replay --out "$OUT/replay" -q ;;
    fidelity)
      t python3 benchmarks/closed_loop_fidelity.py --out "$OUT/closed_loop_fidelity.json"
      t python3 benchmarks/closed_loop_fidelity.py --identification same --out "$OUT/closed_loop_fidelity_same_flight.json" ;;
    nobc)
      t $M train-policy --config tools/configs/policy_no_bc.json --out "$OUT/nobc/run" -q
      t $M evaluate-policy --weights "$OUT/nobc/run/policy.npz" --vehicles 1000 --out "$OUT/nobc/eval" -q
      t $M collect --single-latent --policy "$OUT/nobc/run/policy.npz" --out "$OUT/nobc/data" -q
      t $M train-cfm --pairs "$OUT/nobc/data" --out "$OUT/nobc/dec" --policy "$OUT/nobc/run/policy.npz" -q
      t $M evaluate-decoder --decoders "$OUT/nobc/dec" --pairs "$OUT/nobc/data" --cases 1000 --samples 200 \
        --policy "$OUT/nobc/run/policy.npz" -q
      t $M experiment replay --policy "$OUT/nobc/run/policy.npz" --decoders "$OUT/nobc/dec" --out "$OUT/nobc/replay" -q ;;
    xadap)
      W=${XADAP_WEIGHTS:?set XADAP_WEIGHTS to the released folder or a converted .npz}
      t $M collect --single-latent --policy xadap --weights "$W" --out "$OUT/xadap/data" -q
      same_pairs "$OUT/xadap/data/pairs.npz" mjxsysid/pretrained/xadap/cfm.json
      t $M train-cfm --pairs "$OUT/xadap/data" --policy xadap --weights "$W" --out "$OUT/xadap/dec" \
        --kinds regression --coords theta -q
      cp mjxsysid/pretrained/xadap/cfm.npz "$OUT/xadap/dec/cfm.npz"
      t $M evaluate-decoder --decoders "$OUT/xadap/dec" --pairs "$OUT/xadap/data" --policy xadap --weights "$W" -q
      t $M replay --policy xadap --weights "$W" --decoders "$OUT/xadap/dec" --vehicles 32 --out "$OUT/xadap/replay" -q ;;
    *) echo "unknown stage $stage" >&2; exit 2 ;;
  esac
done
