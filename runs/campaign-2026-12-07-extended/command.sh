#!/usr/bin/env bash
# Accuracy V (issue 51) item 4, the campaign's longer schedule, begun 2026-12-07. The first campaign
# (runs/campaign-2026-12-06-iterative: cadenet-iterative f24 w32, the bake-off's recipe with --floating 0.5,
# 20,000 steps from scratch, the cosine over them) ended with its validation flat over its last 6,000 steps while
# the rate decayed, and as the accurate tier it did not pass the rule against cade-v13-accurate-edges
# (benchmarks/results/2026-12-07-campaign-ship-check/rule.md: Middlebury 2014 EPE worse by 7-9 %, the real VIS/NIR
# pairs better). The shipped network had 2.4x its steps. So: the same recipe from its last weights (init.pt, the
# finished run's weights only: `python -m cade_cli.train compact runs/campaign-2026-12-06-iterative/last.pt
# --out init.pt --weights-only`), a new cosine over 40,000 more steps from half the first peak (5e-4), and
# another seed (53) so that its batches are not the first run's again (docs/research/network-design.md,
# "2026-12-07: the campaign's end"); and --asymmetric 0.3, the lever judged the same day
# (docs/research/training-data.md, 2026-12-07). And --mask-evidence (its convex mask also sees the 1/4 correlation at
# its nine candidates), judged the same day against its control at equal steps (docs/research/refinement.md,
# 2026-12-07, later: the network alone's depth-edge errors lower on every set), with --init-partial: its new inputs
# start at zero, so at step 0 it computes what init.pt did.
#
#   nohup nice runs/campaign-2026-12-07-extended/command.sh >> runs/campaign-2026-12-07-extended/stdout.log 2>&1 &
# resumes where it stopped (from last.pt; init.pt is read at step 0 only); a lent GPU continues it
# (runs/gpu-campaign.sh, docs/gpu-recipe.md). DEVICE_FLAGS and RUN_DIR as in the first campaign's command.sh.
# Since step 16,750 (2026-12-07, 21:00 UTC) the CPU trains it through torch.compile with one process rendering
# the batches beside the step (--compile --workers 1): the same batches bit for bit, 0.54 s a step against 0.83
# (runs/step-speed.sh; docs/research/network-design.md, "the campaign's steps faster"). Its log's CPU column counts
# the training process only from then on.
here=$(dirname "$0")
run=${RUN_DIR:-$here}
data=${DATA:-../shared/data}
export DEVICE_FLAGS=${DEVICE_FLAGS:-"--device cpu --threads 2 --workers 1 --compile --validate-every 1000 --validate-rgb --data-dir $data"}
exec "$here/../bakeoff.sh" "$run" --architecture cadenet-iterative \
  --features2d 24 --width2d 32 --floating 0.5 --init "$here/init.pt" --steps 40000 --lr 5e-4 --seed 53 \
  --asymmetric 0.3 --mask-evidence --init-partial "$@"
