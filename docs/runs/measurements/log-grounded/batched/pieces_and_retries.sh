#!/usr/bin/env bash
# GPU 0: one calibration piece (tools/calibration_pieces.py), the cache carried; GPU 1: batched_posterior's cold pass,
# an empty cache, with the NUTS retries' reasons.
set -uo pipefail
TOP=$PWD; OUT=${OUT:-/tmp/out}; mkdir -p $OUT /tmp/jc_piece /tmp/piece
export PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false MJXSYSID_QUIET=1 PYTHONPATH=$TOP/.site:$TOP
cat .carry/jaxcache.tar.xz.* | xz -d | tar -C /tmp/jc_piece --strip-components=1 -xf - && echo "cache $(du -sh /tmp/jc_piece | cut -f1)"
( MJXSYSID_JAX_CACHE=/tmp/jc_piece MJXSYSID_COMMIT=${COMMIT:-unknown} CUDA_VISIBLE_DEVICES=0 \
  timeout 560 python3 tools/calibration_pieces.py /tmp/piece 530 ${PIECE:-rows/test_vel.0of4.json} > $OUT/log_piece.txt 2>&1 ) &
( MJXSYSID_JAX_CACHE=/tmp/jc_bp CUDA_VISIBLE_DEVICES=1 timeout 560 python3 benchmarks/batched_posterior.py --vehicles 192 \
  --levels x1 --sequential 0 --no-warm --workers 16 --out $OUT/bp.json > $OUT/log_bp.txt 2>&1 ) &
wait
grep -v -i warp $OUT/log_piece.txt | tr '\r' '\n' | grep -v 'it/s\]$\|log/s\]$' | grep -v '^\s*$' | tail -12
grep -v -i warp $OUT/log_bp.txt | tr '\r' '\n' | grep -v 'it/s\]$\|log/s\]$' | tail -12
cp /tmp/piece/rows/* $OUT/ 2>/dev/null; ls -la $OUT
