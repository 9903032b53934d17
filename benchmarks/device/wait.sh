#!/bin/bash
# On the GPU machine: TAG=X WAIT=S bash benchmarks/device/wait.sh: waits up to S s for train.sh's runs X. Once they
# have ended, the log's end, and the run directories less their train state as $OUT/X.tgz (in 15 MB parts,
# X.tgz.part.*, when larger: a returned file holds at most 16 MiB); until then the log's end and how to go on.
set -u
for _ in $(seq "$WAIT"); do [ -e /tmp/runs$TAG/ended ] && break; sleep 1; done
cat /tmp/runs$TAG/watch.txt 2>/dev/null
grep -v "^WARNING\|Warp\b.*initialized\|Delay kernel" /tmp/runs$TAG/log.txt | tail -c 6000
if [ ! -e /tmp/runs$TAG/ended ]; then
  echo; echo "wait.sh: the runs $TAG go on; call TAG=$TAG WAIT=.. bash benchmarks/device/wait.sh again within the machine's idle release"
  exit 0
fi
tar czf $OUT/$TAG.tgz --exclude=train_state.ckpt -C /tmp runs$TAG
if [ "$(stat -c %s $OUT/$TAG.tgz)" -gt 15000000 ]; then split -b 15M $OUT/$TAG.tgz $OUT/$TAG.tgz.part. && rm $OUT/$TAG.tgz; fi
ls -la $OUT
