#!/bin/bash
# Middlebury 2014 and 2005 CS and msir-outdoor: the shipped accurate tier against the chooser fitted with rendered pairs
cd "$(dirname "$0")/../../.." || exit 1
D=benchmarks/results/2026-12-07-chooser-synthetic
NEW=${NEW:-$D/cade-v13-accurate-synthetic.json}
OUT=${OUT:-$D/quick}
mkdir -p "$OUT"
for set in middlebury14 middlebury05 msir-outdoor; do
  protocol=(--protocol cs); [ "$set" = msir-outdoor ] && protocol=()
  OMP_NUM_THREADS=1 .venv/bin/cade benchmark --dataset $set --data-dir ../shared/data --methods cade \
    --model cade-v13-accurate-context,$NEW "${protocol[@]}" --jobs 2 --json "$OUT/$set.json" > "$OUT/$set.md"
done
