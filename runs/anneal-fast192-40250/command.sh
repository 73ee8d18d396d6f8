#!/usr/bin/env bash
# Accuracy IV shipping check of the campaign as the fast tier, 2026-11-28 (docs/research/campaigns.md): an annealed copy of
# runs/fast192-2d's step-40,250 checkpoint (copied to runs/anneal-fast192-40250/init.pt), by the anneal recipe
# (runs/anneal.sh) with --shadows 0.3 as the run trains. Checked by:
#   benchmarks/candidate_check.sh runs/anneal-fast192-40250/last.pt f40250 /tmp/f40250
# Result: does not pass, driving RGB BMP3 +2.7 % (benchmarks/results/2026-11-28-campaign-step-40250/rule-f40250.md). Logs only: init.pt
# (the campaign's step 40,250, between two committed checkpoints) and last.pt are not in the tree; the campaign's
# command resumed from its step-38,750 commit (3652b88) reaches that step over the same batches.
exec runs/anneal.sh runs/anneal-fast192-40250 --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 --shadows 0.3 "$@"
