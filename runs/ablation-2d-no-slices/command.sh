#!/usr/bin/env bash
# Accuracy III ablation: the campaign's first design (CadeNet2D without the per-disparity aggregation), stopped
# at step 3,400 when runs/campaign-2d (the same recipe with --slice-channels 4) replaced it (docs/research/network-design.md, 2026-11-25).
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/ablation-2d-no-slices --architecture cadenet2d \
  --levels 192 --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --steps 60000 --batch 4 --height 192 --width 320 --lr 1e-3 --warmup 500 --seed 29 \
  --device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb "$@"
