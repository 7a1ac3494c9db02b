#!/usr/bin/env bash
# `mjxsysid release` in pieces on the device machine (Python 3.12 + jax there, MuJoCo/MJX from
# .site, see README "GPU"): each argument is a group of stages (`--stages` syntax) run in its own
# process; after each group the record and the small outputs are packed into
# $OUT/release_small.tar.gz and each decoder/policy weight file is copied to $OUT on its own (the
# device tool returns at most 8 files of 16 MiB), so what finished comes back even if a later group
# is cut off at the call's time limit (BUDGET_S, default 585 s, shared by the groups).
#   bash tools/gpu_release.sh runs/release policy pairs,decoders seq_pairs,seq_decoder decoder_eval
# The device's checkout sits on the session's base commit: give the code's commit on the command
# line (MJXSYSID_COMMIT=$(git rev-parse HEAD) evaluated here, before the call) for the record.
set -uo pipefail
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1
[ -n "${MJXSYSID_COMMIT:-}" ] || echo "note: MJXSYSID_COMMIT not set: the record's commit will be the device checkout's base (+dirty)"
OUT=${OUT:-/tmp/out}; R=${1:?usage: gpu_release.sh RELEASE_DIR GROUP...}; shift
mkdir -p "$OUT" "$R"
pack() {
  tar czf "$OUT/release_small.tar.gz" --exclude='pairs.npz' --exclude='*.ckpt.npz' --exclude='checkpoint.npz' \
    --exclude='cfm.npz' --exclude='regression.npz' --exclude='cfm_seq.npz' "$R"
  for f in decoders/cfm.npz decoders/regression.npz seq_decoder/cfm_seq.npz; do
    [ -f "$R/$f" ] && cp "$R/$f" "$OUT/$(echo "$f" | tr / _)"
  done
}
for group in "$@"; do
  left=$(( ${BUDGET_S:-585} - SECONDS ))
  [ "$left" -lt 30 ] && { echo "no time left for $group"; break; }
  echo "== [$SECONDS s] release --stages $group (limit $left s)"
  timeout "$left" python3 -m mjxsysid.cli release --out "$R" --stages "$group" -q 2>&1 | grep -v -i "warp" | tail -25
  pack
done
python3 -m mjxsysid.cli release --out "$R" --list 2>&1 | grep -v -i warp
pack
