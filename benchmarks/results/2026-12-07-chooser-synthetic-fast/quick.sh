#!/bin/bash
# Middlebury 2014 and 2005 CS and msir-outdoor: the shipped fast tier and its chooser's refits in one run per set
cd "$(dirname "$0")/../../.." || exit 1
F=benchmarks/results/2026-12-07-chooser-synthetic-fast
OUT=$F/quick
mkdir -p $OUT
MODELS=cade-v13,$F/cade-v13-s0.json,$F/cade-v13-s1.json,$F/cade-v13-synthetic.json,$F/cade-v13-synthetic-s1.json
for set in middlebury14 middlebury05 msir-outdoor; do
  protocol=(--protocol cs); [ "$set" = msir-outdoor ] && protocol=()
  OMP_NUM_THREADS=1 .venv/bin/cade benchmark --dataset $set --data-dir ../shared/data --methods cade \
    --model $MODELS "${protocol[@]}" --jobs 2 --json "$OUT/$set.json" > "$OUT/$set.md"
done
