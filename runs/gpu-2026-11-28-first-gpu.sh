#!/usr/bin/env bash
# The first GPU call, Accuracy IV, 2026-11-28 (docs/gpu-recipe.md; docs/research/campaigns.md, 2026-11-28): the first GPU lent to this project,
# one H200 for 15 minutes. Run there as
#   device run, carry [".gpu-pack"], timeout_s 600:  DEADLINE_S=545 bash runs/gpu-2026-11-28-first-gpu.sh 2>&1 | tee $OUT/log.txt
# after `make gpu-data` here (the training data, packed losslessly into .gpu-pack/data.tar). It ran in 484 s:
# A (40 s of training), C to step 9,511 of 11,500 (its --time-budget), B (23 s); a second call resumed C to its end
# (runs/fast192-2d-cycle3/command.sh; 80 s). As run, the data were unpacked by an earlier copy of
# benchmarks/gpu_data.py's unpack in .gpu-pack; DEV, STEPS_A, MIN_C and PY let it be tried on the CPU first
# (DEV="--batch 4 --device cpu --threads 2 --workers 2 --validate-every 100000" STEPS_A=50 MIN_C=50 PY=.venv/bin/python).
# runs/fast192-2d-cycle2/last.pt (step 15,000) left the tree on 2026-11-28, a finished run's checkpoint; bring it
# back before running this:  git show 85fb266:runs/fast192-2d-cycle2/last.pt > runs/fast192-2d-cycle2/last.pt
export PYTHONUNBUFFERED=1
T0=$(date +%s); DEADLINE=$((T0 + ${DEADLINE_S:-520}))
left() { echo $((DEADLINE - $(date +%s))); }
python3 -c 'import torch; print(torch.__version__, torch.cuda.get_device_name())'
nproc
${PY:-python3} benchmarks/gpu_data.py unpack .gpu-pack/data.tar .gpu-data || exit 1
du -sh .gpu-data
echo "unpacked at +$(( $(date +%s) - T0 )) s"
DATA="--textures .gpu-data/textures --real-dir .gpu-data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 --ground 0.3 --shadows 0.3"
DESIGN="--architecture cadenet2d --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4"
DEV=${DEV:-"--batch 4 --device cuda --amp --threads 2 --workers 14 --validate-every 100000"}
fit() {  # fit NAME FLAGS...: train, retry without --amp if the first try fails before any checkpoint
  local name=$1; shift
  ${PY:-python3} -m cade_cli.train fit --out runs/$name $DESIGN $DATA $DEV "$@" 2>&1 | grep -v "^step [0-9]*[1-9]00 \|^step [0-9]*[1-9]50 " | tail -60
  local rc=${PIPESTATUS[0]}
  if [ $rc -ne 0 ] && [ ! -f runs/$name/last.pt ]; then
    echo "$name failed (rc $rc) with --amp: retrying without"; DEV="${DEV/--amp/}"
    ${PY:-python3} -m cade_cli.train fit --out runs/$name $DESIGN $DATA $DEV "$@" 2>&1 | tail -60
  fi
  tar cf $OUT/$name.tar --exclude init.pt -C runs $name
}
# A: the planned check's anneal (runs/anneal.sh's recipe: 500 steps, lr 5e-4, warm-up 50, seed 30; 256x448 crops)
mkdir -p runs/anneal-cycle2-15000 && cp runs/fast192-2d-cycle2/last.pt runs/anneal-cycle2-15000/init.pt
a0=$(date +%s)
fit anneal-cycle2-15000 --init runs/anneal-cycle2-15000/init.pt --steps ${STEPS_A:-500} --height 256 --width 448 --lr 5e-4 --warmup 50 --seed 30 --time-budget $(( $(left) - 30 ))
a1=$(date +%s)
tail -2 runs/anneal-cycle2-15000/log.csv
# C: cycle 3, sized from A's pace (192x320 steps cost about 0.6 of 256x448's; keep 100 s for B and copying)
rate=$(python3 -c "import csv; r=[x for x in csv.DictReader(open('runs/anneal-cycle2-15000/log.csv')) if x['set']=='train']; print(max(1.0, 450/max(1,int(r[-1]['elapsed_s'])-int(r[0]['elapsed_s']))*(int(r[-1]['step'])-int(r[0]['step']))/450))" 2>/dev/null || echo 5)
budget=$(( $(left) - 110 ))
steps=$(python3 -c "print(max(${MIN_C:-1000}, min(20000, int($rate*$budget/0.75/500)*500)))")
echo "A took $((a1-a0)) s; 256x448 pace $rate steps/s; cycle 3: $steps steps in $budget s"
if [ $budget -gt 120 ]; then
  fit fast192-2d-cycle3 --init runs/fast192-2d-cycle2/last.pt --steps $steps --height 192 --width 320 --lr 3e-4 --warmup 200 --seed 35 --time-budget $budget
  tail -3 runs/fast192-2d-cycle3/log.csv
fi
# B: the end annealed at 192x320 (the plan's further candidate)
if [ $(left) -gt 70 ]; then
  mkdir -p runs/anneal-cycle2-15000-crop192 && cp runs/fast192-2d-cycle2/last.pt runs/anneal-cycle2-15000-crop192/init.pt
  fit anneal-cycle2-15000-crop192 --init runs/anneal-cycle2-15000-crop192/init.pt --steps ${STEPS_A:-500} --height 192 --width 320 --lr 5e-4 --warmup 50 --seed 30 --time-budget $(( $(left) - 25 ))
fi
for d in $OUT/*.tar; do tar tf $d | grep -v /$ ; done
echo "done at +$(( $(date +%s) - T0 )) s"
