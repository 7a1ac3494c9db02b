#!/usr/bin/env bash
# Side by side, one commit a GPU: 256 logs at × 1 in one batch, cold from an empty cache; GPU 0 the tree in
# .carry/old (the motor-map check reduces a map's variants, then fits them), GPU 1 this tree (the next map's
# variants reduced on the processes while the GPU fits the last).
set -uo pipefail
TOP=$PWD; OUT=${OUT:-/tmp/out}; mkdir -p $OUT
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1
run() {  # gpu tree tag
  (cd $2 && PYTHONPATH=$TOP/.site:$PWD MJXSYSID_JAX_CACHE=/tmp/jc_$3 CUDA_VISIBLE_DEVICES=$1 timeout ${B:-240} \
    python3 benchmarks/batched_posterior.py --vehicles 256 --batch 256 --levels x1 --sequential 0 --no-warm --workers 16 \
    --out $OUT/bp_$3.json > $OUT/log_$3.txt 2>&1; echo "rc $3 $?")
}
run 0 $TOP/.carry/old old & run 1 $TOP new & wait
python3 - <<'PY'
import json, os
for t in ("old", "new"):
    p = os.path.join(os.environ.get("OUT", "/tmp/out"), f"bp_{t}.json")
    if os.path.exists(p):
        d = json.load(open(p)); print(t, d.get("cold_s"), d.get("batched_phases_s"), d.get("nuts_calls_logs_s"))
PY
