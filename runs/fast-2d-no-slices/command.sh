#!/usr/bin/env bash
# Accuracy III, 2026-11-25: the fast design's first try, WITHOUT the per-disparity stage; stopped at step
# 2,400 (checkpoint 2,250) for runs/fast-2d (the same with --slice-channels 4): at step 2,000 its network validation had BMP3
# 43-47 %, as the campaign-width run without the stage (runs/ablation-2d-no-slices) against 33-37 % with it.
# The design:
# 1/4 features 16 channels (campaign 32), U-Net width 32 (48), 1/2 refinement 8 (16), no per-disparity
# aggregation (4), 128 levels (192): 0.51x the campaign network's time at 720x496
# (benchmarks/design_speed.py). Data and schedule as the campaign's, with its ground from the start.
# Threads: 2 when it trains alone; beside another training process on this 2-core machine, run it as
# OMP_NUM_THREADS=1 command.sh --threads 1 (2026-11-25: two 2-thread processes spun on each other, the
# campaign took 7.5 CPU-s a step instead of 1.3, about 5x slower for both).
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/fast-2d-no-slices --architecture cadenet2d \
  --levels 128 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 0 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --steps 60000 --batch 4 --height 192 --width 320 --lr 1e-3 --warmup 500 --seed 31 \
  --device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb "$@"
