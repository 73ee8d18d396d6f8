#!/usr/bin/env bash
# Accuracy V (issue 51) item 3, training data that teaches edges, begun 2026-11-28: the lever
# --asymmetric 0.3 (30 % of the pairs, rendered and real, get one view changed by vignetting, defocus, gamma,
# contrast, blur, noise or JPEG that the other view did not get)
# against runs/bakeoff-2026-11-28-control at equal CPU-hours. Everything else is the control's: its design
# (CadeNet2D in the shipped fast design, cade-v13's), its data recipe, batches (seed 51), crops, levels and
# learning-rate schedule, from scratch, one CPU-hour (runs/bakeoff.sh: --cpu-budget 3600, --workers 0 so
# that rendering, and so a lever's extra rendering cost, counts in the budget), validated on Middlebury
# every 500 steps. Judge it by the edge and non-occluded rows (item 1) against the control's; where the
# difference is within Accuracy IV's seed spread, rerun both with other seeds before concluding.
#
#   nohup nice runs/lever-2026-11-28-asymmetric/command.sh >> runs/lever-2026-11-28-asymmetric/stdout.log 2>&1 &
# resumes where it stopped. Picture of the lever's data: docs/img/training-levers-2026-11-28.png.
# Since 2026-12-06 it also stops at the control's 2,555 steps (--steps 2555: the cosine over them, the CPU-hour a
# backstop): an equal CPU-hour alone gave the floating lever 15 % more steps (docs/research/training-data.md).
# The GPU bake-off's --steps, given after, overrides it.
run=${RUN_DIR:-$(dirname "$0")}  # RUN_DIR: the same design elsewhere (the GPU bake-off, runs/gpu-bakeoff.sh)
exec "$(dirname "$0")/../bakeoff.sh" "$run" --architecture cadenet2d \
  --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 --asymmetric 0.3 --steps 2555 "$@"
