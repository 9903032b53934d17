#!/bin/bash
# train.sh's trainings, in a process session of their own (so that they outlive the call that started them):
# every --run at once, each stopped (Ctrl-C: it saves at the end of its chunk) after T s; a run whose chunk has not
# ended GRACE s later gets a second Ctrl-C (it exits without saving that chunk; its last checkpoint stays), so the
# run directories (no train state) are always complete. /tmp/runs$TAG/ended marks the end.
set -u
python -u -m benchmarks.gym_training --parallel --no-judge --timeout "$T" --out /tmp/runs$TAG \
  --json /tmp/runs$TAG/records.json "$@" > /tmp/runs$TAG/log.txt 2>&1 &
trainings=$!
for _ in $(seq $((T + GRACE))); do kill -0 $trainings 2>/dev/null || break; sleep 1; done
if kill -0 $trainings 2>/dev/null; then
  echo "train.sh: still running $GRACE s after the Ctrl-C at $T s: a second Ctrl-C (the chunk in progress is not saved)"
  pkill -INT -f "benchmarks.cli train"; sleep 1; pkill -INT -f "benchmarks.cli train"
  wait $trainings
fi
touch /tmp/runs$TAG/ended
