#!/bin/bash
# On the GPU machine: bash benchmarks/device/speed.sh TAG ARGS...: benchmarks.dmc_speed (ARGS) with Playground
# installed, its records into $OUT/TAG.json.
TAG=$1; shift
python -m pip install -q --no-deps .whl/*.whl .whl-pg/*.whl 2>&1 | grep -v WARN | tail -2
python -u -m benchmarks.dmc_speed "$@" --json $OUT/$TAG.json 2>&1 | grep -v "^WARNING" | tail -c 8000
