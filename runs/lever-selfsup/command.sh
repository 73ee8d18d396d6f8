#!/usr/bin/env bash
# Accuracy IV lever ablation, issue 38 item 5 (docs/research/training-data.md, 2026-11-27): the self-supervised lever.
# As runs/lever-selfsup-control (its control: same checkpoint, recipe, seed and steps), plus a quarter of
# the training pairs cut from real cross-spectral band pairs without ground truth (../shared/data/micasense:
# the RedEdge-M bench and field captures and the Sequoia tabletop, every band pair rectified so the parallax
# runs along +x, cade_cli/train/selfsup_pairs.py, cached once in runs/lever-selfsup/selfsup-pairs), trained
# by the gradient-consistency + edge-aware smoothness loss (cade_cli/train/selfsup_loss.py) at weight 2.
#   OMP_NUM_THREADS=1 runs/lever-selfsup/command.sh
exec runs/anneal.sh runs/lever-selfsup --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --steps 300 --validate-every 300 \
  --selfsup-dir ../shared/data/micasense --selfsup-share 0.25 --selfsup-weight 2 "$@"
