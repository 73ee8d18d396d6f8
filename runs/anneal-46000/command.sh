#!/usr/bin/env bash
# Accuracy III shipping check, 2026-11-27 (docs/research/campaigns.md): an annealed copy of the campaign's
# step-46,000 checkpoint (2,250 steps after it took --shadows 0.3; runs/campaign-2d/last.pt of commit
# ff7c425, copied to runs/anneal-46000/init.pt), by the anneal recipe (runs/anneal.sh) with the campaign's data, shadows
# included. Checked by:
#   benchmarks/candidate_check.sh runs/anneal-46000/last.pt c46000 /tmp/c46000
exec runs/anneal.sh runs/anneal-46000 --levels 192 --slice-channels 4 --shadows 0.3 "$@"
