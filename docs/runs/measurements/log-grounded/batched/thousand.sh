#!/usr/bin/env bash
# 999 logs of 10 s at x1 with the defaults (batch from the device's memory), cold, one H200; GPU memory every 5 s.
set -uo pipefail
TOP=$PWD; OUT=${OUT:-/tmp/out}; mkdir -p $OUT
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 PYTHONPATH=$TOP/.site:$TOP
nvidia-smi -L; nproc; git -C $TOP log --oneline -1 2>/dev/null
( while true; do nvidia-smi --query-gpu=index,memory.used,utilization.gpu --format=csv,noheader >> $OUT/smi.csv; sleep 5; done ) &
SMI=$!
MJXSYSID_JAX_CACHE=/tmp/jc timeout 560 python3 benchmarks/batched_posterior.py --vehicles 999 --levels x1 --sequential 0 \
  --no-warm --workers 16 --out $OUT/bp_999.json > $OUT/log_999.txt 2>&1; echo "rc: $?"
kill $SMI
grep -v -i warp $OUT/log_999.txt | tr '\r' '\n' | grep -v 'it/s\]$\|log/s\]$' | tail -12
python3 -c "import json; d=json.load(open('$OUT/bp_999.json')); print(d.get('cold_s'), d.get('batched_phases_s'), d.get('nuts_calls_logs_s'))"
sort -t, -k2 -n -r $OUT/smi.csv | head -2
