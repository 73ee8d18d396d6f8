#!/usr/bin/env bash
# Accuracy III shipping check of the fast design, 2026-11-27 (docs/research/campaigns.md): an annealed copy of
# runs/fast192-2d's step-29,750 checkpoint (runs/fast192-2d/last.pt of commit 5e188b7,
# copied to runs/anneal-fast192-29750/init.pt), by the anneal recipe (runs/anneal.sh) with --shadows 0.3 as
# the run has trained with since step 23,500. Checked by:
#   benchmarks/candidate_check.sh runs/anneal-fast192-29750/last.pt f29750 /tmp/f29750
exec runs/anneal.sh runs/anneal-fast192-29750 --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 --shadows 0.3 "$@"
