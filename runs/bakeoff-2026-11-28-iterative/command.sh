#!/usr/bin/env bash
# Accuracy V (issue 51) item 2, the design bake-off begun 2026-11-28: every design trains from scratch on
# the same data (the Accuracy IV campaign's recipe: procedural scenes with ground and shadows, 40 % real
# training scenes, the contrast-floor transform, 30 % misaligned pairs), the same batches (seed 51), 192x320
# crops, 192 levels, the same learning-rate schedule, for the same CPU budget: --cpu-budget 3600 (one
# CPU-hour, the run's cpu_s summed over resumes; --workers 0, so rendering counts too), validated on
# Middlebury every 500 steps. Equal CPU-hours, not equal steps: on this 2-vCPU VM a larger design takes
# fewer steps for the same cost. The cosine runs to 5 % over the budget (fit.learning_rate), so every design
# ends annealed (docs/research/network-design.md).
# This run is cadenet-iterative (cade_cli/train/net_iterative.py): a 1/8 correlation volume and small 2D
# aggregation give a first estimate, re-matched at 1/4 by two update steps on the local correlation at the
# estimate +-2 px (integer-shift slices and linear-interpolation weights, no gather), then learned convex
# upsampling x4 (the mask from the left view).
#
#   nohup nice runs/bakeoff-2026-11-28-iterative/command.sh >> runs/bakeoff-2026-11-28-iterative/stdout.log 2>&1 &
# resumes where it stopped. On a lent GPU the bake-off runs instead at equal steps (docs/gpu-recipe.md).
run=${RUN_DIR:-$(dirname "$0")}  # RUN_DIR: the same design elsewhere (the GPU bake-off, runs/gpu-bakeoff.sh)
exec "$(dirname "$0")/../bakeoff.sh" "$run" --architecture cadenet-iterative \
  --features2d 24 --width2d 32 "$@"
