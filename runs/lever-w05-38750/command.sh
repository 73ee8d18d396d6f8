#!/usr/bin/env bash
# 2026-11-28: issue 38 item 5's next try. The campaign (runs/fast192-2d's flags, its batches [seed 33, step]) from its
# committed checkpoint of step 38,750 (commit 3652b88, copied here as last.pt with its log) WITH the self-supervised lever
# at a quarter of 2026-11-27's weight and under half its share (--selfsup-share 0.1 --selfsup-weight 0.5; 2026-11-27's
# 0.25 / 2 moved msir-outdoor from 1.026 to 1.474 at step 37,000). Its control is the campaign itself, which resumed
# from the same checkpoint: their validation rows of steps 39,000 and 40,000 compare the lever with nothing else changed.
#   git show 3652b88:runs/fast192-2d/last.pt > runs/lever-w05-38750/last.pt
#   git show 3652b88:runs/fast192-2d/log.csv > runs/lever-w05-38750/log.csv
#   OMP_NUM_THREADS=1 runs/lever-w05-38750/command.sh --threads 1
# Result (docs/research/training-data.md, 2026-11-28): at 39,000 msir-outdoor 0.944 against the campaign's 1.044 but every
# Middlebury row worse; at 40,000 level with the campaign; not kept. Logs only (its last.pt is not in the tree).
# runs/fast-2d/last.pt (step 12,500) left the tree on 2026-11-28, a finished run's checkpoint; bring it back before
# running this (fit checks that --init exists, even to resume):
#   git show 85fb266:runs/fast-2d/last.pt > runs/fast-2d/last.pt
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/lever-w05-38750 --architecture cadenet2d \
  --init runs/fast-2d/last.pt --init-partial \
  --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --shadows 0.3 --selfsup-dir ../shared/data/micasense --selfsup-cache runs/fast192-2d/selfsup-pairs \
  --selfsup-share 0.1 --selfsup-weight 0.5 --stop-after 40000 \
  --steps 60000 --batch 4 --height 192 --width 320 --lr 1e-3 --warmup 500 --seed 33 \
  --device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb "$@"
