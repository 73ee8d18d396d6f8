#!/usr/bin/env bash
# Accuracy III lever ablation (docs/research/training-data.md, 2026-11-25): the eraser on top of the ground; its control is
# runs/anneal-10500 (same init: the campaign's step-10,500 checkpoint, commit f294b5d, copied to runs/anneal-10500/init.pt;
# same 500 steps at lr 5e-4 after a 50-step warm-up, cosine to 5 %, seed 30, the ground), with --eraser 0.5 added.

exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/lever-eraser-on-ground --architecture cadenet2d \
  --init runs/anneal-10500/init.pt --levels 192 --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --slice-channels 4 --ground 0.3 --eraser 0.5 --steps 500 --batch 4 --height 192 --width 320 --lr 5e-4 --warmup 50 --seed 30 \
  --device cpu --threads 1 --workers 0 --validate-every 500 --validate-rgb "$@"
