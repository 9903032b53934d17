"""The run lifecycle's judge budget (`agents.run_steps.JudgeClock`): which chunks end with the
greedy judge, by the clock by default or every N chunks when pinned, and that a resumed run keeps
its run's cadence."""

import json
import threading
import time

import jax
import numpy as np
import pytest

from agents import DQNConfig, run_steps, train_run

SMALL = DQNConfig(total_steps=400, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                  eval_episodes=4, hidden=(16,))


def test_the_clock_judges_within_its_budget_and_always_the_last_chunk():
    clock = run_steps.JudgeClock(None, last_chunk=9, budget=0.05)
    assert clock.due(0, run_s=0.0)  # nothing measured yet: judge, to measure
    clock.judged(0.1)
    assert not clock.due(1, run_s=1.0)  # 0.1 + 0.1 > 5% of 1.1 s
    assert clock.due(1, run_s=3.9)  # 0.2 <= 5% of 4.0 s
    clock.judged(0.1)
    assert not clock.due(2, run_s=4.1) and clock.due(9, run_s=4.1)  # the last chunk is always judged
    assert clock.judges == 2 and clock.judge_s == pytest.approx(0.2)


def test_a_pinned_cadence_judges_the_same_chunks_whatever_the_clock():
    clock = run_steps.JudgeClock(3, last_chunk=7)
    assert [i for i in range(8) if clock.due(i, run_s=0.0)] == [2, 5, 7]
    with pytest.raises(ValueError, match="judge_every"):
        run_steps.JudgeClock(0, last_chunk=3)


def _judged_chunks(out):
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert all("env_steps" in r for r in records)  # every chunk says where the run stands
    return [r["chunk"] for r in records if "eval_return" in r]


