#!/usr/bin/env bash
# Accuracy IV lever ablation, issue 38 item 5 (docs/research/training-data.md, 2026-11-27): the CONTROL of runs/lever-selfsup.
# 300 steps from the campaign's step-36,000 checkpoint (runs/fast192-2d, /work/cand/f36000.pt copied to
# runs/lever-selfsup-control/init.pt) by the anneal recipe (runs/anneal.sh: lr 5e-4, warm-up 50, seed 30,
# one thread) with the campaign's data flags (--shadows 0.3), no lever. Run as:
#   OMP_NUM_THREADS=1 runs/lever-selfsup-control/command.sh
exec runs/anneal.sh runs/lever-selfsup-control --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --steps 300 --validate-every 300 "$@"
