#!/usr/bin/env bash
# Accuracy V (issue 51) item 3, training data that teaches edges, begun 2026-11-28: the lever
# --thin 0.5 (half the rendered scenes get 1-6 thin structures, wires, poles and fronds 1-6 px wide, at their
# own disparity in front: sharp depth edges)
# against runs/bakeoff-2026-11-28-control at equal CPU-hours. Everything else is the control's: its design
# (CadeNet2D in the shipped fast design, cade-v13's), its data recipe, batches (seed 51), crops, levels and
# learning-rate schedule, from scratch, one CPU-hour (runs/bakeoff.sh: --cpu-budget 3600, --workers 0 so
# that rendering, and so a lever's extra rendering cost, counts in the budget), validated on Middlebury
# every 500 steps. Judge it by the edge and non-occluded rows (item 1) against the control's; where the
# difference is within Accuracy IV's seed spread, rerun both with other seeds before concluding.
#
#   nohup nice runs/lever-2026-11-28-thin/command.sh >> runs/lever-2026-11-28-thin/stdout.log 2>&1 &
# resumes where it stopped. Picture of the lever's data: docs/img/training-levers-2026-11-28.png.
run=${RUN_DIR:-$(dirname "$0")}  # RUN_DIR: the same design elsewhere (the GPU bake-off, runs/gpu-bakeoff.sh)
exec "$(dirname "$0")/../bakeoff.sh" "$run" --architecture cadenet2d \
  --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 --thin 0.5 "$@"
