#!/usr/bin/env bash
# Batch size: GPU 0 runs N0 (256) logs in one batch, GPU 1 N1 (512) (× 1, 10 s lemniscate),
# each cold from an empty JAX cache, side by side; GPU memory sampled every 5 s.
set -uo pipefail
TOP=$PWD; OUT=${OUT:-/tmp/out}; mkdir -p $OUT
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 PYTHONPATH=$TOP/.site:$TOP
nvidia-smi -L; nproc
( while true; do nvidia-smi --query-gpu=index,memory.used,utilization.gpu --format=csv,noheader >> $OUT/smi.csv; sleep 5; done ) &
SMI=$!
run() {  # gpu n
  MJXSYSID_JAX_CACHE=/tmp/jc_$2 CUDA_VISIBLE_DEVICES=$1 timeout ${B:-570} \
    python3 benchmarks/batched_posterior.py --vehicles $2 --batch $2 --levels x1 --sequential 0 --no-warm --workers 16 \
    --out $OUT/bp_$2.json > $OUT/log_$2.txt 2>&1; echo "rc $2: $?"
}
run 0 ${N0:-256} & run 1 ${N1:-512} & wait %2 %3
kill $SMI
for t in ${N0:-256} ${N1:-512}; do echo "== $t"; grep -v -i warp $OUT/log_$t.txt | tr '\r' '\n' | grep -v 'it/s\]$\|log/s\]$' | tail -8; done
python3 - <<'PY'
import json, os
for t in (os.environ.get("N0", "256"), os.environ.get("N1", "512")):
    p = os.path.join(os.environ.get("OUT", "/tmp/out"), f"bp_{t}.json")
    if os.path.exists(p):
        d = json.load(open(p)); print(t, d.get("cold_s"), d.get("batched_phases_s"), d.get("nuts_calls_logs_s"))
PY
sort -t, -k2 -n -r $OUT/smi.csv | head -3
