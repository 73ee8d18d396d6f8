#!/usr/bin/env bash
# Accuracy V's bake-off judge (issue 51 item 2; docs/research/network-design.md, "Design bake-off"): one run's
# last checkpoint exported as it would ship (rank-sgbm-two-scales, no chooser: the designs, not the chooser, are
# compared) and scored through the CLI on the sets the issue names, every record by region (all, non-occluded,
# depth edges, occluded; docs/accuracy-by-region.md), both as the network alone (cade-network) and as the
# whole matcher (cade):
#
#   benchmarks/bakeoff_judge.sh RUN_DIR OUT_DIR        # e.g. runs/bakeoff-2026-11-28-control benchmarks/results/...
#
# Sets: Middlebury 2014 Q and 2005 (cs), msir-outdoor (the real VIS/NIR array), KITTI 2012 and 2015 (the driving
# set, cs). SETS (space-separated dataset names) and SCENES (comma-separated, one dataset) narrow it for a try.
# Scores are deterministic for a given thread count (OMP_NUM_THREADS, as set by the caller); the CPU may be shared
# with training; OUT_DIR keeps the card and one compact gzipped JSON per set. Speed is not measured here: benchmarks/design_speed.py --bakeoff on a quiet CPU. The exported
# ONNX stays out of git (.gitignore); its card (NAME.json, with its sha256) is kept with the scores.
set -euo pipefail
if [ $# -ne 2 ]; then
  echo "usage: benchmarks/bakeoff_judge.sh RUN_DIR OUT_DIR" >&2
  exit 2
fi
run=$1 out=$2 name=$(basename "$1")
data=${DATA:-../shared/data}
[ -f "$run/last.pt" ] || { echo "bakeoff_judge: no $run/last.pt" >&2; exit 2; }
mkdir -p "$out"
.venv/bin/python -m cade_cli.train export "$run/last.pt" --onnx "$out/$name.onnx" \
  --runtime-refinement rank-sgbm-two-scales --hardware "${HARDWARE:-2-vCPU development VM (AMD EPYC), no GPU}"
scenes=()
[ -n "${SCENES:-}" ] && scenes=(--scenes "$SCENES")
for set in ${SETS:-middlebury14 middlebury05 msir-outdoor kitti2012 kitti2015}; do
  protocol=(--protocol cs)
  [ "$set" = msir-outdoor ] && protocol=()
  .venv/bin/cade benchmark --dataset "$set" --data-dir "$data" --methods cade-network,cade --model "$out/$name.json" \
    "${protocol[@]}" "${scenes[@]}" --json "$out/$set.json" > "$out/$set.log" 2>&1 \
    || { echo "bakeoff_judge: $set failed, see $out/$set.log" >&2; exit 1; }
  # kept compact and gzipped, and only the JSON (benchmarks/bakeoff_table.py renders it): the runs stay small in git
  .venv/bin/python -c "import gzip, json, sys; p = sys.argv[1]; d = json.load(open(p)); gzip.open(p + '.gz', 'wt').write(json.dumps(d, separators=(',', ':')))" \
    "$out/$set.json"
  rm "$out/$set.json" "$out/$set.log"
  echo "$set: $out/$set.json.gz"
done
