#!/usr/bin/env bash
# Accuracy III shipping check of the fast design, 2026-11-27 (docs/research/campaigns.md): an annealed copy of
# runs/fast192-2d's step-13,500 checkpoint (runs/fast192-2d/last.pt of commit bb2dc73,
# copied to runs/anneal-fast192-13500/init.pt), 500 steps as the campaign's anneals: lr 5e-4 after a
# 50-step warm-up, cosine to 5 %, seed 30, the fast run's data and crops (192x320).
# The recipe is runs/anneal.sh's. Checked by:
#   benchmarks/candidate_check.sh runs/anneal-fast192-13500/last.pt f13500 /tmp/f13500
exec runs/anneal.sh runs/anneal-fast192-13500 --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 "$@"
