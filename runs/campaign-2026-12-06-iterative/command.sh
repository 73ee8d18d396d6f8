#!/usr/bin/env bash
# Accuracy V (issue 51) item 4, the chosen design's campaign, begun 2026-12-06: cadenet-iterative
# (cade_cli/train/net_iterative.py), the design the bake-off chose (docs/research/network-design.md, "Design
# bake-off": the best whole matcher on every set after one CPU-hour, the fewest parameters, and still falling
# steeply when its hour ended) with the bake-off's data recipe (runs/bakeoff.sh) and --floating 0.5 (the lever
# that the published procedural-set finding and the bake-off's floating run favour: docs/research/training-data.md),
# from scratch, 20,000 steps with the cosine over the steps and no CPU budget: a lent GPU continues the same
# schedule (runs/gpu-campaign.sh, docs/gpu-recipe.md), the CPU continues it between loans
# (runs/bakeoff-queue.txt lists it). Validated every 1,000 steps on the cross-spectral and the same-band
# Middlebury sets and msir-outdoor.
#
#   nohup nice runs/campaign-2026-12-06-iterative/command.sh >> runs/campaign-2026-12-06-iterative/stdout.log 2>&1 &
# resumes where it stopped; fit prints "finished: step 20000 of 20000" when the schedule is done.
# DEVICE_FLAGS replaces the CPU's flags (the GPU's: runs/gpu-campaign.sh); RUN_DIR trains it elsewhere.
run=${RUN_DIR:-$(dirname "$0")}
data=${DATA:-../shared/data}
export DEVICE_FLAGS=${DEVICE_FLAGS:-"--device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb --data-dir $data"}
exec "$(dirname "$0")/../bakeoff.sh" "$run" --architecture cadenet-iterative \
  --features2d 24 --width2d 32 --floating 0.5 "$@"
