#!/usr/bin/env bash
# Accuracy III shipping check (docs/research/campaigns.md, 2026-11-27): an annealed copy of the campaign's
# step-20,000 checkpoint (runs/campaign-2d/last.pt of commit b5e4fde, copied to
# runs/anneal-20000/init.pt): 500 steps at lr 5e-4 after a 50-step warm-up, cosine to 5 %, seed 30,
# the campaign's data and crops (192x320), as runs/anneal-13250 (cade-v11). Also the control of the
# crop lever (runs/anneal-20000-crop256).
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/anneal-20000 --architecture cadenet2d \
  --init runs/anneal-20000/init.pt --levels 192 --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --slice-channels 4 --ground 0.3 --steps 500 --batch 4 --height 192 --width 320 --lr 5e-4 --warmup 50 --seed 30 \
  --device cpu --threads 1 --workers 0 --validate-every 500 --validate-rgb "$@"
