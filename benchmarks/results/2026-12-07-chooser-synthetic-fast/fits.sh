#!/bin/bash
# The fast tier's perceptron chooser refitted: with 162 rendered pairs (seeds 0 and 1) and without (seeds 0, today's
# refit of the shipped recipe, and 1)
cd "$(dirname "$0")/../../.." || exit 1
F=benchmarks/results/2026-12-07-chooser-synthetic-fast
CACHE=$F/chooser-cache
fit() {  # card seed [synthetic flags]
  OMP_NUM_THREADS=1 .venv/bin/python -m cade_cli.train chooser --real-dir ../shared/data/train-real --cache $CACHE \
    --model $F/$1.json --hidden 32 --steps 4000 --seed $2 --write-card --candidates rank-sgbm "${@:3}" > $F/chooser-$1.log 2>&1
}
fit cade-v13-synthetic 0 --synthetic 162 --textures ../shared/data/textures
fit cade-v13-synthetic-s1 1 --synthetic 162 --textures ../shared/data/textures
fit cade-v13-s1 1
fit cade-v13-s0 0
