#!/usr/bin/env bash
# Accuracy IV, the campaign's second cycle (docs/research/campaigns.md, 2026-11-28). runs/fast192-2d finished its cosine at
# step 60,000 with its Middlebury validation flat since about step 43,000, and through the CLI its end ties with
# cade-v13 (its step 48,750 annealed): c60000 and c60000 annealed (runs/anneal-fast192-60000) each fail the rule by a
# hair, one Middlebury mean lower and the other not (benchmarks/results/2026-11-28-campaign-end/). More steps of the same recipe
# buy nothing measurable, so the second cycle changes the one thing with a weak positive through the CLI in
# Accuracy III (2026-11-27: runs/anneal-20000-crop256, runs/anneal-23000-crop256): 256x448 crops instead of
# 192x320 (1.87x the pixels; more of Middlebury's wide disparities inside a crop), as a warm restart from
# fast192-2d's last checkpoint (runs/fast192-2d/last.pt, step 60,000; not in the tree, as a finished run's: the
# campaign's command resumed from its step-52,500 commit c4de7a4 reaches it over the same batches), the same
# design and data, a new seed (34: new batches), lr 3e-4 after a 200-step warm-up, cosine to 5 % at 15,000 steps.
# Resume with the same command (it continues from runs/fast192-2d-cycle2/last.pt; the --init is read only at
# step 0). That checkpoint (step 15,000, the end) left the tree on 2026-11-28 (runs/fast192-2d-cycle3 --inits it):
#   git show 85fb266:runs/fast192-2d-cycle2/last.pt > runs/fast192-2d-cycle2/last.pt
# Beside other jobs on this 2-core machine: OMP_NUM_THREADS=1 runs/fast192-2d-cycle2/command.sh --threads 1.
exec nice -n 10 .venv/bin/python -m cade_cli.train fit --out runs/fast192-2d-cycle2 --architecture cadenet2d \
  --init runs/fast192-2d/last.pt \
  --levels 192 --features2d 16 --width2d 32 --half-channels 8 --slice-channels 4 \
  --textures ../shared/data/textures --data-dir ../shared/data \
  --real-dir ../shared/data/train-real --real-share 0.4 --network-input cade-floor --misaligned 0.3 --scene-range 0.25 \
  --ground 0.3 --shadows 0.3 --steps 15000 --batch 4 --height 256 --width 448 --lr 3e-4 --warmup 200 --seed 34 \
  --device cpu --threads 2 --workers 0 --validate-every 1000 --validate-rgb "$@"
