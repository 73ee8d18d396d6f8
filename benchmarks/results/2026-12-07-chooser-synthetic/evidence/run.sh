#!/bin/bash
# The mask evidence lever's network (the campaign's design) as the accurate tier: its convolutional chooser refitted
# with 162 rendered pairs, judged against the same card with the train-real-only chooser (../../2026-12-07-chooser-context/evidence-context.json)
cd "$(dirname "$0")/../../../.." || exit 1
E=benchmarks/results/2026-12-07-chooser-synthetic/evidence
OMP_NUM_THREADS=1 .venv/bin/python -m cade_cli.train chooser --real-dir ../shared/data/train-real \
  --cache benchmarks/results/2026-12-07-mask-uncertainty/chooser-cache/evidence-mask-uncertainty \
  --model $E/evidence-synthetic.json --steps 3000 --seed 0 --write-card --candidates rank-sgbm --context \
  --context-width 24 --synthetic 162 --textures ../shared/data/textures > $E/chooser.log 2>&1 || exit 1
for set in middlebury14 middlebury05 msir-outdoor; do
  protocol=(--protocol cs); [ "$set" = msir-outdoor ] && protocol=()
  OMP_NUM_THREADS=1 .venv/bin/cade benchmark --dataset $set --data-dir ../shared/data --methods cade \
    --model benchmarks/results/2026-12-07-chooser-context/evidence-context.json,$E/evidence-synthetic.json \
    "${protocol[@]}" --jobs 2 --json "$E/$set.json" > /dev/null
done
