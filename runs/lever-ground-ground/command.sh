#!/usr/bin/env bash
# Accuracy III lever ablation (docs/research/training-data.md, 2026-11-25): 500 steps from the campaign's step-8,750
# checkpoint, the campaign's data and schedule shape, with a ground in 30 % of rendered scenes.
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/lever-ground-ground --architecture cadenet2d \
  --init runs/lever-ground-init.pt --levels 192 --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --slice-channels 4 --ground 0.3 --steps 500 --batch 4 --height 192 --width 320 --lr 5e-4 --warmup 50 --seed 30 \
  --device cpu --threads 1 --workers 0 --validate-every 500 --validate-rgb "$@"
