"""The run lifecycle's judge cadence (`agents.run_steps.judge_every`, `JudgeClock`): which chunks
end with the greedy judge, a function of the run's config alone (never of the clock), saved in
config.json and kept by a resumed run."""

import dataclasses
import json
import os
import re
import subprocess
import threading
import time

import jax
import numpy as np
import pytest

from agents import DQNConfig, PPOConfig, SACConfig, checkpoint, run_steps, train_run
from agents.commands import wall_line
from agents.processes import MJXSUITE
from agents.run import WALL_PARTS

SMALL = DQNConfig(total_steps=400, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                  eval_episodes=4, hidden=(16,))


def test_the_default_cadence_is_a_function_of_the_config_and_never_of_the_evaluations_size():
    """DQN's judge is spaced out by its cost model: `horizon` batched steps against a chunk's env
    steps and updates; more episodes per judge never judge fewer chunks. PPO and SAC judge every
    chunk (their num_evals is the run's count of evaluations, as Brax's)."""
    config = DQNConfig()  # 1,000 env steps and 1,000 updates a chunk
    work = 1_000 + run_steps.UPDATE_COST * 1_000
    assert config.chunk_work == (1_000, 1_000)
    assert run_steps.judge_every(config, 500) == max(1, -(-500 // int(run_steps.JUDGE_SHARE * work)))
    assert run_steps.judge_every(DQNConfig(eval_every=50_000, total_steps=500_000), 500) == 1
    for episodes in (1, 64, 4096):
        assert run_steps.judge_every(DQNConfig(eval_episodes=episodes), 500) == run_steps.judge_every(config, 500)
    assert run_steps.judge_every(PPOConfig(num_eval_envs=4096), 1000) == 1
    assert run_steps.judge_every(SACConfig(), 1000) == 1


def test_a_cadence_judges_the_same_chunks_and_always_the_last():
    clock = run_steps.JudgeClock(3, last_chunk=7)
    assert [i for i in range(8) if clock.due(i)] == [2, 5, 7]
    with pytest.raises(ValueError, match="judge_every"):
        run_steps.JudgeClock(0, last_chunk=3)


def _judged_chunks(out):
    records = [json.loads(line) for line in (out / "metrics.jsonl").read_text().splitlines()]
    assert all("env_steps" in r for r in records)  # every chunk says where the run stands
    assert all(("judge_s" in r) == ("eval_return" in r) and r.get("judge_s", 1) > 0 for r in records)  # its seconds
    return [r["chunk"] for r in records if "eval_return" in r]


def test_a_run_judges_its_configs_cadence_and_saves_it(tmp_path):
    every = run_steps.judge_every(SMALL, 500)
    assert every > 1  # SMALL's chunks are short beside CartPole's 500-step judge
    result = train_run("cartpole", SMALL, out_dir=tmp_path, progress=False)
    judged = [i for i in range(SMALL.num_chunks) if (i + 1) % every == 0 or i == SMALL.num_chunks - 1]
    assert _judged_chunks(tmp_path) == judged and result.judges == len(judged)
    assert json.loads((tmp_path / "config.json").read_text())["judge_every"] == every
    summary = json.loads((tmp_path / "eval.json").read_text())
    assert summary["judged_chunks"] == len(judged) and summary["chunks"] == SMALL.num_chunks
    assert sum(summary["wall_parts_s"].values()) == pytest.approx(summary["wall_s"], abs=1e-6)
    printed = re.findall(r"([a-z-]+) [0-9.]+", wall_line(result).split("=", 1)[1])  # case 147: one set of names
    assert list(summary["wall_parts_s"]) == printed == list(WALL_PARTS)
    pinned = train_run("cartpole", SMALL, progress=False, judge_every=1)  # judging changes no training
    jax.tree.map(np.testing.assert_array_equal, result.train_state.params, pinned.train_state.params)


def test_a_slower_or_faster_clock_judges_the_same_chunks(tmp_path, monkeypatch):
    """What the clock reads (a loaded machine, a warm compile cache) changes nothing a run reports
    but its seconds: a clock 1,000 times faster gives the same best parameters and returns."""
    plain = train_run("cartpole", SMALL, progress=False)
    real = time.perf_counter
    monkeypatch.setattr(time, "perf_counter", lambda: 1000.0 * real())
    fast = train_run("cartpole", SMALL, progress=False)
    monkeypatch.undo()
    assert fast.judges == plain.judges and fast.mean_return == plain.mean_return
    assert fast.solve_step == plain.solve_step
    jax.tree.map(np.testing.assert_array_equal, fast.params, plain.params)


def test_a_resumed_run_keeps_its_runs_cadence_and_ends_as_the_uninterrupted_one(tmp_path):
    whole = train_run("cartpole", SMALL, out_dir=tmp_path / "whole", progress=False)
    part = train_run("cartpole", SMALL, out_dir=tmp_path / "part", progress=False, stop_after_chunks=1)
    assert part.params is None
    resumed = train_run("cartpole", SMALL, out_dir=tmp_path / "part", progress=False, resume=True)
    jax.tree.map(np.testing.assert_array_equal, resumed.params, whole.params)
    ours, theirs = (json.loads((tmp_path / d / "eval.json").read_text()) for d in ("part", "whole"))
    for key in ("mean_return", "solve_step", "best_seed", "judged_chunks", "chunks", "tie_break_return"):
        assert ours[key] == theirs[key], key
    assert _judged_chunks(tmp_path / "part") == _judged_chunks(tmp_path / "whole")
    with pytest.raises(ValueError, match="judge_every"):
        train_run("cartpole", SMALL, out_dir=tmp_path / "part", progress=False, resume=True, judge_every=1)


def test_an_interrupted_runs_time_split_is_read_from_progress_json_without_its_train_state(tmp_path):
    """A run stopped before its end has no eval.json, and its train state may be too large to keep;
    progress.json carries the clock of its last checkpoint, which `gym_training.describe` reports."""
    from benchmarks import gym_training

    train_run("cartpole", SMALL, out_dir=tmp_path / "part", progress=False, stop_after_chunks=2, judge_every=1)
    (tmp_path / "part" / checkpoint.STATE_FILE).unlink()  # as the GPU benchmarks bring runs back
    progress = json.loads((tmp_path / "part" / checkpoint.PROGRESS_FILE).read_text())
    parts = progress["clock"]["wall_parts_s"]
    assert set(parts) == set(WALL_PARTS) and parts["train"] > 0
    assert progress["clock"]["wall_s"] >= sum(parts.values()) - 1e-6
    record = gym_training.describe({"out": str(tmp_path / "part")})
    assert record["wall_parts_s"] == parts and "eval.json" not in os.listdir(tmp_path / "part")
    assert "actor_saturation" not in record["evaluations"][0]  # TD3's alone


@pytest.mark.slow  # compiles TD3's pendulum-mjx programs
def test_a_td3_runs_record_carries_each_seeds_actor_saturation(tmp_path):
    """The GPU benchmarks bring back run directories without their train state; a seed that stands still
    (its actor at its bounds) shows in the record's curve, judged or not."""
    from agents import TD3Config
    from benchmarks import gym_training

    tiny = TD3Config(num_timesteps=640, num_envs=8, min_replay_size=128, max_replay_size=256, batch_size=32,
                     num_updates=2, num_evals=4, num_eval_envs=4, actor_hidden=(16,), critic_hidden=(16,), num_atoms=21)
    train_run("pendulum-mjx", tiny, seeds=2, out_dir=tmp_path / "td3", progress=False, stop_after_chunks=2)
    curve = gym_training.describe({"out": str(tmp_path / "td3")})["evaluations"]
    assert len(curve) == 2 and all(len(r["actor_saturation"]) == 2 for r in curve)
    assert all(0.0 <= s <= 1.0 for r in curve for s in r["actor_saturation"])


def test_a_run_stopped_before_its_first_checkpoint_keeps_its_best_policy(tmp_path):
    """A checkpoint holds the replay, so its spacing grows with the replay's size (`SaveClock`): a pixel
    TD3 run Ctrl-C'd on the GPU before its first checkpoint kept no policy of its four judges. A judge
    that raises a best return now writes best_params.ckpt alone, on a clock of its own."""
    out, best = tmp_path / "run", {}

    def stopped_at_the_third_chunk(index, ts, record):
        best[index] = np.asarray(ts.best_return).tolist()
        if index == 2:
            raise RuntimeError("stopped")

    with pytest.raises(RuntimeError, match="stopped"):
        train_run("cartpole", SMALL, seeds=2, out_dir=out, progress=False, judge_every=1, checkpoint_every=100,
                  checkpoint_seconds=0, on_chunk=stopped_at_the_third_chunk)
    assert not (out / checkpoint.STATE_FILE).exists()
    assert checkpoint.load_best_returns(out) == best[1] and np.all(np.isfinite(best[1]))  # chunk 1's judge's


def test_wall_s_and_solve_wall_s_span_every_session_of_a_resumed_run(tmp_path):
    """Cases 28 and 56: after a --resume, eval.json's wall_s, its parts and solve_wall_s count the
    sessions before it too (the clock each checkpoint saves), not the resumed session alone."""
    config = dataclasses.replace(SMALL, solve_return=1.0)  # every CartPole policy reaches it at its first judge
    out = tmp_path / "run"
    slow = lambda *_: time.sleep(0.3)  # noqa: E731  a first session of at least 3 x 0.3 s
    train_run("cartpole", config, out_dir=out, progress=False, judge_every=1, stop_after_chunks=3, on_chunk=slow)
    first = checkpoint.saved_clock(out)
    assert first["wall_s"] >= 0.9 and all(s is not None and s < first["wall_s"] for s in first["solve_wall_s"])
    resumed = train_run("cartpole", config, out_dir=out, progress=False, resume=True)
    summary = json.loads((out / "eval.json").read_text())
    assert summary["solve_wall_s"] == first["solve_wall_s"]  # reached in the first session, timed there
    assert summary["wall_s"] == resumed.wall_s > first["wall_s"] + resumed.train_s - first["wall_parts_s"]["train"]
    assert resumed.earlier_wall_s == first["wall_s"]
    assert sum(summary["wall_parts_s"].values()) == pytest.approx(summary["wall_s"], abs=1e-6)
    for name in ("start-up", "compile", "train", "judge"):
        assert summary["wall_parts_s"][name] >= first["wall_parts_s"][name] > 0, name


def _cli_run(out, *flags, cache=None):
    environ = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "MJXSUITE_COMPILE_CACHE")}
    if cache is not None:
        environ["MJXSUITE_COMPILE_CACHE"] = str(cache)
    subprocess.run([*MJXSUITE, "train", "--env", "cartpole", "--steps", "400", "--eval_every", "100",
                    "--learning_starts", "64", "--batch_size", "32", "--buffer_size", "256", "--eval_episodes", "4",
                    "--hidden", "16", "--out", str(out), "--overwrite", *flags], check=True, capture_output=True,
                   timeout=300, env=environ)
    summary = json.loads((out / "eval.json").read_text())
    return {k: summary[k] for k in ("mean_return", "solve_step", "judged_chunks", "best_seed")}, (
        out / "best_params.ckpt").read_bytes()


