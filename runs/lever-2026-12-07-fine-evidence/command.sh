#!/usr/bin/env bash
# Accuracy V (issue 51), the mask's next evidence, begun 2026-12-07: does the convex mask pick the right surface at
# depth edges more often when it also sees, inside its cell, which 1/2 pixels match which candidate? This run:
# runs/lever-2026-12-07-mask-evidence's recipe plus --fine-evidence (for each of the nine candidates and each 1/2
# pixel of the cell, the cosine of the two views' 1/2 features at that candidate; cade_cli/train/net_iterative.py
# fine_evidence_of), --init-partial (its new inputs start at zero). Its control is that run: the first campaign's
# last weights (runs/campaign-2026-12-07-extended/init.pt) trained on for 2,555 steps with the campaign's recipe
# and the mask's 1/4 evidence, the cosine over them from 5e-4, seed 53, validated every 500 steps. Why:
# docs/research/refinement.md, "the mask's levers". Judged by the queue (benchmarks/bakeoff_judge.sh), by region.
#   nohup nice runs/lever-2026-12-07-fine-evidence/command.sh >> runs/lever-2026-12-07-fine-evidence/stdout.log 2>&1 &
# resumes where it stopped. RUN_DIR trains it elsewhere (the GPU bake-off).
run=${RUN_DIR:-$(dirname "$0")}
data=${DATA:-../shared/data}
export DEVICE_FLAGS=${DEVICE_FLAGS:-"--device cpu --threads 2 --workers 0 --validate-every 500 --validate-rgb --data-dir $data"}
exec "$(dirname "$0")/../bakeoff.sh" "$run" --architecture cadenet-iterative --features2d 24 --width2d 32 --floating 0.5 \
  --init "$(dirname "$0")/../campaign-2026-12-07-extended/init.pt" --steps 2555 --lr 5e-4 --seed 53 --mask-evidence \
  --fine-evidence --init-partial "$@"
