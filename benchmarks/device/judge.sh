#!/bin/bash
# Here: bash benchmarks/device/judge.sh DIR TAG: the runs of DIR/TAG.tgz (from train.sh) judged on their reference
# env, 10 episodes per seed, into /tmp/judge/TAG/TAG.judged.json.
set -eu
SRC=$1; TAG=$2; J=/tmp/judge/$TAG
rm -rf $J && mkdir -p $J && cat $SRC/$TAG.tgz* | tar xz -C $J  # train.sh's archive, whole or in parts
python3 - "$J" "$TAG" <<'PY'
import json, sys
J, TAG = sys.argv[1:]
p = f"{J}/runs{TAG}/records.json"
recs = json.load(open(p))
for r in recs:
    r["out"] = r["out"].replace(f"/tmp/runs{TAG}", f"{J}/runs{TAG}")
json.dump(recs, open(p, "w"), indent=2)
PY
cd "$(dirname "$0")/../.." && JAX_PLATFORMS=cpu "${PYTHON:-.venv/bin/python}" -m benchmarks.gym_training --judge $J/runs$TAG/records.json --episodes 10 --json $J/$TAG.judged.json 2>&1 | grep -v WARN
