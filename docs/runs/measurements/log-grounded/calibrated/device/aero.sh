#!/usr/bin/env bash
# Device job: calibration rows of logs that carry velocity, flown with the simulator's rotor aerodynamics (--aero):
# calibration set (oracle and policy) and a held-out test set, new seeds. Usage: bash .carry/aero.sh BUDGET_S
set -u
B=${1:-360}
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 NCCL_NVLS_ENABLE=0
W=$OUT/w; mkdir -p $W/cal $W/test
nvidia-smi -L > $W/gpus.txt; nproc >> $W/gpus.txt; date -u >> $W/gpus.txt
python3 -c "import jax, mujoco, mujoco.mjx, blackjax, optimistix, mjxsysid.identify.inference; print(jax.__version__, jax.devices())" > $W/imports.txt 2>&1 || { cat $W/imports.txt; exit 3; }
NG=$(nvidia-smi -L | wc -l)
PIDS=(); k=0
job() {  # job NAME args...
  local n=$1; shift
  ( export CUDA_VISIBLE_DEVICES=$((k % NG)) XLA_PYTHON_CLIENT_MEM_FRACTION=0.04
    s=$(date +%s); timeout $((B + 150)) python3 -m mjxsysid.cli calibrate-posterior -q --aero "$@" --time-budget $B > $W/$n.log 2>&1; rc=$?
    echo "$n rc=$rc gpu=$((k % NG)) $(( $(date +%s) - s ))s" >> $W/jobs.txt ) &
  PIDS+=($!); k=$((k+1))
}
FL=(lemniscate:10 minsnap:10 lemniscate:20 hover:8)
for r in 0 1 2 3; do f=${FL[$r]}; for lv in clean x1 x5_white x5_vibration x20; do
  job cal_${lv}_$r --collect $W/cal/a_${lv}_$r.json --vehicles 200 --seed 23 --levels $lv --flights $f --shard $r/4; done; done
for r in 0 1; do f=${FL[$r]}; for lv in clean x1 x5_white x5_vibration x20; do
  job calp_${lv}_$r --collect $W/cal/ap_${lv}_$r.json --vehicles 200 --seed 29 --levels $lv --flights $f --shard $r/2 --controller policy; done; done
for r in 0 1 2 3; do f=${FL[$r]}; for lv in clean x1 x2 x5_white x5_vibration x10 x20; do
  job test_${lv}_$r --collect $W/test/a_${lv}_$r.json --vehicles 200 --seed 83 --levels $lv --flights $f --shard $r/4; done; done
( while sleep 30; do nvidia-smi --query-gpu=index,utilization.gpu,memory.used --format=csv,noheader | tr '\n' ' '; echo " load $(cut -d' ' -f1 /proc/loadavg)"; done ) > $W/monitor.txt 2>&1 &
MON=$!
wait "${PIDS[@]}"
kill $MON
sort $W/jobs.txt | awk '{print $2}' | sort | uniq -c
tar czf $OUT/aero.tar.gz -C $OUT w
rm -rf $W
ls -la $OUT
