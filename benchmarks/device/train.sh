#!/bin/bash
# On the GPU machine: TAG=X T=450 [GRACE=90] bash benchmarks/device/train.sh --run "--env ... --agent td3 --impl warp --seeds 4" [--run ...]
# Trains every --run at once and stops each after T s (Ctrl-C: it saves at the end of its chunk). A run whose
# chunk has not ended GRACE s later gets a second Ctrl-C (it exits without saving that chunk; its last
# checkpoint stays), so the run directories (no train state) always reach $OUT/X.tgz within the call's limit.
set -u
GRACE=${GRACE:-90}
python -m pip install -q --no-deps .whl/*.whl 2>&1 | grep -v WARN | tail -2
mkdir -p /tmp/runs$TAG
python -u -m benchmarks.gym_training --parallel --no-judge --timeout "$T" --out /tmp/runs$TAG \
  --json /tmp/runs$TAG/records.json "$@" > /tmp/runs$TAG/log.txt 2>&1 &
trainings=$!
for _ in $(seq $((T + GRACE))); do kill -0 $trainings 2>/dev/null || break; sleep 1; done
if kill -0 $trainings 2>/dev/null; then
  echo "train.sh: still running $GRACE s after the Ctrl-C at $T s: a second Ctrl-C (the chunk in progress is not saved)"
  pkill -INT -f "benchmarks.cli train"; sleep 1; pkill -INT -f "benchmarks.cli train"
  wait $trainings
fi
grep -v "^WARNING\|Warp\b.*initialized\|Delay kernel" /tmp/runs$TAG/log.txt | tail -c 6000
tar czf $OUT/$TAG.tgz --exclude=train_state.ckpt -C /tmp runs$TAG
# A returned file holds at most 16 MiB (pixel policies are ~12 MB a seed): larger archives come back in parts.
if [ "$(stat -c %s $OUT/$TAG.tgz)" -gt 15000000 ]; then split -b 15M $OUT/$TAG.tgz $OUT/$TAG.tgz.part. && rm $OUT/$TAG.tgz; fi
ls -la $OUT
