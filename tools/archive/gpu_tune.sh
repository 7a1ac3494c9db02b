#!/usr/bin/env bash
# The tune-* runs of issue 26 on one GPU (the device machine: Python 3.12 + jax there, MuJoCo/MJX
# from .site, see README "GPU"). Each argument is NAME:SEED:VARIANT:METHODS:OUTDIR (VARIANT and
# METHODS may be empty: the defaults); every finished run is packed into $OUT/runs.tar.gz at once,
# so what finished comes back even if a later run is cut off.
#   bash tools/gpu_tune.sh tune-slow:0:::docs/runs/tuning/tune_slow tune-slow:7:::docs/runs/tuning/tune_slow_seed7
set -uo pipefail
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1 JAX_COMPILATION_CACHE_DIR=/tmp/jax_cache
OUT=${OUT:-/tmp/out}
mkdir -p "$OUT"
done_dirs=()
for spec in "$@"; do
  IFS=: read -r name seed variant methods dir <<<"$spec"
  args=(experiment "$name" --seed "$seed" --out "$dir" -q)
  [ -n "$variant" ] && args+=(--variant "$variant")
  [ -n "$methods" ] && args+=(--methods "$methods")
  t0=$(date +%s)
  python3 -m mjxsysid.cli "${args[@]}" 2>&1 | grep -v "warp" | tee -a "$OUT/log.txt"
  echo "[$(( $(date +%s) - t0 )) s] $spec" | tee -a "$OUT/log.txt"
  [ -d "$dir" ] && done_dirs+=("$dir")
  [ -d "$dir" ] || { echo "FAILED: $spec"; exit 1; }
  tar czf "$OUT/runs.tar.gz" "${done_dirs[@]}"
done
