#!/usr/bin/env bash
# ARGS.pkl (.carry/nuts_args.pkl, not committed): one captured log's run_chains arguments, pickled as (args, {"prior": ...}).
# NUTS at L logs under XLA's default flags and with while loops and conditionals in CUDA graphs (command buffers).
set -uo pipefail
TOP=$PWD; OUT=${OUT:-/tmp/out}; mkdir -p $OUT
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 PYTHONPATH=$TOP/.site:$TOP
nvidia-smi -L
L=${L:-512}
for v in default cmdbuf default2; do
  if [ $v = cmdbuf ]; then export XLA_FLAGS="--xla_gpu_enable_command_buffer=FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,WHILE,CONDITIONAL"; else unset XLA_FLAGS; fi
  MJXSYSID_JAX_CACHE=/tmp/jc_${v%2} timeout ${B:-270} python3 docs/runs/measurements/log-grounded/batched/nuts_cmdbuf.py $L 1 .carry/nuts_args.pkl > $OUT/$v.txt 2>&1; echo "rc $v: $?"
  grep -v -i warp $OUT/$v.txt | tail -4
done
