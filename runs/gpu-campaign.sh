#!/usr/bin/env bash
# A lent GPU's call for Accuracy V (issue 51 item 4; docs/gpu-recipe.md, "The next lent GPU"): it continues the
# chosen design's campaign, the campaign-* run that runs/LIVE names (CAMPAIGN, a folder under runs/ with its
# command.sh; RUN_DIR, where it trains, defaults to the same folder), from its checkpoint with the GPU's flags
# (bf16 autocast, 14 rendering workers, no Middlebury validation there) until DEADLINE_S, then tars the run folder
# into $OUT. A first try that fails before it checkpoints a new step is retried without --amp. When the campaign
# has reached its last step with more than 150 s left, the rest goes to the bake-off at equal steps
# (runs/gpu-bakeoff.sh). Afterwards, here: unpack $OUT/campaign.tar into runs/ (after stopping the CPU queue:
# docs/gpu-recipe.md), `.venv/bin/python -m cade_cli.train validate runs/<campaign>`, resume the queue.
#   make gpu-data      # here, first: .gpu-pack/data.tar
#   device run, carry [".gpu-pack", "runs/<the campaign>"], timeout_s 600:  DEADLINE_S=545 bash runs/gpu-campaign.sh 2>&1 | tee $OUT/log.txt
# Tried on the CPU with (2 steps past a scratch copy's checkpoint, then the bake-off's runs at 2 steps each; on
# 2026-12-07 with the longer schedule's folder, which holds only init.pt, and DEADLINE_S=140: 2 steps from init.pt;
# again the same day once it trains with --mask-evidence --init-partial, DEADLINE_S=200: the same):
#   cp -r runs/campaign-2026-12-06-iterative /tmp/try && CAMPAIGN=campaign-2026-12-06-iterative DEV="--device cpu --threads 2 --workers 1 --validate-every 100000" \
#     STEPS=2 PY=.venv/bin/python DATA_DIR=../shared/data OUT=/tmp/try-out RUN_DIR=/tmp/try DEADLINE_S=400 bash runs/gpu-campaign.sh
export PYTHONUNBUFFERED=1
T0=$(date +%s); DEADLINE=$((T0 + ${DEADLINE_S:-520}))
left() { echo $((DEADLINE - $(date +%s))); }
step_of() { ${PY:-python3} -c "import torch; print(torch.load('$1/last.pt', weights_only=False, map_location='cpu')['step'])" 2>/dev/null || echo 0; }
campaign=${CAMPAIGN:-$(grep -v '^#' runs/LIVE | grep -m1 '^campaign-')}
[ -x "runs/$campaign/command.sh" ] || { echo "no campaign in runs/LIVE (CAMPAIGN=runs/<name> names one)"; exit 1; }
run=${RUN_DIR:-runs/$campaign}
mkdir -p "${OUT:?OUT: where the run folder goes as a tar}"
if [ -z "$DATA_DIR" ]; then
  ${PY:-python3} -c 'import torch; print(torch.__version__, torch.cuda.get_device_name())'
  [ -d .gpu-data ] || ${PY:-python3} benchmarks/gpu_data.py unpack .gpu-pack/data.tar .gpu-data || exit 1
  echo "data ready at +$(( $(date +%s) - T0 )) s"
fi
device=${DEV:-"--device cuda --amp --threads 2 --workers 14 --validate-every 100000"}
train() {  # train DEVICE_FLAGS: the campaign's own command, cut by --time-budget to end before the deadline
  local budget=$(( $(left) - 30 ))
  [ $budget -lt 40 ] && { echo "no time left for $campaign"; return 1; }
  echo "$campaign -> $run at +$(( $(date +%s) - T0 )) s (from step $(step_of "$run"), budget $budget s)"
  RUN_DIR=$run DATA=${DATA_DIR:-.gpu-data} PYTHON=${PY:-python3} DEVICE_FLAGS="$1" \
    "runs/$campaign/command.sh" ${STEPS:+--steps $(( $(step_of "$run") + STEPS ))} --time-budget $budget 2>&1 \
    | grep -v "^step [0-9]*[1-9][05]0 " | tail -12
  return "${PIPESTATUS[0]}"
}
before=$(step_of "$run")
if ! train "$device" && [ "$(step_of "$run")" = "$before" ] && [[ $device == *--amp* ]]; then
  echo "failed before a checkpoint with --amp: retrying without"; train "${device/--amp/}"
fi
(cd "$(dirname "$run")" && tar cf "$OUT/campaign.tar" "$(basename "$run")")
echo "$campaign at step $(step_of "$run") at +$(( $(date +%s) - T0 )) s"
last=$(${PY:-python3} -c "import json; print(json.load(open('$run/config.json'))['steps'])")
if [ "$(step_of "$run")" -ge "$last" ] && [ "$(left)" -gt 150 ]; then  # the campaign is done: the bake-off's turn
  DEADLINE_S=$(left) bash runs/gpu-bakeoff.sh
fi
ls -la "$OUT"; echo "done at +$(( $(date +%s) - T0 )) s"
