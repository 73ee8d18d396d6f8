#!/usr/bin/env bash
# Accuracy III shipping check of the fast design, 2026-11-27 (docs/research/campaigns.md): an annealed copy of
# runs/fast192-2d's step-21,000 checkpoint (runs/fast192-2d/last.pt of commit 151e7f2,
# copied to runs/anneal-fast192-21000/init.pt), by the anneal recipe (runs/anneal.sh), unchanged. Checked by:
#   benchmarks/candidate_check.sh runs/anneal-fast192-21000/last.pt f21000 /tmp/f21000
exec runs/anneal.sh runs/anneal-fast192-21000 --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 "$@"
