#!/usr/bin/env bash
# Accuracy III shipping check, 2026-11-27 (docs/research/campaigns.md): an annealed copy of the campaign's
# step-34,000 checkpoint (runs/campaign-2d/last.pt of commit d018c86, copied to
# runs/anneal-34000/init.pt): 500 steps at lr 5e-4 after a 50-step warm-up, cosine to 5 %, seed 30,
# the campaign's data and crops (192x320): the recipe of runs/anneal-13250 (cade-v11), unchanged.
# The recipe is runs/anneal.sh's. Checked by:
#   benchmarks/candidate_check.sh runs/anneal-34000/last.pt c34000 /tmp/c34000
exec runs/anneal.sh runs/anneal-34000 --levels 192 --slice-channels 4 "$@"
