#!/usr/bin/env bash
# Accuracy III, 2026-11-25: a design inside the speed budget, trained from scratch with the campaign's
# recipe, to be compared with the campaign at equal CPU time (steps x the quiet cost per step of
# benchmarks/train_step.py, retired since: git show 85fb266:benchmarks/train_step.py; the logged cpu_s depends
# on what shared the CPU). The design: 1/4 features 16 channels (campaign 32), U-Net width 32 (48), 1/2
# refinement 8 channels (16), the per-disparity stage as the campaign's (4 channels), 128 levels (192). Data and schedule as the campaign's, with its
# ground from the start. runs/fast-2d-no-slices: the same without the per-disparity stage (stopped).
# log.csv's Middlebury 2014 rows up to step 3,000 were scored before validation brought a pyramid
# level's map back to the scene's px (commit 43e1b81): they flatter this 128-level design (Jadeplant).
# Threads: 2 when it trains alone; beside another training process on this 2-core machine, run it as
# OMP_NUM_THREADS=1 command.sh --threads 1 (2026-11-25: two 2-thread processes spun on each other, the
# campaign took 7.5 CPU-s a step instead of 1.3, about 5x slower for both).
# Its last checkpoint (runs/fast-2d/last.pt, step 12,500, where it stopped) left the tree on 2026-11-28 (runs/fast192-2d
# and the runs started from it --init it):  git show 85fb266:runs/fast-2d/last.pt > runs/fast-2d/last.pt
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/fast-2d --architecture cadenet2d \
  --levels 128 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --steps 60000 --batch 4 --height 192 --width 320 --lr 1e-3 --warmup 500 --seed 31 \
  --device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb "$@"
