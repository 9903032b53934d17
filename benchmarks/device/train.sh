#!/bin/bash
# On the GPU machine: TAG=X T=450 bash benchmarks/device/train.sh --run "--env ... --agent td3 --impl warp --seeds 4" [--run ...]
# Trains every --run at once, stops each after T s, tars the run directories (no train state) into $OUT.
set -u
python -m pip install -q --no-deps .whl/*.whl 2>&1 | grep -v WARN | tail -2
mkdir -p /tmp/runs$TAG
python -u -m benchmarks.gym_training --parallel --no-judge --timeout "$T" --out /tmp/runs$TAG \
  --json /tmp/runs$TAG/records.json "$@" 2>&1 | tee /tmp/runs$TAG/log.txt | grep -v "^WARNING\|Warp\b.*initialized" | tail -c 6000
tar czf $OUT/$TAG.tgz --exclude=train_state.ckpt -C /tmp runs$TAG
ls -la $OUT
