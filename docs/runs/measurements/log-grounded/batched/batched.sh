#!/usr/bin/env bash
# Device job: the log-grounded posterior batched over logs against one at a time (benchmarks/batched_posterior.py).
set -u
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1
nvidia-smi -L; nproc; date -u
python3 -c "import jax, mujoco, mujoco.mjx, blackjax, optimistix, mjxsysid.identify.inference; print(jax.__version__, jax.devices())" || exit 3
( while sleep 20; do nvidia-smi --query-gpu=utilization.gpu,memory.used --format=csv,noheader | tr '\n' ' '; echo " load $(cut -d' ' -f1 /proc/loadavg)"; done ) > $OUT/monitor.txt 2>&1 &
timeout ${2:-560} python3 benchmarks/batched_posterior.py --vehicles ${1:-1000} --levels ${3:-clean,x1,x5_white,x20} --sequential ${4:-8} --batch ${5:-256} \
  --out $OUT/batched.json 2>&1 | grep -v -i "warp" | tee $OUT/log.txt
