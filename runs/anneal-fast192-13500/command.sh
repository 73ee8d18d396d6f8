#!/usr/bin/env bash
# Accuracy III shipping check of the fast design, session 22 (models/README.md): an annealed copy of
# runs/fast192-2d's step-13,500 checkpoint (runs/fast192-2d/last.pt of this session's commit of that step,
# copied to runs/anneal-fast192-13500/init.pt), 500 steps as the campaign's anneals: lr 5e-4 after a
# 50-step warm-up, cosine to 5 %, seed 30, the fast run's data and crops (192x320).
# Checked by: benchmarks/candidate_check.sh runs/anneal-fast192-13500/last.pt f13500 /tmp/f13500
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/anneal-fast192-13500 --architecture cadenet2d \
  --init runs/anneal-fast192-13500/init.pt --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --steps 500 --batch 4 --height 192 --width 320 --lr 5e-4 --warmup 50 --seed 30 \
  --device cpu --threads 1 --workers 0 --validate-every 500 --validate-rgb "$@"
