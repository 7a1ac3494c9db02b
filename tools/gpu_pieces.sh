#!/usr/bin/env bash
# The posterior calibration's pieces on a device machine, one process a GPU (tools/calibration_pieces.py), with
# JAX's compilation cache carried from one device call to the next.
#   P0=rows/a.0of4.json,rows/a.1of4.json P1=rows/a.2of4.json B=540 bash tools/gpu_pieces.sh
# Pi: the pieces GPU i collects, in order (an unset Pi leaves GPU i idle); B: each process's deadline, seconds.
# Ri: the tree GPU i runs from (default: this one), e.g. another commit's `git archive` in .carry/old with its
# short sha in a COMMIT file there: two commits' pieces side by side in one call, for a ratio.
# Brings back $OUT/rows.tar (every piece's row file, whole or .partial, and each process's log) and the cache as
# $OUT/jaxcache.tar.xz.NN (15 MB parts). Carry those parts in .carry/ (with .site) and the next call starts with
# them: compiling 24 s a piece instead of 114 s (2026-11-30). Partial pieces put in .carry/resume/ are resumed.
set -uo pipefail
TOP=$PWD
export PYTHONPATH=$PWD/.site:$PWD PYTHONUNBUFFERED=1 MJXSYSID_JAX_CACHE=${MJXSYSID_JAX_CACHE:-/tmp/jaxcache}
export MJXSYSID_PROGRESS=1 MJXSYSID_COMMIT=${COMMIT:-$(git rev-parse --short HEAD 2>/dev/null || echo unknown)}
OUT=${OUT:-/tmp/out}; W=${W:-/tmp/pieces}; B=${B:-540}
mkdir -p "$OUT" "$W/res" "$MJXSYSID_JAX_CACHE"
if ls .carry/jaxcache.tar.xz.* >/dev/null 2>&1; then
  cat .carry/jaxcache.tar.xz.* | xz -d | tar -C "$MJXSYSID_JAX_CACHE" --strip-components=1 -xf - \
    && echo "cache: $(du -sh "$MJXSYSID_JAX_CACHE" | cut -f1) carried"
fi
RES=(); ls .carry/resume/* >/dev/null 2>&1 && RES=(--resume-from $TOP/.carry/resume)
nvidia-smi --query-gpu=name,memory.used --format=csv,noheader
NGPU=$(nvidia-smi -L 2>/dev/null | grep -c '^GPU')
for ((i = 0; i < NGPU; i++)); do
  var=P$i; [ -n "${!var:-}" ] || continue
  mkdir -p "$W/$i"; root=R$i; dir=${!root:-.}
  (cd "$dir" && export PYTHONPATH=$TOP/.site:$PWD MJXSYSID_COMMIT=$(cat COMMIT 2>/dev/null || echo "$MJXSYSID_COMMIT") \
    && CUDA_VISIBLE_DEVICES=$i timeout $((B + 20)) python3 tools/calibration_pieces.py "$W/$i" "$B" "${!var}" \
    "${RES[@]}" > "$W/res/log$i.txt" 2>&1) &
done
wait
for f in "$W"/res/log*.txt; do [ -f "$f" ] || continue; grep -v -i warp "$f" | grep -v '^\s*$' | tr '\r' '\n' | grep -v 'it/s\]$\|log/s\]$' | tail -15; done
for ((i = 0; i < NGPU; i++)); do
  [ -d "$W/$i/rows" ] && cp "$W/$i"/rows/*.json* "$W/res/" 2>/dev/null
done
tar -C "$W" -cf "$OUT/rows.tar" res && tar -tf "$OUT/rows.tar"
tar -C "$(dirname "$MJXSYSID_JAX_CACHE")" -cf - "$(basename "$MJXSYSID_JAX_CACHE")" | xz -T0 -1 > "$W/jc.tar.xz"
split -b 15M -d "$W/jc.tar.xz" "$OUT/jaxcache.tar.xz."
ls -la "$OUT"
