#!/usr/bin/env bash
# Accuracy IV shipping check of the campaign as the fast tier, 2026-11-28 (docs/research/campaigns.md): an annealed copy of
# runs/fast192-2d's step-60,000 checkpoint (copied to runs/anneal-fast192-60000/init.pt), by the anneal recipe
# (runs/anneal.sh) with --shadows 0.3 as the run trains. Checked against cade-v13 (beside the check of step 60,000 itself, c60000) by:
#   REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm \
#     benchmarks/candidate_check.sh runs/anneal-fast192-60000/last.pt f60000 OUT cade-v13
# Logs only: init.pt (the campaign's last checkpoint, step 60,000) and last.pt are not in the tree; the campaign's
# command resumed from its step-52,500 commit (c4de7a4) reaches that step over the same batches.
exec runs/anneal.sh runs/anneal-fast192-60000 --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 --shadows 0.3 "$@"
