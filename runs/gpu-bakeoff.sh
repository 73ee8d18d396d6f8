#!/usr/bin/env bash
# Accuracy V's bake-off on a lent GPU (issue 51 item 4; docs/gpu-recipe.md): the same designs and levers as the CPU
# bake-off (runs/bakeoff-queue.txt, each run's own command.sh), but at EQUAL STEPS (STEPS each, default 2,500,
# the cosine over them), batch 4, 192x320 crops, 14 rendering workers, bf16 autocast, into runs/gpu-bakeoff-<name>
# (RUN_DIR), one after the other in the queue's order, skipping a run whose last.pt has reached STEPS. Each run
# is cut by --time-budget so that the call ends by DEADLINE_S; the next call resumes where it stopped. After a
# call, here: unpack $OUT/gpu-bakeoff.tar into runs/, then `.venv/bin/python -m cade_cli.train validate runs/gpu-bakeoff-<name>`.
#   make gpu-data      # here, first: .gpu-pack/data.tar
#   device run, carry [".gpu-pack"], timeout_s 600:  DEADLINE_S=545 bash runs/gpu-bakeoff.sh 2>&1 | tee $OUT/log.txt
# To resume a later call, carry the runs/gpu-bakeoff-* folders too. Tried on the CPU first with:
#   DEV="--device cpu --threads 2 --workers 1 --validate-every 100000" STEPS=3 PY=.venv/bin/python DATA_DIR=../shared/data \
#     OUT=/tmp/gpu-bakeoff-out DEADLINE_S=300 bash runs/gpu-bakeoff.sh
export PYTHONUNBUFFERED=1
T0=$(date +%s); DEADLINE=$((T0 + ${DEADLINE_S:-520}))
left() { echo $((DEADLINE - $(date +%s))); }
steps=${STEPS:-2500}
mkdir -p "${OUT:?OUT: where the run folders go as tars}"
if [ -z "$DATA_DIR" ]; then
  ${PY:-python3} -c 'import torch; print(torch.__version__, torch.cuda.get_device_name())'
  [ -d .gpu-data ] || ${PY:-python3} benchmarks/gpu_data.py unpack .gpu-pack/data.tar .gpu-data || exit 1
  echo "data ready at +$(( $(date +%s) - T0 )) s"
fi
for name in $(grep -v '^#' runs/bakeoff-queue.txt | grep -v '^campaign-'); do  # a campaign: runs/gpu-campaign.sh
  run=runs/gpu-bakeoff-${name#bakeoff-}
  done_steps=$(${PY:-python3} -c "import torch,sys; print(torch.load('$run/last.pt', weights_only=False, map_location='cpu')['step'])" 2>/dev/null || echo 0)
  [ "$done_steps" -ge "$steps" ] && continue
  budget=$(( $(left) - 25 ))
  [ $budget -lt 40 ] && { echo "no time left for $name"; break; }
  echo "$name -> $run at +$(( $(date +%s) - T0 )) s (from step $done_steps, budget $budget s)"
  RUN_DIR=$run DATA=${DATA_DIR:-.gpu-data} PYTHON=${PY:-python3} \
    DEVICE_FLAGS=${DEV:-"--device cuda --amp --threads 2 --workers 14 --validate-every 100000"} \
    "runs/$name/command.sh" --steps $steps --time-budget $budget 2>&1 | grep -v "^step [0-9]*[1-9][05]0 " | tail -8
  (cd runs && tar cf "$OUT/gpu-bakeoff.tar" gpu-bakeoff-*)  # one file back however many runs (a call returns few)
done
ls -la "$OUT"; echo "done at +$(( $(date +%s) - T0 )) s"
