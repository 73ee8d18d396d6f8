#!/usr/bin/env bash
# Accuracy IV shipping check of the campaign as the fast tier, 2026-11-28 (docs/research/campaigns.md): an annealed copy of
# runs/fast192-2d's step-48,750 checkpoint (copied to runs/anneal-fast192-48750/init.pt), by the anneal recipe
# (runs/anneal.sh) with --shadows 0.3 as the run trains. Checked against cade-v12 by:
#   REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm \
#     benchmarks/candidate_check.sh runs/anneal-fast192-48750/last.pt f48750 OUT cade-v12
# Logs only: init.pt (the campaign's step 48,750, between two committed checkpoints) and last.pt are not in the
# tree; the campaign's command resumed from its step-46,000 commit (bf68a04) reaches that step over the same batches.
exec runs/anneal.sh runs/anneal-fast192-48750 --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 --shadows 0.3 "$@"
