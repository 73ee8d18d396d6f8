#!/usr/bin/env bash
# Accuracy V (issue 51): a second seed (52) of the bake-off's control design, queued 2026-11-29 after the four levers
# (runs/bakeoff-queue.txt). The four designs differed by a few per cent from one seed each; the control, the
# iterative design (which led) and peak are run again with SEED=52, everything else as
# runs/bakeoff-2026-11-28-control/command.sh (docs/research/network-design.md, "Design bake-off").
#
#   nohup nice runs/seed-2026-11-29-control-s52/command.sh >> runs/seed-2026-11-29-control-s52/stdout.log 2>&1 &
# resumes where it stopped.
export SEED=52
RUN_DIR=${RUN_DIR:-$(dirname "$0")} exec "$(dirname "$0")/../bakeoff-2026-11-28-control/command.sh" "$@"
