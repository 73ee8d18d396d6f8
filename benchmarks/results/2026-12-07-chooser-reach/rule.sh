#!/bin/bash
# The shipping rule: the chooser with 33 px of reach (seed 0) against the shipped accurate tier, one run per set
cd "$(dirname "$0")/../../.." || exit 1
D=benchmarks/results/2026-12-07-chooser-reach
NEW=${NEW:-$D/cade-v13-accurate-reach33-s0.json}
OUT=${OUT:-$D/rule}
mkdir -p "$OUT"
for set in middlebury14 middlebury05 flyingthings3d kitti2012 kitti2015 msir-outdoor; do
  protocol=(--protocol cs,rgb); [ "$set" = msir-outdoor ] && protocol=()
  OMP_NUM_THREADS=1 .venv/bin/cade benchmark --dataset $set --data-dir ../shared/data --methods cade \
    --model cade-v13-accurate-synthetic,$NEW "${protocol[@]}" --jobs ${JOBS:-1} --json "$OUT/$set.json" > "$OUT/$set.md"
done
.venv/bin/python benchmarks/shipping_rule.py --shipped cade:cade-v13-accurate-synthetic \
  --candidate cade:$(basename "$NEW" .json) "$OUT"/*.json > "$OUT/rule.md"
echo "rule exit $?"
