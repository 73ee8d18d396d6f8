#!/usr/bin/env bash
# Accuracy III, 2026-11-27: how far the fast design is from shipping. An annealed copy of runs/fast-2d's
# step-10,000 checkpoint (runs/fast-2d/last.pt in commit 4c7b906, copied to runs/anneal-fast-10000/init.pt;
# or runs/fast-2d/command.sh --stop-after 10000 from the step-5,000 commit), 500 steps as the campaign's anneals:
# lr 5e-4 after a 50-step warm-up, cosine to 5 %, seed 30, the fast run's data.
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/anneal-fast-10000 --architecture cadenet2d \
  --init runs/anneal-fast-10000/init.pt --levels 128 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --steps 500 --batch 4 --height 192 --width 320 --lr 5e-4 --warmup 50 --seed 30 \
  --device cpu --threads 1 --workers 0 --validate-every 500 --validate-rgb "$@"
