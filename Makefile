# One command to set up and run the main job, one to set up and run the tests.
# Each creates .venv on first use (Python >= 3.11 as `python3`).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: train test test-slow bench clean

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e ".[test]"
	touch $@

train: $(BIN)/.installed  ## train DQN on the MJX CartPole: checkpoint + Rerun recording in runs/cartpole-mjx
	$(BIN)/mjxsuite train --env cartpole-mjx --out runs/cartpole-mjx --rerun runs/cartpole-mjx/train.rrd --overwrite

test: $(BIN)/.installed  ## the fast test suite (what CI runs)
	$(BIN)/python -m pytest -q

test-slow: $(BIN)/.installed  ## long training tests: 16 seeds to 50k steps on both backends
	$(BIN)/python -m pytest -q -m slow

bench: $(BIN)/.installed  ## env throughput and DQN speed figures
	$(BIN)/python -m pip install -q -e ".[bench]"
	$(BIN)/python -m envs.bench
	$(BIN)/python -m agents.bench
	$(BIN)/python -m agents.bench_logging

clean:
	rm -rf $(VENV) runs .pytest_cache
