#!/usr/bin/env bash
# The Accuracy III training campaign: one run, resumed day after day (docs/research/campaigns.md,
# 2026-11-25). CadeNet2D with the per-disparity aggregation (--slice-channels 4), from scratch,
# seed 29. Run from the repository root; it continues from runs/campaign-2d/last.pt.
# --ground 0.3 from step 10,500 on (2026-11-25: its ablation, docs/research/training-data.md); the steps
# before it ran without (this file's earlier versions in git).
# Threads: 2 when it trains alone; beside another training process on this 2-core machine, run it as
# OMP_NUM_THREADS=1 command.sh --threads 1 (2026-11-25: two 2-thread processes spun on each other, the
# campaign took 7.5 CPU-s a step instead of 1.3, about 5x slower for both).
# --shadows 0.3 from the checkpoint of step 43,750 on (2026-11-27: its ablation, runs/lever-shadows against
# runs/anneal-42000, docs/research/training-data.md); the steps before it ran without (this file's earlier versions in git).
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/campaign-2d --architecture cadenet2d \
  --levels 192 --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --slice-channels 4 --ground 0.3 --shadows 0.3 --steps 60000 --batch 4 --height 192 --width 320 --lr 1e-3 --warmup 500 --seed 29 \
  --device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb "$@"