@pytest.mark.slow
def test_cold_warm_and_no_compile_cache_give_the_same_results(tmp_path):
    cache = tmp_path / "cache"
    cold = _cli_run(tmp_path / "cold", cache=cache)
    assert any(cache.iterdir())
    warm = _cli_run(tmp_path / "warm", cache=cache)
    none = _cli_run(tmp_path / "none", "--no-compile-cache")
    assert cold == warm == none


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


def test_resuming_a_finished_run_changes_nothing(tmp_path, capsys):
    """`--resume` of a finished run says it is finished, with its returns, and leaves eval.json and
    metrics.jsonl as they were (it used to evaluate again and rewrite eval.json)."""
    from agents.cli import main as cli_main

    out = tmp_path / "run"
    train_run("cartpole", SMALL, out_dir=out, progress=False)
    files = {name: (out / name).read_bytes() for name in ("eval.json", "metrics.jsonl")}
    assert cli_main(["train", "--out", str(out), "--resume"]) == 0
    assert "holds a finished run" in capsys.readouterr().out
    assert {name: (out / name).read_bytes() for name in files} == files


def test_a_diverged_seed_is_reported_and_never_sinks_the_others(capsys):
    """One seed's NaN return (a diverged seed) neither ties nor wins, and the others are ranked as
    ever; a chunk whose loss is NaN names its seed once. All NaN: the first seed stands."""
    from agents import run

    assert run.tied_seeds([float("nan"), 3.0, 3.0]).tolist() == [1, 2]
    assert run.tied_seeds([float("nan"), float("nan")]).tolist() == [0]
    diverged = []

    class Bar:
        def write(self, text):
            print(text)

    for chunk in (3, 4):
        run._check_diverged({"chunk": chunk, "loss": [0.5, float("nan")], "q": [1.0, 1.0]}, diverged, 0, Bar())
    assert diverged == [1]
    said = capsys.readouterr().out
    assert said.count("seed 1 diverged in chunk 3") == 1 and "chunk 4" not in said


