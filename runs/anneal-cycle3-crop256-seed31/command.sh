#!/usr/bin/env bash
# Accuracy IV, 2026-11-28 (docs/research/campaigns.md): runs/anneal-cycle3-crop256's anneal again with another seed (31: other
# batches), from the same init (runs/fast192-2d-cycle3/last.pt, copied to runs/anneal-cycle3-crop256-seed31/init.pt),
# at two threads alone on the CPU. It measures the anneal recipe's own spread on the one set that stopped
# anneal-cycle3-crop256 (driving RGB BMP3 +1.8 % against a 1.0 % tolerance); fixed before any of its figures existed
# as a candidate like any other under the rule:
#   REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm \
#     benchmarks/candidate_check.sh runs/anneal-cycle3-crop256-seed31/last.pt c3a256s31 OUT cade-v13
# Logs only: init.pt and last.pt are not in the tree.
exec runs/anneal.sh runs/anneal-cycle3-crop256-seed31 --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --height 256 --width 448 --seed 31 "$@"
