# One command to set up and run the main job, one to set up and run the tests.
# Each creates .venv on first use (Python >= 3.11 as `python3`).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: train test test-slow test-heavy bench clean

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $@

train: $(BIN)/.installed  ## train DQN on the MJX CartPole: checkpoint + Rerun recording in runs/cartpole-mjx
	$(BIN)/mjxsuite train --env cartpole-mjx --out runs/cartpole-mjx --rerun runs/cartpole-mjx/train.rrd --overwrite

test: $(BIN)/.installed  ## the fast test suite (what CI runs)
	$(BIN)/python -m pytest -q -n 2 --dist loadfile  # two workers, each test file on one (its module fixtures built once); at most 5 minutes on 2 cores

test-slow: $(BIN)/.installed  ## long tests: training to solve on every backend, multi-device and two-process runs, pip install, benchmark scripts
	$(BIN)/python -m pytest -q -m "slow and not heavy" -n 2 --dist loadfile --durations=30  # two workers, each test file on one (its compiled programs shared); the 30 longest listed

test-heavy: $(BIN)/.installed  ## the largest models' proofs (humanoid, quadruped, ...) and the lifecycle's repeats per agent: out of CI, run when a task's physics or an agent changes
	$(BIN)/python -m pytest -q -m heavy -n 2 --dist loadfile --durations=30

# `make bench BENCH_TAG=gpu` on a GPU machine
BENCH_TAG ?= cpu

bench: $(BIN)/.installed  ## every benchmark figure of docs/results.md -> docs/bench-$(BENCH_TAG).json, docs/throughput-$(BENCH_TAG).png
	$(BIN)/python -m pip install -q -e ".[bench]"
	$(BIN)/python -m pip install -q --no-deps gymnax==1.0.1 playground==0.2.0
	$(BIN)/mjxsuite bench --json docs/bench-$(BENCH_TAG).json
	$(BIN)/mjxsuite bench --table docs/bench-$(BENCH_TAG).json
	$(BIN)/mjxsuite bench --plot docs/bench-$(BENCH_TAG).json --out docs/throughput-$(BENCH_TAG).png

clean:
	rm -rf $(VENV) runs .pytest_cache
