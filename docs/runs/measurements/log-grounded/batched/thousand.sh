#!/usr/bin/env bash
# 1,000 logs of 10 s at × 1 with the defaults a user gets (the batch from the device's memory), cold from an
# empty JAX cache, one GPU; the device's allocator limit and the default batch printed first.
set -uo pipefail
TOP=$PWD; OUT=${OUT:-/tmp/out}; mkdir -p $OUT
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 PYTHONPATH=$TOP/.site:$TOP
nvidia-smi -L; nproc
( while true; do nvidia-smi --query-gpu=index,memory.used,utilization.gpu --format=csv,noheader >> $OUT/smi.csv; sleep 5; done ) &
SMI=$!
python3 -c "
import jax; from mjxsysid.runtime import startup
print('bytes_limit', jax.devices()[0].memory_stats().get('bytes_limit'))
from mjxsysid.identify.inference import batch_for; print('default batch of a 10 s log', batch_for(172308, jax.devices()[0].memory_stats().get('bytes_limit')))
" 2>&1 | grep -v -i warp
MJXSYSID_JAX_CACHE=/tmp/jc timeout ${B:-560} python3 benchmarks/batched_posterior.py --vehicles 1000 --levels x1 \
  --sequential 0 --no-warm --workers 16 --out $OUT/bp_1000.json > $OUT/log_1000.txt 2>&1; echo "rc $?"
kill $SMI
grep -v -i warp $OUT/log_1000.txt | tr '\r' '\n' | grep -v 'it/s\]$\|log/s\]$' | tail -10
python3 -c "
import json; d = json.load(open('$OUT/bp_1000.json')); print(d['logs'], d['fly_s'], d['cold_s'], d['batched_phases_s'], d['nuts_calls_logs_s'])"
sort -t, -k2 -n -r $OUT/smi.csv | head -2
