#!/usr/bin/env bash
# The design bake-off's shared recipe (Accuracy V, begun 2026-11-28): RUN_DIR DESIGN_FLAGS... [EXTRA].
# Every design: from scratch, the same data and batches, 192x320 crops, 192 levels, one CPU-hour
# (--cpu-budget 3600; the steps are a ceiling the budget stops first). DATA and PYTHON as runs/anneal.sh.
# DEVICE_FLAGS defaults to this VM's CPU (2 threads, rendering in-process so that the CPU budget counts it).
# SEED (default 51, every design's) gives a second seed of a design: the seed spread the choice is judged against.
set -euo pipefail
# Threads that wait sleep instead of spinning: a spinning OpenMP thread bills CPU-seconds for no work, more so
# on a busy machine, and the budget is in CPU-seconds.
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-PASSIVE}
run=$1; shift
data=${DATA:-../shared/data}
device=${DEVICE_FLAGS:-"--device cpu --threads 2 --workers 0 --validate-every 500 --data-dir $data --cpu-budget 3600"}
exec ${PYTHON:-.venv/bin/python} -m cade_cli.train fit --out "$run" \
  --levels 192 --textures "$data/textures" --real-dir "$data/train-real" --real-share 0.4 --network-input cade-floor \
  --misaligned 0.3 --scene-range 0.25 --ground 0.3 --shadows 0.3 --steps 20000 --batch 4 --height 192 --width 320 \
  --lr 1e-3 --warmup 200 --seed "${SEED:-51}" $device "$@"
