#!/usr/bin/env bash
# Independent GPU jobs spread over every GPU of the device machine, one job per GPU at a time
# (Python 3.12 + jax there, MuJoCo/MJX from .site, see README "GPU").
#   bash tools/gpu_farm.sh JOBS_FILE
# JOBS_FILE: one job a line, `NAME|GPU|NEEDS|COMMAND` (GPU: an index, * for any free one, or indices
# joined by + for a job on several GPUs, e.g. 0+1: GPU 0's worker runs it once GPU 1 is idle, and GPU 1's
# worker starts nothing while it is pending; put such jobs first); NEEDS:
# job names joined by commas, or -); `#` starts a comment. Each GPU's worker runs, in file order,
# the first job that is not done, not taken, meant for it, and whose NEEDS are done; a job is done
# when its command exits 0 (FARM/done/NAME). The command must resume what an earlier call left
# (train-policy, `release` stages and `experiment probe-loop` do), so every call of the same file
# goes on where the last one stopped: on a machine kept warm between calls, call it again until
# every job is done. Each job is cut at the call's budget (BUDGET_S, default 570 s); a job that
# fails is not retried in this call and its dependents wait for the next.
# After each job the small outputs of PACK (folders, default: every runs/ folder the jobs name)
# are packed into $OUT/farm_small.tar.gz (weights, pairs and checkpoints left out) and each file of
# FETCH (paths joined by spaces) is copied to $OUT on its own (at most 7: the tool returns 8 files).
# The job's output goes to FARM/logs/NAME.log (FARM, default runs/farm), the schedule to stdout.
set -uo pipefail
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1
JOBS=${1:?usage: gpu_farm.sh JOBS_FILE}
[ -f "$JOBS" ] || { echo "gpu_farm: $JOBS: no such jobs file"; exit 2; }
OUT=${OUT:-/tmp/out}; FARM=${FARM:-runs/farm}; T0=$(date +%s); END=$(( T0 + ${BUDGET_S:-570} ))
NGPU=${NGPU:-$(nvidia-smi -L 2>/dev/null | grep -c '^GPU')}
[ "$NGPU" -ge 1 ] || { echo "gpu_farm: no GPU found (set NGPU)"; exit 2; }
mkdir -p "$OUT" "$FARM/done" "$FARM/logs"; rm -rf "$FARM/claim" "$FARM/failed"; mkdir -p "$FARM/claim" "$FARM/failed"
PACK=${PACK:-$(grep -v '^#' "$JOBS" | grep -o 'runs/[A-Za-z0-9_.-]*' | sort -u | tr '\n' ' ')}
t() { echo "+$(( $(date +%s) - T0 ))s"; }

pack() {   # one archive per group of PACK (groups joined by ';'): each must stay under 16 MiB
  exec 9>"$FARM/pack.lock"; flock 9
  local i=0 group
  IFS=';' read -ra groups <<<"$FARM $PACK"
  for group in "${groups[@]}"; do
    i=$((i + 1))
    # shellcheck disable=SC2086
    tar czf "$OUT/farm_small$i.tar.gz.tmp" --exclude='pairs.npz' --exclude='checkpoint.npz' --exclude='*.tmp.npz' \
      --exclude='cfm.npz' --exclude='regression.npz' --exclude='cfm_seq.npz' --exclude='claim' $group 2>/dev/null
    mv -f "$OUT/farm_small$i.tar.gz.tmp" "$OUT/farm_small$i.tar.gz"
  done
  local n=0
  for f in ${FETCH:-}; do
    [ -f "$f" ] && [ $n -lt $((8 - i)) ] && { cp "$f" "$OUT/$(echo "$f" | tr / _)"; n=$((n + 1)); }
  done
  flock -u 9
}

worker() {   # GPU
  local gpu=$1
  while :; do
    local ran=0 waiting=0 reserved=0
    # A pending several-GPU job that needs this GPU (not as its first): start nothing until it is over.
    while IFS='|' read -r name where needs cmd; do
      [[ $name == \#* || $where != *+* ]] && continue
      name=$(echo "$name" | xargs); where=$(echo "$where" | xargs)
      [ -e "$FARM/done/$name" ] || [ -e "$FARM/failed/$name" ] && continue
      [[ "+${where#*+}+" == *"+$gpu+"* ]] && reserved=1
    done < "$JOBS"
    if [ $reserved = 1 ]; then
      [ $(( END - $(date +%s) )) -ge 20 ] || return
      sleep 5; continue
    fi
    while IFS='|' read -r name where needs cmd; do
      [[ $name == \#* ]] && continue
      name=$(echo "$name" | xargs); where=$(echo "$where" | xargs); needs=$(echo "$needs" | xargs)
      [ -z "$name" ] && continue; [[ $name == \#* ]] && continue
      [ -e "$FARM/done/$name" ] || [ -e "$FARM/claim/$name" ] && continue
      [ "$where" = "*" ] || [ "$where" = "$gpu" ] || [ "${where%%+*}" = "$gpu" ] || continue
      local ready=1 blocked=0
      for d in ${needs//,/ }; do
        [ "$d" = - ] && continue
        [ -e "$FARM/failed/$d" ] && blocked=1
        [ -e "$FARM/done/$d" ] || ready=0
      done
      [ $blocked = 1 ] && continue
      [ $ready = 1 ] || { waiting=1; continue; }
      mkdir "$FARM/claim/$name" 2>/dev/null || continue
      local gpus=$gpu locks=() g fd
      [[ $where == *+* ]] && gpus=${where//+/,}
      for g in ${gpus//,/ }; do   # each GPU's lock: held by whoever runs on it
        exec {fd}>"$FARM/gpu$g.lock"; flock "$fd"; locks+=("$fd")
      done
      local left=$(( END - $(date +%s) ))
      [ $left -lt 20 ] && { rmdir "$FARM/claim/$name"; for fd in "${locks[@]}"; do exec {fd}>&-; done; return; }
      echo "[$(t) gpu $gpus] $name: start ($left s left)"
      echo "=== $(date -u +%FT%TZ) gpu $gpus, $left s left: $cmd" >> "$FARM/logs/$name.log"
      CUDA_VISIBLE_DEVICES=$gpus timeout --kill-after=15 "$left" bash -c "$cmd" >> "$FARM/logs/$name.log" 2>&1
      local rc=$?
      for fd in "${locks[@]}"; do exec {fd}>&-; done
      if [ $rc = 0 ]; then touch "$FARM/done/$name"; echo "[$(t) gpu $gpus] $name: done"
      else touch "$FARM/failed/$name"; echo "[$(t) gpu $gpus] $name: exit $rc$([ $rc = 124 ] && echo ' (cut at the budget)')"
           grep -v -i warp "$FARM/logs/$name.log" | tail -4 | sed 's/^/    /'; fi
      pack; ran=1; break
    done < "$JOBS"
    [ $ran = 1 ] && continue
    [ $waiting = 1 ] && [ $(( END - $(date +%s) )) -ge 20 ] || return
    sleep 5
  done
}

echo "gpu_farm: $NGPU GPU(s), budget $(( END - T0 )) s, jobs: $(grep -v '^#' "$JOBS" | grep -c '|')"
for g in $(seq 0 $((NGPU - 1))); do worker "$g" & done
wait
pack
echo "[$(t)] jobs done: $(ls "$FARM/done" | tr '\n' ' ')"
echo "[$(t)] not done: $(grep -v '^#' "$JOBS" | cut -d'|' -f1 | xargs -n1 | while read -r j; do [ -e "$FARM/done/$j" ] || printf '%s ' "$j"; done)"
