#!/usr/bin/env bash
# Accuracy III shipping check, 2026-11-27 (docs/research/campaigns.md): an annealed copy of the campaign's
# step-42,000 checkpoint (runs/campaign-2d/last.pt of commit 151e7f2, copied to
# runs/anneal-42000/init.pt), by the anneal recipe (runs/anneal.sh), unchanged. Also the control of
# runs/lever-shadows. Checked by:
#   benchmarks/candidate_check.sh runs/anneal-42000/last.pt c42000 /tmp/c42000
exec runs/anneal.sh runs/anneal-42000 --levels 192 --slice-channels 4 "$@"
