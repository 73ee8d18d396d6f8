#!/usr/bin/env bash
# Accuracy IV shipping check of the campaign's second cycle, 2026-11-28 (docs/research/campaigns.md): an annealed copy of
# runs/fast192-2d-cycle2's step-15,000 checkpoint, its end (copied to runs/anneal-cycle2-15000/init.pt), by the anneal
# recipe (runs/anneal.sh: 500 steps, lr 5e-4 after a 50-step warm-up, seed 30) with --shadows 0.3 and the cycle's
# 256x448 crops: the recipe of runs/anneal-cycle2-5000 and -10000, run this time on the lent H200 (40 s of training;
# the first stage of runs/gpu-2026-11-28-first-gpu.sh). Checked against cade-v13 by:
#   REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm \
#     benchmarks/candidate_check.sh runs/anneal-cycle2-15000/last.pt a15000 OUT cade-v13
# Logs only: init.pt and last.pt are not in the tree. There: DATA=.gpu-data PYTHON=python3 with the default device
# flags below (runs/gpu-2026-11-28-first-gpu.sh, which ran it, wrote the recipe's flags out without anneal.sh's --data-dir and
# --validate-rgb, which find no sets there: the same training); here: DEVICE_FLAGS="--threads 2".
device=${DEVICE_FLAGS:-"--device cuda --amp --threads 2 --workers 14 --validate-every 100000"}
exec runs/anneal.sh runs/anneal-cycle2-15000 --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --height 256 --width 448 $device "$@"
