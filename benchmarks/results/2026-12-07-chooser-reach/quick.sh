#!/bin/bash
# Middlebury 2014 and 2005 CS and msir-outdoor for one card (NEW), its records in OUT; compare with the shipped
# tier's records (docs/bench/cade-v13-accurate-synthetic) by benchmarks/model_table.py
cd "$(dirname "$0")/../../.." || exit 1
D=benchmarks/results/2026-12-07-chooser-reach
NEW=${NEW:?a card}
OUT=${OUT:?a folder}
mkdir -p "$OUT"
for set in middlebury14 middlebury05 msir-outdoor; do
  protocol=(--protocol cs); [ "$set" = msir-outdoor ] && protocol=()
  OMP_NUM_THREADS=1 .venv/bin/cade benchmark --dataset $set --data-dir ../shared/data --methods cade \
    --model $NEW "${protocol[@]}" --jobs ${JOBS:-1} --json "$OUT/$set.json" > "$OUT/$set.md" && gzip -9f "$OUT/$set.json"
done
