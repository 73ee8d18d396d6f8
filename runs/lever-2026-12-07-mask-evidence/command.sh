#!/usr/bin/env bash
# Accuracy V (issue 51), the next design step's test, begun 2026-12-07: does the convex mask pick the right
# surface at depth edges when it sees the matching evidence? This run: --mask-evidence (the mask also sees the 1/4
# correlation at each of its nine candidates; cade_cli/train/net_iterative.py), --init-partial (its new inputs
# start at zero: it starts computing what its control starts from). Its control, runs/lever-2026-12-07-mask-control,
# is the rest of it: the first campaign's last weights (runs/campaign-2026-12-07-extended/init.pt) trained on with
# the campaign's recipe for 2,555 steps, the cosine over them from 5e-4, seed 53, no CPU budget, validated every
# 500 steps. Why: docs/research/refinement.md, 2026-12-07, later. Judged by the queue (benchmarks/bakeoff_judge.sh),
# by region, against the control.
#   nohup nice runs/lever-2026-12-07-mask-evidence/command.sh >> runs/lever-2026-12-07-mask-evidence/stdout.log 2>&1 &
# resumes where it stopped. RUN_DIR trains it elsewhere (the GPU bake-off).
run=${RUN_DIR:-$(dirname "$0")}
data=${DATA:-../shared/data}
export DEVICE_FLAGS=${DEVICE_FLAGS:-"--device cpu --threads 2 --workers 0 --validate-every 500 --validate-rgb --data-dir $data"}
exec "$(dirname "$0")/../bakeoff.sh" "$run" --architecture cadenet-iterative --features2d 24 --width2d 32 --floating 0.5 \
  --init "$(dirname "$0")/../campaign-2026-12-07-extended/init.pt" --steps 2555 --lr 5e-4 --seed 53 --mask-evidence --init-partial "$@"
