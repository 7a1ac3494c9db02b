#!/usr/bin/env bash
# 256 logs of 10 s at x1 with the defaults, cold, one H200: MJXSYSID_COMPILE_AHEAD 0 then 1 (each its own empty cache).
set -uo pipefail
TOP=$PWD; OUT=${OUT:-/tmp/out}; mkdir -p $OUT
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 PYTHONPATH=$TOP/.site:$TOP
nvidia-smi -L; nproc; python3 -c "import jax, mujoco, blackjax; print(jax.__version__, jax.devices())"
N=${N:-256}
for A in ${ORDER:-0 1}; do
  MJXSYSID_COMPILE_AHEAD=$A MJXSYSID_JAX_CACHE=/tmp/jc$A timeout ${T:-280} python3 benchmarks/batched_posterior.py --vehicles $N \
    --batch $N --levels x1 --sequential 0 --no-warm --workers 16 --out $OUT/bp_${N}_ahead$A.json > $OUT/log_${N}_ahead$A.txt 2>&1
  echo "ahead=$A rc: $?"
  grep -v -i warp $OUT/log_${N}_ahead$A.txt | tr '\r' '\n' | grep -v 'it/s\]$\|log/s\]$' | tail -6
  python3 -c "import json; d=json.load(open('$OUT/bp_${N}_ahead$A.json')); print('ahead=$A', d.get('cold_s'), d.get('batched_phases_s'), d.get('nuts_calls_logs_s'))"
done
