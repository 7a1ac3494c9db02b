#!/usr/bin/env bash
# Issue 30 on a 2-GPU device machine (Python 3.12 + jax there, MuJoCo/MJX from .site): the
# training profile (GPU 0), candidate fast-training configs trained and evaluated (--fast) two at a
# time (one per GPU), then the 1-vs-2-GPU scaling run. Everything finished is packed into
# $OUT/speed.tar.gz as it finishes.
#   bash tools/gpu_speed.sh RUNS_DIR CONFIG_GPU0[,CONFIG_GPU0b] CONFIG_GPU1[,...]
# PROFILE="4096x32x4x8 ..." the profiled configs (default two; "none" skips the profile), SCALING=0 skips
# the scaling run, EVAL_VEHICLES (1000) the fast evaluation's vehicles.
set -uo pipefail
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1
OUT=${OUT:-/tmp/out}; RUNS=${1:?runs dir}; mkdir -p "$OUT" "$RUNS"
pack() { tar czf "$OUT/speed.tar.gz" --exclude=checkpoint.npz "$RUNS" 2>/dev/null; }
train_eval() {   # GPU CONFIG...: tools/speed_job.sh for each config on that GPU
  local gpu=$1; shift
  for c in "$@"; do
    local name; name=$(basename "$c" .json)
    CUDA_VISIBLE_DEVICES=$gpu bash tools/speed_job.sh "$RUNS/$name" "$c" "${EVAL_VEHICLES:-1000}" > "$RUNS/$name.log" 2>&1
    echo "[gpu $gpu] $name done: $(grep command_wall "$RUNS/$name/train.txt")"; pack
  done
}
bg=
IFS=, read -ra C1 <<<"${3:-}"
if [ ${#C1[@]} -gt 0 ]; then train_eval 1 "${C1[@]}" & bg=$!; fi
if [ "${PROFILE:-}" != none ]; then
  CUDA_VISIBLE_DEVICES=0 python3 benchmarks/train_profile.py --configs ${PROFILE:-4096x32x4x8 16384x32x4x16} \
    --out "$RUNS/train_profile.json" 2>&1 | grep -v warp | tee "$RUNS/train_profile.txt"; pack
fi
IFS=, read -ra C0 <<<"${2:-}"
if [ ${#C0[@]} -gt 0 ]; then train_eval 0 "${C0[@]}"; fi
[ -n "$bg" ] && wait "$bg"
if [ "${SCALING:-1}" = 1 ]; then
  python3 benchmarks/scaling.py --vehicles 16384 --envs 4096 --reset-per-unroll --out "$RUNS/scaling.json" 2>&1 \
    | grep -v warp | tee "$RUNS/scaling.txt"; pack
fi
ls -R "$RUNS" | head -50