def test_a_run_directory_trains_one_run_at_a_time(tmp_path):
    """A second run in a directory a run trains in (two `--resume`s of one run) is refused, naming
    the process that holds it, before anything compiles; once the first ends, the directory is free."""
    out = tmp_path / "run"
    out.mkdir()
    held = run_steps.RunDirLock(out)
    with pytest.raises(ValueError, match=rf"--out {out} is in use by a run training there \(pid {os.getpid()}\)"):
        train_run("cartpole", SMALL, out_dir=out, progress=False)
    held.release()
    train_run("cartpole", SMALL, out_dir=out, progress=False, stop_after_chunks=1)
    run_steps.RunDirLock(out).release()  # the run released it when it returned


# ---- a long chunk in parts (case 118): the bar moves and a signal acts between them -------------------
PARTED = PPOConfig(num_timesteps=2 * 4 * 256, num_envs=8, batch_size=8, num_minibatches=4, unroll_length=8,
                   num_updates_per_batch=1, num_evals=3, num_eval_envs=4, policy_hidden=(16,), value_hidden=(16,))


def test_how_many_parts_a_chunk_runs_as_is_a_function_of_the_config():
    from agents import brax_defaults

    assert PARTED.training_steps_per_chunk == 4 and run_steps.chunk_parts(PARTED) == 1  # 1,024 steps: one part
    hopper = PPOConfig(**brax_defaults.settings("hopper", "ppo"))  # 983,040 env steps per training step
    assert run_steps.chunk_parts(hopper) == hopper.training_steps_per_chunk > 1  # one training step a part
    cpu = PPOConfig(**brax_defaults.settings("hopper", "ppo", "cpu"))
    parts = run_steps.chunk_parts(cpu)
    assert cpu.training_steps_per_chunk % parts == 0 and cpu.eval_every // parts <= run_steps.PART_ENV_STEPS
    assert run_steps.chunk_parts(SMALL) == run_steps.chunk_parts(SACConfig()) == 1


