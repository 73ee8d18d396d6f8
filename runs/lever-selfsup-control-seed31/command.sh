#!/usr/bin/env bash
# Issue 38 item 5, the ablation's second seed (docs/research/training-data.md, 2026-11-27): runs/lever-selfsup-control with
# --seed 31 (other batches), the noise of one 300-step anneal. Run as:
#   OMP_NUM_THREADS=1 runs/lever-selfsup-control-seed31/command.sh
exec runs/anneal.sh runs/lever-selfsup-control-seed31 --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --steps 300 --validate-every 300 --seed 31 "$@"
