#!/usr/bin/env bash
# Accuracy III crop lever (docs/research/campaigns.md, 2026-11-27): the shipping anneal runs/anneal-20000
# with larger crops, 256x448 (1.87x the pixels of 192x320) instead of 192x320; the same init
# (runs/anneal-20000/init.pt), steps, schedule, seed and data: 500 steps at lr 5e-4 after a 50-step
# warm-up, cosine to 5 %, seed 30. Larger crops hold wider disparities and more context (the
# Middlebury Q pairs reach 190 px, 60 % of a 320 px crop).
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/anneal-20000-crop256 --architecture cadenet2d \
  --init runs/anneal-20000/init.pt --levels 192 --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --slice-channels 4 --ground 0.3 --steps 500 --batch 4 --height 256 --width 448 --lr 5e-4 --warmup 50 --seed 30 \
  --device cpu --threads 1 --workers 0 --validate-every 500 --validate-rgb "$@"
