#!/usr/bin/env bash
# Device jobs for regenerating the log-grounded downstream tables. Usage: bash .carry/dev.sh PHASE
# PHASE a: calibration (200 vehicles, 8 shards x 5 levels), fidelity, robustness, tuner (two variants)
# PHASE b: innovations calibration (96 vehicles, 16 shards), sysid side by side (16 vehicles)
set -u
PHASE=$1
T=${JOB_TIMEOUT:-530}
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
W=$OUT/w; mkdir -p $W
nvidia-smi -L > $W/gpus.txt; nproc >> $W/gpus.txt; date -u >> $W/gpus.txt
python3 -c "import jax, mujoco, mujoco.mjx, blackjax, optimistix, mjxsysid.identify.inference; print(jax.__version__, jax.devices())" > $W/imports.txt 2>&1 || { cat $W/imports.txt; exit 3; }
NG=$(nvidia-smi -L | wc -l)
job() {  # job GPU FRACTION NAME cmd...
  local g=$1 f=$2 n=$3; shift 3
  ( export CUDA_VISIBLE_DEVICES=$g XLA_PYTHON_CLIENT_MEM_FRACTION=$f
    s=$(date +%s); timeout $T "$@" > $W/$n.log 2>&1; rc=$?
    echo "$n rc=$rc gpu=$g ${s} $(( $(date +%s) - s ))s" >> $W/jobs.txt ) &
  PIDS+=($!)
}
PIDS=()
k=0
if [ "$PHASE" = a ]; then
  mkdir -p $W/cal $W/fid $W/rob $W/tune
  job 0 0.15 fid_lg python3 benchmarks/closed_loop_fidelity.py --posterior log_grounded --out $W/fid/log_grounded.json
  job 1 0.15 fid_lgw python3 benchmarks/closed_loop_fidelity.py --posterior log_grounded_weighed --out $W/fid/log_grounded_weighed.json
  job $((2 % NG)) 0.15 rob_lg python3 -m mjxsysid.cli experiment robustness --variant log_grounded --out $W/rob/log_grounded
  job $((3 % NG)) 0.15 rob_lgw python3 -m mjxsysid.cli experiment robustness --variant log_grounded_weighed --out $W/rob/log_grounded_weighed
  job $((2 % NG)) 0.15 tune_lg python3 -m mjxsysid.cli experiment tune-slow --variant log_grounded --out $W/tune/log_grounded
  job $((3 % NG)) 0.15 tune_kd python3 -m mjxsysid.cli experiment tune-slow --variant log_grounded_known_drag --out $W/tune/log_grounded_known_drag
  for lv in clean x1 x5_white x5_vibration x20; do for i in 0 1 2 3 4 5 6 7; do
    job $((k % NG)) 0.05 cal_${lv}_$i python3 benchmarks/log_grounded.py --vehicles 200 --shard $i/8 --levels $lv --out $W/cal/${lv}_$i.json
    k=$((k+1)); done; done
elif [ "$PHASE" = b ]; then
  mkdir -p $W/inn $W/sys $W/tune
  job 0 0.2 tune_lg python3 -m mjxsysid.cli experiment tune-slow --variant log_grounded --out $W/tune/log_grounded
  job 1 0.2 tune_kd python3 -m mjxsysid.cli experiment tune-slow --variant log_grounded_known_drag --out $W/tune/log_grounded_known_drag
  for i in $(seq 0 15); do
    job $((i % NG)) 0.05 sys_$i nice -n 10 python3 benchmarks/sysid_side_by_side.py --vehicles 16 --levels clean,x5_white,x20 --shard $i/16 --out $W/sys/$i.json
  done
  for lvs in clean,x1 x5_white,x5_vibration x20; do for i in $(seq 0 15); do
    job $((k % NG)) 0.04 inn_${lvs%%,*}_$i nice -n 10 python3 benchmarks/log_grounded.py --vehicles 96 --rates innovations --levels $lvs --shard $i/16 --out $W/inn/${lvs%%,*}_$i.json
    k=$((k+1)); done; done
fi
( while sleep 30; do nvidia-smi --query-gpu=index,utilization.gpu,memory.used --format=csv,noheader | tr '\n' ' '; echo " load $(cut -d' ' -f1 /proc/loadavg)"; done ) > $W/monitor.txt 2>&1 &
MON=$!
wait "${PIDS[@]}"
kill $MON
cat $W/jobs.txt | sort
tar czf $OUT/res_$PHASE.tar.gz -C $OUT w
rm -rf $W
ls -la $OUT
