#!/usr/bin/env bash
# Issue 38 item 5 (docs/research/training-data.md, 2026-11-27): runs/lever-selfsup with the self-supervised loss weighted 20
# instead of 2 (at 2 the loss on real crops hardly moved in 300 steps), the rectified pairs from runs/lever-selfsup's
# cache. Its control: runs/lever-selfsup-control (same seed 30, checkpoint, recipe, steps). Run as:
#   OMP_NUM_THREADS=1 runs/lever-selfsup-w20/command.sh
exec runs/anneal.sh runs/lever-selfsup-w20 --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --steps 300 --validate-every 300 \
  --selfsup-dir ../shared/data/micasense --selfsup-cache runs/lever-selfsup/selfsup-pairs \
  --selfsup-share 0.25 --selfsup-weight 20 "$@"
