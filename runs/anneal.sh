#!/usr/bin/env bash
# Accuracy III's anneal of a checkpoint before its shipping check (docs/research/campaigns.md, 2026-11-25 to 2026-11-27):
# 500 steps at lr 5e-4 after a 50-step warm-up, cosine to 5 %, seed 30, the campaign's data and crops
# (192x320), one thread, from RUN_DIR/init.pt (a copy of the checkpoint) into RUN_DIR.
#
#   runs/anneal.sh RUN_DIR DESIGN_FLAGS... [OVERRIDES...]
#
# DESIGN_FLAGS are those of the checkpoint's network (--levels, --slice-channels, --features2d, ...);
# flags after them override the recipe's (the last occurrence wins). Run from the repository root.
# On a lent GPU (docs/gpu-recipe.md): DATA=.gpu-data PYTHON=python3, and the device flags after the others.
set -euo pipefail
out=$1
shift
data=${DATA:-../shared/data}
exec nice -n 10 "${PYTHON:-.venv/bin/python}" -m cade_cli.train fit --out "$out" --architecture cadenet2d --init "$out/init.pt" \
  --textures "$data/textures" --data-dir "$data" \
  --real-dir "$data/train-real" --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --steps 500 --batch 4 --height 192 --width 320 --lr 5e-4 --warmup 50 --seed 30 \
  --device cpu --threads 1 --workers 0 --validate-every 500 --validate-rgb "$@"
