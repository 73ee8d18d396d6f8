#!/usr/bin/env bash
# Accuracy V (issue 51), the next design step's second test, begun 2026-12-07: does the convex mask pick the right
# surface at depth edges when its loss asks it to pick? The blend's L1 loss pushes a confidently wrong mask toward
# the right candidate only at the weight the right one has (its softmax saturates); the pick loss (fit --mask-pick,
# cade_cli/train/fit.py pick_loss: the truth's likelihood under the mask's mixture of its nine candidates) pushes it
# at the right candidate's share of the truth's likelihood. This run: --mask-pick 0.5 added to its control,
# runs/lever-2026-12-07-mask-control (the first campaign's last weights trained on with the campaign's recipe for
# 2,555 steps, the cosine from 5e-4, seed 53, validated every 500 steps). Why: docs/research/refinement.md,
# 2026-12-07, later. Judged by the queue (benchmarks/bakeoff_judge.sh), by region, against the control.
#   nohup nice runs/lever-2026-12-07-mask-pick/command.sh >> runs/lever-2026-12-07-mask-pick/stdout.log 2>&1 &
# resumes where it stopped. RUN_DIR trains it elsewhere (the GPU bake-off).
run=${RUN_DIR:-$(dirname "$0")}
data=${DATA:-../shared/data}
export DEVICE_FLAGS=${DEVICE_FLAGS:-"--device cpu --threads 2 --workers 0 --validate-every 500 --validate-rgb --data-dir $data"}
exec "$(dirname "$0")/../bakeoff.sh" "$run" --architecture cadenet-iterative --features2d 24 --width2d 32 --floating 0.5 \
  --init "$(dirname "$0")/../campaign-2026-12-07-extended/init.pt" --steps 2555 --lr 5e-4 --seed 53 --mask-pick 0.5 "$@"