@pytest.mark.slow  # two compiles of PPO's chunk; the fast run keeps chunk_parts' rule
def test_a_chunk_in_parts_ends_as_the_whole_chunk_to_the_bit():
    """`evaluation.chunk_part` run in turn gives `train_steps`' train state, metrics and evaluation key."""
    import envs
    from agents import evaluation
    from agents.ppo import PPO

    ppo = PPO(PARTED, envs.make("pendulum-mjx"))
    ts = ppo.init(jax.random.PRNGKey(0))
    whole = jax.jit(ppo.train_steps)(ts)
    part = jax.jit(lambda ts, carry: evaluation.chunk_part(ppo.chunk_loop(ts), 4, ts, carry))
    carry = evaluation.part_carry(ppo.chunk_loop, ts)
    for _ in range(4):
        ts, carry, metrics, eval_key = part(ts, carry)
    jax.tree.map(np.testing.assert_array_equal, (ts, metrics, eval_key), whole)


@pytest.mark.slow
def test_a_signal_between_parts_stops_the_run_and_resume_ends_as_the_whole_run(tmp_path, monkeypatch):
    """With chunks in parts, SIGINT is acted on after the part under way: the chunk under way is
    dropped, the checkpoint holds the chunks done, and --resume ends as an uninterrupted run of
    whole chunks, to the bit."""
    import signal

    from agents import run as run_module

    whole = train_run("pendulum-mjx", PARTED, out_dir=tmp_path / "whole", progress=False)
    monkeypatch.setattr(run_steps, "PART_ENV_STEPS", 256)  # each chunk in 4 parts
    real_bar = run_steps.progress_bar

    def bar(*args, **kwargs):
        made = real_bar(*args, **kwargs)
        update = made.update

        def signalled(steps):
            update(steps)
            if made.n == PARTED.eval_every + 256:  # chunk 1's first part
                os.kill(os.getpid(), signal.SIGINT)
        made.update = signalled
        return made

    monkeypatch.setattr(run_module.run_steps, "progress_bar", bar)
    out = tmp_path / "parts"
    stopped = train_run("pendulum-mjx", PARTED, out_dir=out, progress=True)
    assert stopped.interrupted and stopped.chunks_done == stopped.saved_chunks == 1
    monkeypatch.setattr(run_module.run_steps, "progress_bar", real_bar)
    resumed = train_run("pendulum-mjx", PARTED, out_dir=out, progress=False, resume=True)
    jax.tree.map(np.testing.assert_array_equal, resumed.params, whole.params)
    assert resumed.mean_return == whole.mean_return
