#!/usr/bin/env bash
# 2026-11-27: the campaign's counterfactual for its first 1,000 steps with the self-supervised lever: the same run
# (runs/fast192-2d's flags, its batches [seed 33, step]) from its committed checkpoint of step 36,000 (commit 64355b1,
# copied here as last.pt) to 37,000 WITHOUT the lever (the campaign ran 36,000-36,500 without it, 36,500-37,000 with it),
# so its validation row of step 37,000 is the control of the campaign's. docs/research/training-data.md, 2026-11-27.
#   git show 64355b1:runs/fast192-2d/last.pt > runs/control-36000-37000/last.pt
#   OMP_NUM_THREADS=2 runs/control-36000-37000/command.sh --threads 2
# runs/fast-2d/last.pt (step 12,500) left the tree on 2026-11-28, a finished run's checkpoint; bring it back before
# running this (fit checks that --init exists, even to resume):
#   git show 85fb266:runs/fast-2d/last.pt > runs/fast-2d/last.pt
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/control-36000-37000 --architecture cadenet2d \
  --init runs/fast-2d/last.pt --init-partial \
  --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --shadows 0.3 --steps 60000 --stop-after 37000 --batch 4 --height 192 --width 320 --lr 1e-3 --warmup 500 --seed 33 \
  --device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb "$@"
