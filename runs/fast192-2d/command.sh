#!/usr/bin/env bash
# Accuracy III, the fast design at 192 levels (docs/research/network-design.md, 2026-11-27): runs/fast-2d (128 levels)
# lost 17-37 % EPE against cade-v11 through cade benchmark on the sets whose ranges its 128 levels run
# at half size (Middlebury 2014, KITTI 2012, FlyingThings3D), at +17 % network time for 192 levels.
# It starts from runs/fast-2d's last checkpoint (runs/fast-2d/last.pt, step 12,500, where that run
# stopped; commit d2c1536) widened by net2d.with_more_levels (--init-partial): the old
# disparities keep their weights, the new ones start at the correlation prior. Then the campaign's
# data and schedule: lr 1e-3 after a 500-step warm-up, cosine to 5 % at 60,000, seed 33, the ground.
# Resume with the same command (it continues from runs/fast192-2d/last.pt). Beside the campaign on
# this 2-core machine: OMP_NUM_THREADS=1 runs/fast192-2d/command.sh --threads 1.
# --shadows 0.3 from the checkpoint of step 23,500 on (2026-11-27: its ablation, runs/lever-shadows against
# runs/anneal-42000, docs/research/training-data.md); the steps before it ran without (this file's earlier versions in git).
# The self-supervised lever (--selfsup-dir ../shared/data/micasense --selfsup-share 0.25 --selfsup-weight 2) ran steps
# 36,500-37,000 and was dropped (2026-11-27): at step 37,000 the campaign with it validated msir-outdoor 1.474 / 8.52 and
# Middlebury 2014 CS 4.86 / 30.4, the same run without it (runs/control-36000-37000, the same batches from the committed
# step 36,000) 1.026 / 4.80 and 4.72 / 29.7. The campaign goes on from the control's checkpoint of step 37,000; the
# lever's 500 steps are kept as runs/lever-campaign-36500 (logs only).
# runs/fast-2d/last.pt (step 12,500) left the tree on 2026-11-28, a finished run's checkpoint; bring it back before
# running this (fit checks that --init exists, even to resume):
#   git show 85fb266:runs/fast-2d/last.pt > runs/fast-2d/last.pt
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/fast192-2d --architecture cadenet2d \
  --init runs/fast-2d/last.pt --init-partial \
  --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --shadows 0.3 --steps 60000 --batch 4 --height 192 --width 320 --lr 1e-3 --warmup 500 --seed 33 \
  --device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb "$@"
