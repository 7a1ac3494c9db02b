#!/usr/bin/env bash
# NUTS micro (512 logs) under GPU_LOOP_GRAPHS and two additions to it.
set -uo pipefail
TOP=$PWD; OUT=${OUT:-/tmp/out}; mkdir -p $OUT
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 PYTHONPATH=$TOP/.site:$TOP
G="--xla_gpu_enable_command_buffer=FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,WHILE,CONDITIONAL"
declare -A V=( [graphs]="$G" [minsize1]="$G --xla_gpu_graph_min_graph_size=1" [dsfusion]="--xla_gpu_enable_command_buffer=FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,WHILE,CONDITIONAL,DYNAMIC_SLICE_FUSION" )
for v in graphs minsize1 dsfusion; do
  XLA_FLAGS="${V[$v]}" MJXSYSID_JAX_CACHE=/tmp/jc_$v timeout 150 python3 docs/runs/measurements/log-grounded/batched/nuts_cmdbuf.py ${L:-512} 1 .carry/nuts_args.pkl > $OUT/$v.txt 2>&1; echo "rc $v: $?"
  grep -v -i warp $OUT/$v.txt | tail -2 | cut -c1-400
done