@pytest.mark.parametrize("budget, judged", [(0.0, [0, 3]), (1.0, [0, 1, 2, 3])])
def test_the_budget_decides_which_chunks_a_run_judges(tmp_path, monkeypatch, budget, judged):
    """Budget 0: only the first chunk (the measurement) and the last; a budget of the whole run:
    every chunk. The training itself is the same either way: only the judged chunks differ."""
    monkeypatch.setattr(run_steps, "JUDGE_BUDGET", budget)
    result = train_run("cartpole", SMALL, out_dir=tmp_path, progress=False)
    assert _judged_chunks(tmp_path) == judged and result.judges == len(judged)
    summary = json.loads((tmp_path / "eval.json").read_text())
    assert summary["judged_chunks"] == len(judged) and summary["chunks"] == SMALL.num_chunks
    assert summary["wall_parts_s"]["judge"] > 0
    assert sum(summary["wall_parts_s"].values()) == pytest.approx(summary["wall_s"], abs=1e-6)
    pinned = train_run("cartpole", SMALL, progress=False, judge_every=1)
    for a, b in zip(jax.tree.leaves(result.train_state.params), jax.tree.leaves(pinned.train_state.params),
                    strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_a_resumed_run_keeps_its_runs_cadence(tmp_path):
    part = train_run("cartpole", SMALL, out_dir=tmp_path, progress=False, stop_after_chunks=1, judge_every=2)
    assert part.params is None and json.loads((tmp_path / "config.json").read_text())["judge_every"] == 2
    train_run("cartpole", SMALL, out_dir=tmp_path, progress=False, resume=True)  # judge_every from --out
    assert _judged_chunks(tmp_path) == [1, 3]
    with pytest.raises(ValueError, match="judge_every 2"):
        train_run("cartpole", SMALL, out_dir=tmp_path, progress=False, resume=True, judge_every=1)


@pytest.mark.slow
def test_deterministic_pins_the_judge_to_every_chunk(tmp_path):
    """`--deterministic` without --judge-every judges every chunk: the default cadence reads the clock."""
    import subprocess
    import sys

    out = tmp_path / "run"
    subprocess.run([sys.executable, "-m", "agents.cli", "train", "--env", "cartpole", "--steps", "3000", "--eval_every",
                    "1000", "--deterministic", "--out", str(out)], check=True, capture_output=True, timeout=300)
    assert json.loads((out / "config.json").read_text())["judge_every"] == 1
    assert json.loads((out / "eval.json").read_text())["judged_chunks"] == 3


@pytest.mark.parametrize("on_warp", [False, True])
def test_the_final_saves_copy_to_the_host_is_made_beside_the_final_evaluation_except_on_warp(tmp_path, monkeypatch,
                                                                                            on_warp):
    """The final evaluation is dispatched before the final save, whose copy to the host is then made
    (on the writing thread on one device, on the run's thread where the agents are spread over
    devices) while the devices evaluate. On MuJoCo Warp the copy is made before the evaluation, on
    the run's thread: a copy while the evaluation's Warp kernels capture a CUDA graph breaks the
    capture (CUDA error 904) and never ends. Warp's check is faked here (the suite's CPU tests run
    without warp-lang). The results are the same either way."""
    from agents import checkpoint
    from agents import run as run_module

    handed = []  # per save: whether the writing thread makes the host copy (a function) or gets arrays
    events = []  # "save" (train_run's saves) and "evaluation" (the final evaluation's program run), in order
    real_save, real_run_save = checkpoint.BackgroundSaves.save, run_module.save
    real_call = jax.stages.Compiled.__call__
    monkeypatch.setattr(checkpoint.BackgroundSaves, "save", lambda self, out, env, state, *rest, **kw: (
        handed.append(callable(state)), real_save(self, out, env, state, *rest, **kw))[1])
    monkeypatch.setattr(run_module, "save", lambda *args, **kw: (events.append("save"), real_run_save(*args, **kw))[1])
    monkeypatch.setattr(jax.stages.Compiled, "__call__", lambda self, *args: (
        events.append("evaluation") if len(args) == 2 and not hasattr(args[0], "best_params") else None,
        real_call(self, *args))[1])  # the judge's program takes (train state, key)
    monkeypatch.setattr(run_module, "runs_warp", lambda env: on_warp)
    result = train_run("cartpole", SMALL, out_dir=tmp_path / "run", progress=False)
    assert handed[-1] is not on_warp
    assert events[-2:] == (["evaluation", "save"] if not on_warp else ["save", "evaluation"])
    assert checkpoint.chunks_saved(tmp_path / "run") == SMALL.num_chunks
    monkeypatch.undo()
    plain = train_run("cartpole", SMALL, progress=False)
    assert result.mean_return == plain.mean_return


@pytest.mark.parametrize("on_warp", [False, True])
def test_warp_runs_compile_every_program_before_any_runs_and_others_compile_the_evaluation_beside_training(
        monkeypatch, on_warp):
    """A Warp kernel cannot launch while another thread's XLA autotuner captures a CUDA graph, and
    tracing loads Warp's modules onto the GPU: on MuJoCo Warp every program is traced, then all
    compile at once, and the first program runs once they are done; elsewhere the final
    evaluation's program compiles beside training. The programs are the same either way: so are
    the results. Warp's check is faked here (the suite's CPU tests run without warp-lang)."""
    from agents import run as run_module

    assert run_module.runs_warp(type("OnWarp", (), {"impl": "warp"})())
    traced, compiles, runs = [], [], []  # (when), (thread, began, ended), (when)
    real_lower, real_compile, real_call = jax.stages.Traced.lower, jax.stages.Lowered.compile, jax.stages.Compiled.__call__

    def lower(self, *args, **kwargs):
        lowered = real_lower(self, *args, **kwargs)
        traced.append(time.perf_counter())
        return lowered

    def compile_(self, *args, **kwargs):
        began = time.perf_counter()
        compiled = real_compile(self, *args, **kwargs)
        compiles.append((threading.current_thread().name, began, time.perf_counter()))
        return compiled

    def call(self, *args, **kwargs):
        runs.append(time.perf_counter())
        return real_call(self, *args, **kwargs)

    monkeypatch.setattr(jax.stages.Traced, "lower", lower)
    monkeypatch.setattr(jax.stages.Lowered, "compile", compile_)
    monkeypatch.setattr(jax.stages.Compiled, "__call__", call)
    monkeypatch.setattr(run_module, "runs_warp", lambda env: on_warp)
    result = train_run("cartpole", SMALL, progress=False)
    first_run = min(runs)
    beside = {name.split("_")[0]: (began, ended) for name, began, ended in compiles if name.startswith("mjxsuite-")}
    assert set(beside) == {"mjxsuite-init", "mjxsuite-train", "mjxsuite-evaluation"}
    if on_warp:
        last_trace = max(t for t in traced if t < first_run)
        assert all(last_trace <= began and ended <= first_run for began, ended in beside.values())
    else:
        assert beside["mjxsuite-init"][0] < beside["mjxsuite-train"][0] < first_run < beside["mjxsuite-evaluation"][0]

    monkeypatch.undo()
    plain = train_run("cartpole", SMALL, progress=False)
    assert result.mean_return == plain.mean_return
    jax.tree.map(np.testing.assert_array_equal, result.params, plain.params)
