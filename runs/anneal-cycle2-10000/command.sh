#!/usr/bin/env bash
# Accuracy IV shipping check of the campaign's second cycle, 2026-11-28 (docs/research/campaigns.md): an annealed copy of
# runs/fast192-2d-cycle2's step-10,000 checkpoint (copied to runs/anneal-cycle2-10000/init.pt), by the anneal recipe
# (runs/anneal.sh) with --shadows 0.3 and the cycle's 256x448 crops, at two threads with the cycle stopped: the
# same recipe as runs/anneal-cycle2-5000. Checked against cade-v13 by:
#   REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm \
#     benchmarks/candidate_check.sh runs/anneal-cycle2-10000/last.pt a10000 OUT cade-v13
# Logs only: init.pt and last.pt are not in the tree; the cycle's command resumed from its last committed
# checkpoint reaches step 10,000 over the same batches.
exec runs/anneal.sh runs/anneal-cycle2-10000 --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --height 256 --width 448 "$@"
