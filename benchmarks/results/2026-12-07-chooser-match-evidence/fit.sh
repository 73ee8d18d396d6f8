#!/bin/bash
# Fit seed S (default 0) of the shipped accurate tier's chooser recipe plus --match-evidence into a copy of its card
# (cade-v13-accurate-match-sS.json, models/cade-v13.onnx beside it); CPU shared with training
cd "$(dirname "$0")/../../.." || exit 1
D=benchmarks/results/2026-12-07-chooser-match-evidence
S=${S:-0}
CARD=$D/cade-v13-accurate-match-s$S.json
[ -f $D/cade-v13.onnx ] || cp models/cade-v13.onnx $D/
[ -f $CARD ] || cp models/cade-v13-accurate-synthetic.json $CARD
OMP_NUM_THREADS=1 .venv/bin/python -m cade_cli.train chooser --real-dir ../shared/data/train-real \
    --cache benchmarks/results/2026-12-07-chooser-at-edges/chooser-cache --model $CARD --steps 3000 --seed $S \
    --write-card --candidates rank-sgbm --context --context-width 24 --match-evidence \
    --synthetic 162 --textures ../shared/data/textures
