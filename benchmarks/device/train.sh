#!/bin/bash
# On the GPU machine: TAG=X T=450 [GRACE=90] [WAIT=S] bash benchmarks/device/train.sh --run "--env ... --agent td3 --impl warp --seeds 4" [--run ...]
# Starts every --run at once (`watch.sh`: each stopped with Ctrl-C after T s, and again GRACE s later), then waits
# for them (`wait.sh`) WAIT s, T + GRACE + 60 by default, so the run directories reach $OUT/X.tgz within the call. The
# trainings run in a process session of their own: a run longer than a call's 10 minutes sets WAIT under them and
# goes on in the next calls, `TAG=X WAIT=S bash benchmarks/device/wait.sh`, each within the machine's idle release.
set -u
export TAG T GRACE=${GRACE:-90}
WHEELS=${WHEELS:-.whl}  # the wheels the GPU image lacks (README.md here)
if [ -d "$WHEELS" ]; then python -m pip install -q --no-deps "$WHEELS"/*.whl 2>&1 | grep -v WARN | tail -2; fi
mkdir -p /tmp/runs$TAG && rm -f /tmp/runs$TAG/ended
setsid bash "$(dirname "$0")/watch.sh" "$@" > /tmp/runs$TAG/watch.txt 2>&1 < /dev/null &
WAIT=${WAIT:-$((T + GRACE + 60))} bash "$(dirname "$0")/wait.sh"
