#!/usr/bin/env bash
# Accuracy IV, the campaign's third cycle (docs/research/campaigns.md, 2026-11-28), trained on the first GPU lent to this
# project (one H200, 2026-11-28) in 446 s of training: cycle 2 (runs/fast192-2d-cycle2, 256x448 crops) ended with
# its annealed checkpoints better than cade-v13 on both Middlebury means but worse on the same-band BMP3 of the
# driving and Middlebury 2005 sets, the 192x320 crops' strength. Cycle 3 goes back to 192x320 crops as a warm restart
# from cycle 2's end (runs/fast192-2d-cycle2/last.pt, step 15,000, weights only; out of the tree since 2026-11-28, see below),
# the same design and data, a new seed (35), lr 3e-4 after a 200-step warm-up, cosine to 5 % at 11,500 steps (the
# step count the device call's time left allowed, from the pace of its first stage: .gpu-pack's run script,
# recorded as runs/gpu-2026-11-28-first-gpu.sh).
#
# As run there (docs/gpu-recipe.md): DATA=.gpu-data PYTHON=python3 runs/fast192-2d-cycle3/command.sh --time-budget 366
# (stopped at step 9,511, checkpointed), then the same command resumed to the end. On this CPU instead (about
# 3.4 CPU-hours; bf16 autocast on the GPU, float32 here, so not bit for bit):
#   DEVICE_FLAGS="--device cpu --threads 2 --workers 0 --validate-every 1000 --data-dir ../shared/data" \
#     runs/fast192-2d-cycle3/command.sh
# runs/fast192-2d-cycle2/last.pt (step 15,000) left the tree on 2026-11-28, a finished run's checkpoint; bring it
# back before running this (fit checks that --init exists, even to resume):
#   git show 85fb266:runs/fast192-2d-cycle2/last.pt > runs/fast192-2d-cycle2/last.pt
data=${DATA:-../shared/data}
device=${DEVICE_FLAGS:-"--device cuda --amp --threads 2 --workers 14 --validate-every 100000"}
exec ${PYTHON:-.venv/bin/python} -m cade_cli.train fit --out runs/fast192-2d-cycle3 --architecture cadenet2d \
  --init runs/fast192-2d-cycle2/last.pt \
  --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures "$data/textures" --real-dir "$data/train-real" --real-share 0.4 --network-input cade-floor \
  --misaligned 0.3 --scene-range 0.25 --ground 0.3 --shadows 0.3 --steps 11500 --batch 4 --height 192 --width 320 \
  --lr 3e-4 --warmup 200 --seed 35 $device "$@"
