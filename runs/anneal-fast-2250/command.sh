#!/usr/bin/env bash
# Accuracy III, 2026-11-25: how far the fast design is from shipping. An annealed copy of runs/fast-2d's
# step-2,250 checkpoint (runs/fast-2d/last.pt then, copied to runs/anneal-fast-2250/init.pt; not committed:
# re-run runs/fast-2d/command.sh --stop-after 2250 to remake it), 500 steps as the campaign's anneals:
# lr 5e-4 after a 50-step warm-up, cosine to 5 %, seed 30, the fast run's data.
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/anneal-fast-2250 --architecture cadenet2d \
  --init runs/anneal-fast-2250/init.pt --levels 128 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --steps 500 --batch 4 --height 192 --width 320 --lr 5e-4 --warmup 50 --seed 30 \
  --device cpu --threads 1 --workers 0 --validate-every 500 --validate-rgb "$@"
