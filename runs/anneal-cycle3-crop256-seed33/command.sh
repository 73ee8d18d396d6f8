#!/usr/bin/env bash
# Accuracy IV, 2026-11-28 (docs/research/campaigns.md): runs/anneal-cycle3-crop256's anneal again with seed 33, from the same init
# (runs/fast192-2d-cycle3/last.pt, copied to runs/anneal-cycle3-crop256-seed33/init.pt), at two threads alone on the
# CPU: seeds 30 and 31 gave Middlebury means 2 % apart, as much as the candidates' effects; seeds 32 and 33 make the
# anneal's seed spread a four-draw measure (for the next rule's noise), decided after those two and before any
# figure of these. Checked like the others, and a candidate under the rule like any other:
#   REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm \
#     benchmarks/candidate_check.sh runs/anneal-cycle3-crop256-seed33/last.pt c3a256s33 OUT cade-v13
# Logs only: init.pt and last.pt are not in the tree.
exec runs/anneal.sh runs/anneal-cycle3-crop256-seed33 --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --height 256 --width 448 --seed 33 "$@"
