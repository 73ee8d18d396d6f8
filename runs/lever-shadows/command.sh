#!/usr/bin/env bash
# Accuracy III lever ablation, 2026-11-27 (docs/research/training-data.md): cast shadows on 30 % of the rendered backgrounds and
# grounds (--shadows 0.3, cade_cli.train.scenes.cast_shadow), 500 steps from the campaign's step-42,000
# checkpoint (runs/campaign-2d/last.pt of commit 151e7f2, copied to
# runs/lever-shadows/init.pt) by the anneal recipe (runs/anneal.sh). Its control is runs/anneal-42000:
# the same recipe from the same checkpoint without the lever.
exec runs/anneal.sh runs/lever-shadows --levels 192 --slice-channels 4 --shadows 0.3 "$@"
