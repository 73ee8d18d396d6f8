#!/usr/bin/env bash
# The shipping check of one trained checkpoint, end to end (models/README.md; Accuracy IV's rule):
#
#   benchmarks/candidate_check.sh CHECKPOINT NAME OUT_DIR [SHIPPED]
#   benchmarks/candidate_check.sh CARD.json NAME OUT_DIR [SHIPPED]
#
# Given a model card (a path ending in .json, whose name is NAME) instead of a checkpoint, steps 1 and 2 are
# skipped: the card is judged as it is (a card that changes only the runtime, e.g. its edge filter).
# 1. exports CHECKPOINT (a `fit` run's last.pt) as OUT_DIR/NAME.onnx + NAME.json, with the runtime's
#    rank-SGBM refinement (REFINEMENT: another of `export --runtime-refinement`'s, e.g. rank-sgbm-two-scales;
#    EXPORT_FLAGS: more of `export`'s options, e.g. --mask-uncertainty for a cadenet-iterative checkpoint);
# 2. fits its own chooser on the real training scenes (train-real), as every shipped card's was
#    (32 hidden units, 4,000 steps, seed 0), and writes it into the card; CHOOSER_CANDIDATES fits it on
#    another refinement's matches (`train chooser --candidates`, e.g. rank-sgbm under a two-scale card);
#    CHOOSER_FLAGS replaces its "--hidden 32 --steps 4000", e.g. "--context --steps 3000" for the
#    convolutional chooser (cade_cli/matching/chooser_net.py, 2026-12-07);
# 3. runs `cade benchmark` on the five sets (Middlebury 2005 and 2014, FlyingThings3D, KITTI 2012 and
#    2015; protocols cs and rgb) and on the real cross-spectral check (msir-outdoor: VIS/NIR pairs of a
#    real camera array against pseudo ground truth) with the shipped model (SHIPPED, default cade-v13)
#    and the candidate in the same run, one JSON file per set in OUT_DIR;
# 4. applies the shipping rule (benchmarks/shipping_rule.py): exit 0 when the candidate ships. Its table and
#    verdict, then both models' rows per region (non-occluded, depth edges, occluded; reported, not judged),
#    also go to OUT_DIR/rule.md, under the command that made them.
#
# Run it from the repository root with ../shared/data beside it. HARDWARE names the machine in the
# card (default: this development VM). CHOOSER_SCENES (comma-separated) fits the chooser on those
# train-real scenes only: the ones the checkpoint's run held out (fit --real-hold-out). CARD_EXTRAS (a JSON
# object) is merged into the exported card after its chooser, for a tier that adds runtime stages to the
# network, e.g. the accurate tier's '{"test_time_augmentation": ["upscaled-x1.5"], "runtime_edge_filter":
# "weighted-median"}' (models/cade-v13-accurate-edges.json). Threads:
# OMP_NUM_THREADS as set by the caller; JOBS (default 1) runs that many scenes at a time in step 3
# (`cade benchmark --jobs`: the same scores, results in scene order). SETS (space-separated dataset names)
# narrows step 3 for a look at a checkpoint on the way (e.g. SETS=middlebury14): the verdict is then the rule's
# on those sets only, not a shipping decision.
set -euo pipefail
if [ $# -lt 3 ]; then
  echo "usage: benchmarks/candidate_check.sh CHECKPOINT NAME OUT_DIR [SHIPPED]" >&2
  exit 2
fi
checkpoint=$1 name=$2 out=$3 shipped=${4:-cade-v13}
data=../shared/data
cpu=$(sed -n 's/^model name[[:space:]]*: //p' /proc/cpuinfo 2>/dev/null | head -1)
hardware=${HARDWARE:-"$(nproc --all)-vCPU development VM (${cpu:-CPU unknown}), torch 2.13.0+cpu, no GPU lent"}
refinement=${REFINEMENT:-rank-sgbm} jobs=${JOBS:-1}
mkdir -p "$out"
card="$out/$name.json"
if [[ "$checkpoint" == *.json ]]; then
  card=$checkpoint
else
.venv/bin/python -m cade_cli.train export "$checkpoint" --onnx "$out/$name.onnx" \
  --runtime-refinement "$refinement" --hardware "$hardware" ${EXPORT_FLAGS:-}
chooser_options=()
[ -n "${CHOOSER_SCENES:-}" ] && chooser_options=(--scenes "$CHOOSER_SCENES")
[ -n "${CHOOSER_CANDIDATES:-}" ] && chooser_options+=(--candidates "$CHOOSER_CANDIDATES")
.venv/bin/python -m cade_cli.train chooser --real-dir "$data/train-real" --cache "$out/chooser-cache" \
  --model "$out/$name.json" ${CHOOSER_FLAGS:---hidden 32 --steps 4000} --seed 0 --write-card "${chooser_options[@]}"
if [ -n "${CARD_EXTRAS:-}" ]; then
  .venv/bin/python -c "import json, sys; p = sys.argv[1]; card = json.load(open(p)); card.update(json.loads(sys.argv[2]));
json.dump(card, open(p, 'w'), indent=2)" "$card" "$CARD_EXTRAS"
fi
fi
runs=()
for dataset in ${SETS:-middlebury05 middlebury14 flyingthings3d kitti2012 kitti2015 msir-outdoor}; do
  protocol=(--protocol cs,rgb)
  [ "$dataset" = msir-outdoor ] && protocol=()
  .venv/bin/cade benchmark --dataset "$dataset" --data-dir "$data" --methods cade --model "$shipped,$card" \
    "${protocol[@]}" --jobs "$jobs" --json "$out/$dataset.json" > "$out/$dataset.md"
  runs+=("$out/$dataset.json")
done
{
  echo "# \`$name\` ($checkpoint) against $shipped"
  echo
  echo "\`${SETS:+SETS='$SETS'} ${EXPORT_FLAGS:+EXPORT_FLAGS='$EXPORT_FLAGS'} REFINEMENT=$refinement CHOOSER_CANDIDATES=${CHOOSER_CANDIDATES:-} CHOOSER_SCENES=${CHOOSER_SCENES:-}" \
    "${CHOOSER_FLAGS:+CHOOSER_FLAGS='$CHOOSER_FLAGS'}" "${CARD_EXTRAS:+CARD_EXTRAS='$CARD_EXTRAS'}" \
    "OMP_NUM_THREADS=${OMP_NUM_THREADS:-} JOBS=$jobs benchmarks/candidate_check.sh $checkpoint $name $out $shipped\`" \
    "($(date -u +%Y-%m-%d), $hardware). Its last step," \
    "\`benchmarks/shipping_rule.py --shipped cade:$shipped --candidate cade:$name $out/*.json\`, printed:"
  echo
} > "$out/rule.md"
.venv/bin/python benchmarks/shipping_rule.py --shipped "cade:$shipped" --candidate "cade:$name" "${runs[@]}" \
  | tee -a "$out/rule.md"
