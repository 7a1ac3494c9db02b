#!/usr/bin/env bash
# Device job: the posterior calibration's rows (calibration set, held-out test set, held-out families).
# Usage: bash .carry/cal.sh BUDGET_S
set -u
B=${1:-400}
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1
export NCCL_NVLS_ENABLE=0
W=$OUT/w; mkdir -p $W/cal $W/test $W/fam
nvidia-smi -L > $W/gpus.txt; nproc >> $W/gpus.txt; date -u >> $W/gpus.txt; git log --oneline -1 >> $W/gpus.txt 2>/dev/null
python3 -c "import jax, mujoco, mujoco.mjx, blackjax, optimistix, mjxsysid.identify.inference; print(jax.__version__, jax.devices())" > $W/imports.txt 2>&1 || { cat $W/imports.txt; exit 3; }
NG=$(nvidia-smi -L | wc -l)
PIDS=(); k=0
job() {  # job NAME args...
  local n=$1; shift
  ( export CUDA_VISIBLE_DEVICES=$((k % NG)) XLA_PYTHON_CLIENT_MEM_FRACTION=0.04
    s=$(date +%s); timeout $((B + 150)) python3 -m mjxsysid.cli calibrate-posterior -q "$@" --time-budget $B > $W/$n.log 2>&1; rc=$?
    echo "$n rc=$rc gpu=$((k % NG)) $(( $(date +%s) - s ))s" >> $W/jobs.txt ) &
  PIDS+=($!); k=$((k+1))
}
S=${SHARDS:-4}
for lv in clean x1 x5_white x5_vibration x20; do for i in $(seq 0 $((S-1))); do
  job cal_${lv}_$i --collect $W/cal/${lv}_$i.json --vehicles 200 --seed 5 --levels $lv --shard $i/$S; done; done
for i in $(seq 0 $((S/2-1))); do
  job cal_stress_$i --collect $W/cal/stress_$i.json --prior stress --vehicles 60 --seed 6 --levels clean,x5_white,x20 --shard $i/$((S/2)); done
for lv in clean x1 x2 x5_white x5_vibration x10 x20; do for i in $(seq 0 $((S-1))); do
  job test_${lv}_$i --collect $W/test/${lv}_$i.json --vehicles 200 --seed 71 --levels $lv --shard $i/$S; done; done
for fam in weak_motor slow_motors low_thrust payload_offset yaw_torque; do
  job fam_$fam --collect $W/fam/$fam.json --prior $fam --vehicles 16 --seed 71 --levels clean,x1; done
( while sleep 30; do nvidia-smi --query-gpu=index,utilization.gpu,memory.used --format=csv,noheader | tr '\n' ' '; echo " load $(cut -d' ' -f1 /proc/loadavg)"; done ) > $W/monitor.txt 2>&1 &
MON=$!
wait "${PIDS[@]}"
kill $MON
sort $W/jobs.txt
tar czf $OUT/cal.tar.gz -C $OUT w
ls -la $OUT
