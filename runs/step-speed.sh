#!/usr/bin/env bash
# Wall seconds per training step of a live run, trained as its command.sh trains it, with fit options added:
#   runs/step-speed.sh RUN STEPS [FIT OPTIONS...]      e.g. runs/step-speed.sh campaign-2026-12-07-extended 150 --compile
# Copies the run's last.pt into a scratch folder, trains STEPS more steps there (--stop-after, no
# validation), and prints the seconds per step after the first 50 (which hold a compile's minutes and the first
# batches). The run itself is not touched. Pause any training first (kill -STOP), as for every speed figure.
set -euo pipefail
cd "$(dirname "$0")/.."
[ $# -ge 2 ] || { echo "usage: runs/step-speed.sh RUN STEPS [FIT OPTIONS...]" >&2; exit 2; }
run=runs/$1 steps=$2
shift 2
[ "$steps" -gt 50 ] || { echo "runs/step-speed.sh: STEPS must be more than 50" >&2; exit 2; }
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
cp "$run/last.pt" "$scratch/"
start=$(.venv/bin/python -c "import sys, torch; print(torch.load(sys.argv[1], weights_only=False)['step'])" "$scratch/last.pt")
export DEVICE_FLAGS=${DEVICE_FLAGS:-"--device cpu --threads 2 --workers 0 --validate-every 1000000000"}
RUN_DIR=$scratch "$run/command.sh" --stop-after $((start + steps)) "$@" > "$scratch/stdout.log" 2>&1 \
  || { tail -n 5 "$scratch/stdout.log" >&2; exit 1; }
.venv/bin/python - "$scratch/log.csv" "$start" "$@" <<'PY'
import csv, sys
rows = {int(r[0]): float(r[1]) for r in csv.reader(open(sys.argv[1])) if len(r) > 5 and r[5] == "train"}
first = int(sys.argv[2]) + 50
last = max(rows)
print(f"{(rows[last] - rows[first]) / (last - first):.3f} s a step over steps {first}..{last}"
      f" (fit options added: {' '.join(sys.argv[3:]) or 'none'})")
PY
