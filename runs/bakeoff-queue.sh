#!/usr/bin/env bash
# The bake-off's queue (Accuracy V, begun 2026-11-28): trains the runs named in runs/bakeoff-queue.txt one after
# the other, each by its own command.sh (which stops itself when its CPU budget is spent or its steps are done),
# skipping those whose stdout.log (or stdout.log.gz) says so ("budget spent", or fit's "finished: "), then judges each spent run once
# (benchmarks/bakeoff_judge.sh, one thread, into benchmarks/results/2026-11-28-bakeoff/RUN), after the run's own
# shipping check where it has one (runs/RUN/ship-check.sh, once: its exit status goes to runs/RUN/ship-check.exit,
# its output to runs/RUN/ship-check.log). It re-reads the list
# after each run, waits for a listed run's command.sh to appear and for a run some other process is training, and
# ends when every listed run is spent and judged. One run at a time: the VM has 2 vCPUs.
#   nohup nice runs/bakeoff-queue.sh >> runs/bakeoff-queue.log 2>&1 &
cd "$(dirname "$0")/.."
judged=benchmarks/results/2026-11-28-bakeoff
while true; do
  next="" waiting=0
  for run in $(grep -v '^#' runs/bakeoff-queue.txt); do
    while pgrep -f "fit --out runs/$run " > /dev/null; do sleep 60; done  # trained by another process
    # a finished run's stdout.log may be gzipped to keep the tree small: read either
    if cat "runs/$run/stdout.log" 2>/dev/null | grep -qE "budget spent|^finished: " \
      || zcat "runs/$run/stdout.log.gz" 2>/dev/null | grep -qE "budget spent|^finished: "; then
      if [ -x "runs/$run/ship-check.sh" ] && [ ! -f "runs/$run/ship-check.exit" ]; then
        echo "$(date -u +%FT%TZ) shipping check of $run"
        "runs/$run/ship-check.sh" >> "runs/$run/ship-check.log" 2>&1
        echo $? > "runs/$run/ship-check.exit"  # 0: the candidate passes the rule
      fi
      [ -f "$judged/$run/kitti2015.json.gz" ] || [ -f "$judged/$run/FAILED" ] && continue
      echo "$(date -u +%FT%TZ) judging $run"
      OMP_NUM_THREADS=1 benchmarks/bakeoff_judge.sh "runs/$run" "$judged/$run" \
        || { echo "judging $run failed"; touch "$judged/$run/FAILED"; }
      continue
    fi
    if [ -x "runs/$run/command.sh" ]; then next=$run; break; fi
    waiting=1
  done
  if [ -z "$next" ]; then
    [ "$waiting" = 0 ] && { echo "$(date -u +%FT%TZ) every listed run is spent and judged"; exit 0; }
    sleep 60; continue
  fi
  echo "$(date -u +%FT%TZ) $next"
  OMP_NUM_THREADS=2 "runs/$next/command.sh" >> "runs/$next/stdout.log" 2>&1 || { echo "$next failed"; sleep 60; }
done
