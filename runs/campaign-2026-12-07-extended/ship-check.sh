#!/usr/bin/env bash
# The extended campaign's shipping check (issue 51 item 5), run once by runs/bakeoff-queue.sh when the campaign is spent,
# before its bake-off judge: the last checkpoint exported as the accurate tier ships (rank-sgbm-two-scales, its own
# chooser fitted on rank-sgbm's matches, the 1.5x second pass and the edge filter of
# models/cade-v13-accurate-context.json) and judged by the shipping rule against the shipped accurate tier in the
# same runs, one thread (the CPU may be shared: scores are exact, times are not). The verdict is the last lines of
# benchmarks/results/campaign-2026-12-07-extended-ship-check/rule.md; speed (the tier's 3 s/MP) is measured apart, on a quiet
# CPU, with benchmarks/speed.py. JOBS=2: two scenes at a time, one thread each (the same scores). EXPORT_FLAGS
# --mask-uncertainty: the exported uncertainty carries the convex mask's doubt, which the chooser reads (2026-12-07,
# docs/research/refinement.md, "the mask's doubt for the chooser"). CHOOSER_FLAGS: its chooser is the convolutional one, as the
# shipped accurate tier's since 2026-12-07 (docs/research/refinement.md, "a chooser that sees around the pixel"), fitted on
# 162 rendered pairs too, as the tier's since that evening ("rendered pairs for the chooser"), judged against that tier,
# cade-v13-accurate-synthetic.
cd "$(dirname "$0")/../.."
REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm EXPORT_FLAGS=--mask-uncertainty CHOOSER_FLAGS="--context --steps 3000 --synthetic 162 --textures ../shared/data/textures" \
CARD_EXTRAS='{"test_time_augmentation": ["upscaled-x1.5"], "runtime_edge_filter": "weighted-median"}' \
JOBS=2 OMP_NUM_THREADS=1 exec benchmarks/candidate_check.sh runs/campaign-2026-12-07-extended/last.pt \
  cade-v14-accurate benchmarks/results/campaign-2026-12-07-extended-ship-check cade-v13-accurate-synthetic
