#!/usr/bin/env bash
# Device job: the downstream tables with the calibrated posterior (logs with velocity): closed-loop fidelity,
# robustness and the tuner given a log. Usage: bash .carry/down.sh
set -u
T=${JOB_TIMEOUT:-500}
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 NCCL_NVLS_ENABLE=0
W=$OUT/w; mkdir -p $W/fid $W/rob $W/tune
nvidia-smi -L > $W/gpus.txt; nproc >> $W/gpus.txt; date -u >> $W/gpus.txt
PIDS=()
job() {  # job GPU NAME cmd...
  local g=$1 n=$2; shift 2
  ( export CUDA_VISIBLE_DEVICES=$g XLA_PYTHON_CLIENT_MEM_FRACTION=0.2
    s=$(date +%s); timeout $T "$@" > $W/$n.log 2>&1; rc=$?
    echo "$n rc=$rc gpu=$g $(( $(date +%s) - s ))s" >> $W/jobs.txt ) &
  PIDS+=($!)
}
job 0 fid_lg python3 benchmarks/closed_loop_fidelity.py --posterior log_grounded --out $W/fid/log_grounded.json
job 1 fid_lgw python3 benchmarks/closed_loop_fidelity.py --posterior log_grounded_weighed --out $W/fid/log_grounded_weighed.json
job 2 rob_lg python3 -m mjxsysid.cli experiment robustness -q --variant log_grounded --out $W/rob/log_grounded
job 3 rob_lgw python3 -m mjxsysid.cli experiment robustness -q --variant log_grounded_weighed --out $W/rob/log_grounded_weighed
job 0 tune_lg python3 -m mjxsysid.cli experiment tune-slow -q --variant log_grounded --out $W/tune/log_grounded
job 1 tune_kd python3 -m mjxsysid.cli experiment tune-slow -q --variant log_grounded_known_drag --out $W/tune/log_grounded_known_drag
( while sleep 30; do nvidia-smi --query-gpu=index,utilization.gpu,memory.used --format=csv,noheader | tr '\n' ' '; echo " load $(cut -d' ' -f1 /proc/loadavg)"; done ) > $W/monitor.txt 2>&1 &
MON=$!
wait "${PIDS[@]}"
kill $MON
sort $W/jobs.txt
find $W -name "*.png" -delete
tar czf $OUT/down.tar.gz -C $OUT w
ls -la $OUT
