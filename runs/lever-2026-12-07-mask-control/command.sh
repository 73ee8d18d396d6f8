#!/usr/bin/env bash
# Accuracy V (issue 51), the next design step's test, begun 2026-12-07: does the convex mask pick the right
# surface at depth edges when it sees the matching evidence (runs/lever-2026-12-07-mask-evidence)? This is its
# control: the first campaign's last weights (runs/campaign-2026-12-07-extended/init.pt) trained on with the
# campaign's recipe for 2,555 steps (the bake-off's equal steps), the cosine over them from 5e-4, seed 53, no CPU
# budget, validated every 500 steps. The evidence run is the same with --mask-evidence (--init-partial: it starts
# computing what this starts from). Why: docs/research/refinement.md, 2026-12-07, later (at these weights an
# oracle over the mask's nine candidates takes Middlebury 2014 CS depth edges from 41.0 to 23.5 %, the mask's
# heaviest candidate 40.5 %). Judged by the queue (benchmarks/bakeoff_judge.sh), by region.
#   nohup nice runs/lever-2026-12-07-mask-control/command.sh >> runs/lever-2026-12-07-mask-control/stdout.log 2>&1 &
# resumes where it stopped. RUN_DIR trains it elsewhere (the GPU bake-off).
run=${RUN_DIR:-$(dirname "$0")}
data=${DATA:-../shared/data}
export DEVICE_FLAGS=${DEVICE_FLAGS:-"--device cpu --threads 2 --workers 0 --validate-every 500 --validate-rgb --data-dir $data"}
exec "$(dirname "$0")/../bakeoff.sh" "$run" --architecture cadenet-iterative --features2d 24 --width2d 32 --floating 0.5 \
  --init "$(dirname "$0")/../campaign-2026-12-07-extended/init.pt" --steps 2555 --lr 5e-4 --seed 53 "$@"
