#!/usr/bin/env bash
# Device job: the tuner given a log, the ensemble's drag from the log's velocity. Usage: bash .carry/logdrag.sh
set -u
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1
mkdir -p $OUT/t
nvidia-smi -L > $OUT/t/gpus.txt; date -u >> $OUT/t/gpus.txt
s=$(date +%s); timeout 370 python3 -m mjxsysid.cli experiment tune-slow -q --variant log_grounded_log_drag --out $OUT/t/run > $OUT/t/log.txt 2>&1; echo "rc=$? $(( $(date +%s) - s ))s" >> $OUT/t/gpus.txt
rm -f $OUT/t/run/*.png
cat $OUT/t/gpus.txt; tail -n 2 $OUT/t/log.txt
