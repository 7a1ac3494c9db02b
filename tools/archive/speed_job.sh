#!/usr/bin/env bash
# One wall-time-against-quality run (issue 30): train-policy with a config, timed as a command
# (start-up and compile included), then the fast evaluation (1,000 default-prior vehicles).
#   bash tools/speed_job.sh RUN_DIR CONFIG.json [EVAL_VEHICLES]   (0: no evaluation, a timing run)
# Writes RUN_DIR/train.txt (the training log; `command_wall_s N ms` unless the run resumed from a
# checkpoint, whose time would not be a clean figure) and RUN_DIR/eval_fast/. Resumes a cut run.
# A run whose policy and evaluation exist is left as it is. tools/speed_table.py reads the folder.
set -euo pipefail
d=${1:?run dir}; cfg=${2:?config json}; n=${3:-1000}
mkdir -p "$d"
M="python3 -m mjxsysid.cli"
if [ ! -f "$d/policy.npz" ]; then
  t0=$(date +%s%N)
  $M train-policy --config "$cfg" --out "$d" -q > "$d/train.txt" 2>&1 || { tail -5 "$d/train.txt"; exit 1; }
  grep -q "resumed from" "$d/train.txt" || echo "command_wall_s $(( ($(date +%s%N) - t0) / 1000000 )) ms" >> "$d/train.txt"
  tail -3 "$d/train.txt"
fi
[ "$n" = 0 ] || [ -f "$d/eval_fast/eval.json" ] || $M evaluate-policy --fast --vehicles "$n" --weights "$d/policy.npz" --out "$d/eval_fast" -q
