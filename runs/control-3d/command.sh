#!/usr/bin/env bash
# Accuracy III's control: today's design (cadenet, cade-v6's 3D aggregation, 192 levels) on the
# campaign's data and schedule, for comparison at equal CPU time (docs/research/network-design.md, 2026-11-25).
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/control-3d --architecture cadenet \
  --levels 192 --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --steps 60000 --batch 4 --height 192 --width 320 --lr 1e-3 --warmup 500 --seed 29 \
  --device cpu --threads 2 --workers 0 --validate-every 500 --validate-rgb --stop-after 1500 "$@"
