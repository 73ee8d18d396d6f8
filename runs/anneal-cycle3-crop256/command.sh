#!/usr/bin/env bash
# Accuracy IV, 2026-11-28 (docs/research/campaigns.md): the third cycle's end (runs/fast192-2d-cycle3/last.pt, step 11,500, trained
# on the lent H200 at 192x320 crops; copied to runs/anneal-cycle3-crop256/init.pt) annealed by the anneal recipe
# (runs/anneal.sh) with --shadows 0.3 and 256x448 crops, at two threads alone on the CPU: the small crops' cycle (best on
# the real cross-spectral check, level on Middlebury) finished on the large crops (better on Middlebury 2014 in cycle 2).
# Checked against cade-v13 by:
#   REFINEMENT=rank-sgbm-two-scales CHOOSER_CANDIDATES=rank-sgbm \
#     benchmarks/candidate_check.sh runs/anneal-cycle3-crop256/last.pt c3a256 OUT cade-v13
# Logs only: init.pt and last.pt are not in the tree.
exec runs/anneal.sh runs/anneal-cycle3-crop256 --levels 192 --features2d 16 --width2d 32 --half-channels 8 \
  --slice-channels 4 --shadows 0.3 --height 256 --width 448 "$@"
