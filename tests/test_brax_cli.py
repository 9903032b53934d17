"""`mjxsuite train --agent ppo|sac`: Brax's trainers behind our command line and run directory.

The references are independent of the driver: the saved policy is checked against the
in-memory parameters acting through our env's own `action_to_ctrl`; the run directory
against what an uninterrupted run writes; the table against the config classes' checks.
Fast tests train a few hundred steps; the slow ones train pendulum-mjx with the defaults.
"""

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

import envs
from agents import brax_agents, brax_defaults, brax_run, checkpoint, load_policy
from agents.brax_agents import PPOConfig, SACConfig
from agents.cli import UsageError
from agents.cli import main as cli_main

TINY_PPO = PPOConfig(num_timesteps=512, num_envs=8, batch_size=8, num_minibatches=4, unroll_length=8,
                     num_updates_per_batch=1, num_evals=3, num_eval_envs=4, policy_hidden=(16,), value_hidden=(16,))
TINY_PPO_ARGS = ["--steps", "512", "--num_envs", "8", "--batch_size", "8", "--num_minibatches", "4",
                 "--unroll_length", "8", "--num_updates_per_batch", "1", "--num_evals", "3", "--num_eval_envs", "4",
                 "--policy_hidden", "16", "--value_hidden", "16"]


@pytest.mark.parametrize("argv, message", [
    (["--env", "pendulum-mjx", "--agent", "dqn"], "choose --agent ppo or sac"),
    (["--env", "cartpole", "--agent", "ppo"], "choose --agent dqn"),
    (["--env", "pendulum-mjx", "--agent", "sac", "--seeds", "2"], "drop --seeds"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--num_envz", "8"], "unknown option --num_envz; PPOConfig fields"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--num_envs", "0"], "PPOConfig.num_envs must be an integer >= 1"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--learning_rate", "fast"], "bad value for --learning_rate"),
    (["--env", "pendulum-mjx", "--num_envs", "48"], "must be a multiple of num_envs (48)"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--preset", "playground"], "choose one of default"),
    (["--env", "cartpole", "--preset", "playground"], "choose one of default, many-envs"),
    (["--env", "pendulum-mjx", "--agent", "sac", "--steps", "1000"], "must be below num_timesteps"),
    (["--env", "pendulum-mjx", "--agent", "sac", "--steps", "9000", "--min_replay_size", "100"], "needs --out"),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_train_refuses_before_anything_compiles(argv, message, tmp_path, monkeypatch):
    """Wrong agent for the task, unknown fields, bad values and combinations Brax would assert on."""
    monkeypatch.setattr(brax_run, "train_brax", lambda *a, **k: pytest.fail("training started"))
    with pytest.raises(UsageError, match=message.replace("(", r"\(").replace(")", r"\)")):
        cli_main(["train", *argv])


def test_the_table_holds_valid_recipes_for_tasks_registered_or_not():
    """Every row of agents/brax_defaults.py is a valid config; rows for tasks that are not
    registered (another branch adds them) cost nothing."""
    for task, agents in brax_defaults.SETTINGS.items():
        for agent, presets in agents.items():
            assert "default" in presets, (task, agent)
            for preset in presets:
                brax_agents.CONFIGS[agent](**brax_defaults.settings(task, agent, preset))
    assert brax_defaults.settings("my-own-task", "ppo") == {}  # the base recipe
    assert brax_defaults.presets("cartpole-swingup-mjx", "ppo") == ["default", "playground"]


def test_default_agent_follows_the_action_space(monkeypatch):
    seen = {}
    monkeypatch.setattr("agents.cli._train_brax", lambda args, config, **k: seen.setdefault("config", config))
    monkeypatch.setattr("agents.cli._report_brax", lambda *a: 0)
    assert cli_main(["train", "--env", "pendulum-mjx", "--learning_rate", "3e-4"]) == 0
    assert seen["config"] == PPOConfig(**{**brax_defaults.settings("pendulum-mjx", "ppo"), "learning_rate": 3e-4})
    seen.clear()
    assert cli_main(["train", "--env", "half-cheetah", "--out", "unused"]) == 0  # the table's choice
    assert seen["config"] == SACConfig(**brax_defaults.settings("half-cheetah", "sac"))


def test_a_default_sac_without_out_names_where_sac_came_from():
    with pytest.raises(UsageError, match=r"--agent sac \(half-cheetah's default agent\) needs --out"):
        cli_main(["train", "--env", "half-cheetah"])


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ppo")
    result = brax_run.train_brax("pendulum-mjx", TINY_PPO, seed=3, out_dir=out, progress=False, checkpoint_seconds=0)
    return out, result


def test_ppo_run_writes_dqns_run_directory(tiny_run):
    out, result = tiny_run
    saved = checkpoint.load_config(out)
    assert (saved.agent, saved.env, saved.seed, saved.config) == ("ppo", "pendulum-mjx", 3, TINY_PPO)
    records = [json.loads(line) for line in (out / checkpoint.METRICS_FILE).read_text().splitlines()]
    assert [r["env_steps"] for r in records] == [0, 256, 512]  # Brax's first evaluation, then one per epoch
    assert [r["evaluation"] for r in records] == [0, 1, 2]
    assert records == result.history
    best = max(r["eval_return"] for r in records[1:])
    assert checkpoint.load_best_returns(out) == pytest.approx([best])
    summary = json.loads((out / "eval.json").read_text())
    assert summary["agent"] == "ppo" and np.isfinite(summary["mean_return"][0])
    assert json.loads((out / checkpoint.PROGRESS_FILE).read_text())["chunks_done"] == 3
    assert not (out / brax_run.SCRATCH_DIR).exists()


def test_saved_policy_acts_exactly_as_the_in_memory_one(tiny_run):
    """load_policy(DIR) against the parameters train_brax returned, through the env's own
    action_to_ctrl: the same float32 torques, for one observation and for a batch."""
    out, result = tiny_run
    env = envs.make("pendulum-mjx")
    act = brax_agents.deterministic_policy(TINY_PPO, env.observation_size, env.action_size)
    obs = np.asarray(jax.random.normal(jax.random.PRNGKey(0), (32, env.observation_size)), np.float32)
    expected = np.asarray(jax.jit(lambda o: env.unwrapped.action_to_ctrl(act(result.params, o, None)))(obs))
    policy = load_policy(out)
    np.testing.assert_array_equal(policy(obs), expected)
    np.testing.assert_array_equal(policy(obs[0]), expected[0])
    assert policy(obs).dtype == np.float32 and np.abs(expected).max() <= 2.0  # pendulum's ctrlrange is +-2 N m
    with pytest.raises(ValueError, match="observations have size 3"):
        policy(np.zeros(4))


def test_eval_and_rollout_read_a_ppo_run(tiny_run, tmp_path, capsys):
    out, _ = tiny_run
    assert cli_main(["eval", "--checkpoint", str(out), "--episodes", "4"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["env"] == "pendulum-mjx" and np.isfinite(printed["mean_return"][0])
    assert cli_main(["rollout", "--checkpoint", str(out), "--rerun", str(tmp_path / "r.rrd")]) == 0
    assert "1 episodes" in capsys.readouterr().out


def test_to_gymnasium_takes_an_env_instance():
    gymnasium = pytest.importorskip("gymnasium")
    by_name = envs.to_gymnasium("pendulum-mjx")
    instance = envs.to_gymnasium(envs.make("pendulum-mjx"))
    bare = envs.to_gymnasium(envs.PendulumMjx(), episode_length=200)
    for env in (instance, bare):
        assert env.episode_length == 200 and env.action_space == by_name.action_space
        obs, _ = env.reset(seed=1)
        np.testing.assert_array_equal(obs, by_name.reset(seed=1)[0])
    vector = envs.to_gymnasium(envs.make("pendulum-mjx"), num_envs=2)
    assert isinstance(vector, gymnasium.vector.VectorEnv) and vector.reset(seed=0)[0].shape == (2, 3)
    with pytest.raises(ValueError, match="no time limit"):
        envs.to_gymnasium(envs.PendulumMjx())
    with pytest.raises(ValueError, match="only apply to a registered name"):
        envs.to_gymnasium(envs.make("pendulum-mjx"), speed_cost=1.0)


@pytest.mark.slow  # two more Brax compiles: ~40 s on a quiet 2-core machine
def test_resume_continues_from_the_checkpoint(tmp_path, monkeypatch):
    """A run stopped after its second evaluation (of four) resumes from the checkpoint's
    parameters (handed to Brax as restore_params) and ends at the uninterrupted run's step,
    with the same metrics.jsonl steps; Adam's state and the envs restart (agents.brax_run's docs)."""
    config = dataclasses.replace(TINY_PPO, num_timesteps=768, num_evals=4)
    out = tmp_path / "run"
    first = brax_run.train_brax("pendulum-mjx", config, seed=3, out_dir=out, progress=False, checkpoint_seconds=0,
                                stop_after_evals=2)
    assert first.params is None and len(first.history) == 2
    template = brax_run.params_template(config, envs.make("pendulum-mjx"))
    state, evals = checkpoint.load_state(out, "pendulum-mjx", jax.eval_shape(
        lambda: brax_run.BraxState(template, template, np.zeros(1, np.float32), np.zeros((), np.int64))))
    assert evals == 2 and int(state.env_steps) == 256
    handed = {}
    real_trainer = brax_agents.trainer

    def spy(config):
        def train(env, **kwargs):
            handed.update(kwargs)
            return real_trainer(config)(env, **kwargs)
        return train

    monkeypatch.setattr(brax_agents, "trainer", spy)
    resumed = brax_run.train_brax("pendulum-mjx", config, seed=3, out_dir=out, progress=False, resume=True)
    jax.tree.map(np.testing.assert_array_equal, handed["restore_params"], state.params)
    assert (handed["num_timesteps"], handed["num_evals"]) == (512, 3)  # the two epochs left, as long as before
    records = [json.loads(line) for line in (out / checkpoint.METRICS_FILE).read_text().splitlines()]
    assert [r["env_steps"] for r in records] == [0, 256, 512, 768]
    assert [r["evaluation"] for r in records] == [0, 1, 2, 3]
    assert resumed.history == records[2:]
    assert np.isfinite(resumed.mean_return[0])


@pytest.mark.slow  # SAC's compile: ~40 s on a quiet 2-core machine
def test_sac_smoke(tmp_path):
    """SAC through the same driver: its parameters come back through Brax's checkpoint folder."""
    out = tmp_path / "sac"
    code = cli_main(["train", "--env", "pendulum-mjx", "--agent", "sac", "--steps", "1024", "--num_envs", "8",
                     "--min_replay_size", "256", "--batch_size", "32", "--grad_updates_per_step", "1",
                     "--num_evals", "3", "--num_eval_envs", "4", "--hidden", "16", "--out", str(out),
                     "--checkpoint-seconds", "0"])
    assert code == 0
    records = [json.loads(line) for line in (out / checkpoint.METRICS_FILE).read_text().splitlines()]
    assert [r["env_steps"] for r in records] == [0, 640, 1024]  # 256 prefill + 2 epochs of 384 (rounded up by Brax)
    assert all(np.isfinite(r["critic_loss"]) for r in records[1:])
    assert checkpoint.load_config(out).config == SACConfig(num_timesteps=1024, num_envs=8, min_replay_size=256,
                                                           batch_size=32, grad_updates_per_step=1, num_evals=3,
                                                           num_eval_envs=4, hidden=(16,),
                                                           **{k: v for k, v in brax_defaults.settings(
                                                               "pendulum-mjx", "sac").items()
                                                              if k not in ("num_timesteps", "num_evals")})
    action = load_policy(out)(np.zeros(3, np.float32))
    assert action.shape == (1,) and abs(float(action[0])) <= 2.0
    assert not (out / brax_run.SCRATCH_DIR).exists()


# ---- slow: the defaults on pendulum-mjx ----------------------------------------------------
def _cli(*argv: str) -> list[str]:
    return [sys.executable, "-m", "agents.cli", *argv]


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "MJXSUITE_COMPILE_CACHE": "0"}


@pytest.mark.slow  # issue #29: two compiling subprocesses (~40 s); the tiny PPO run stays in the default run
def test_training_and_judging_a_ppo_run_need_no_rerun(tmp_path):
    """GPU machines may lack rerun-sdk (it is large): only --rerun and `rollout` may import it."""
    out = tmp_path / "run"
    no_rerun = "import runpy, sys; sys.modules['rerun'] = None; runpy.run_module('agents.cli', run_name='__main__')"
    for argv in (["train", "--env", "pendulum-mjx", "--agent", "ppo", *TINY_PPO_ARGS, "--out", str(out)],
                 ["eval", "--checkpoint", str(out), "--episodes", "2"]):
        done = subprocess.run([sys.executable, "-c", no_rerun, *argv], env=_env(), capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]


@pytest.mark.slow
def test_ppo_defaults_solve_pendulum_within_3_minutes(tmp_path):
    """`mjxsuite train --env pendulum-mjx --agent ppo` with the table's defaults: Gymnasium's
    Pendulum-v1 counts as solved at -200; our evaluation of the saved policy (64 episodes)."""
    out = tmp_path / "p"
    start, cpu_start = time.perf_counter(), _children_cpu_s()
    subprocess.run(_cli("train", "--env", "pendulum-mjx", "--agent", "ppo", "--out", str(out)), env=_env(), check=True,
                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    wall, cpu = time.perf_counter() - start, _children_cpu_s() - cpu_start
    summary = json.loads((out / "eval.json").read_text())
    print(f"pendulum-mjx PPO defaults: {wall:.0f} s wall, {cpu:.0f} s CPU, mean return {summary['mean_return'][0]:.1f}")
    assert summary["mean_return"][0] >= -200
    # 3 minutes of a quiet 2-core machine, judged by CPU time (a shared machine stretches the wall time)
    assert cpu <= 2 * 180


@pytest.mark.slow
def test_ppo_defaults_solve_gymnasiums_inverted_pendulum(tmp_path):
    """`mjxsuite train --env inverted-pendulum --agent ppo` with the table's defaults, judged as
    issue #27 asks: its saved policy on Gymnasium's own InvertedPendulum-v5 (C MuJoCo, 10
    episodes), within 10% of its return on our env, in 3 minutes of a quiet 2-core machine."""
    from benchmarks import gym_training

    start = _children_cpu_s()
    record = gym_training.run_one(["--env", "inverted-pendulum", "--agent", "ppo"], tmp_path / "ip", 10, None)
    cpu = _children_cpu_s() - start
    print(gym_training.line(record), f"{cpu:.0f} s CPU")
    assert record["return_on_gymnasium"] >= 950
    assert record["most_overflowing_evaluation"] == 0.0  # MJX's flag reached the record (impl="jax": never set)
    assert abs(record["gymnasium_over_here"] - 1) <= 0.1
    assert cpu <= 2 * 180  # judged by CPU time: a shared machine stretches the wall time


def _children_cpu_s() -> float:
    import resource

    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


@pytest.mark.slow
def test_kill_9_and_resume_end_where_an_uninterrupted_run_ends(tmp_path):
    """kill -9 during the default PPO run, then --resume: the same evaluations at the same env
    steps as an uninterrupted run (metrics.jsonl), and a trained policy at the end."""
    out = tmp_path / "k"
    argv = ("train", "--env", "pendulum-mjx", "--agent", "ppo", "--out", str(out), "--checkpoint-seconds", "0")
    proc = subprocess.Popen(_cli(*argv), env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    progress = out / checkpoint.PROGRESS_FILE
    try:
        while proc.poll() is None and not (progress.is_file() and json.loads(progress.read_text())["chunks_done"] >= 4):
            time.sleep(0.2)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    killed_at = json.loads(progress.read_text())["chunks_done"]
    config = checkpoint.load_config(out).config
    assert killed_at < config.num_evals, "the run finished before it was killed"
    subprocess.run(_cli("train", "--out", str(out), "--resume"), env=_env(), check=True,
                   stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    records = [json.loads(line) for line in (out / checkpoint.METRICS_FILE).read_text().splitlines()]
    assert [r["evaluation"] for r in records] == list(range(config.num_evals))
    assert [r["env_steps"] for r in records] == [i * config.steps_per_epoch for i in range(config.num_evals)]
    # A resume restarts Adam, the envs and the key stream (docs/brax.md), so the resumed run's return
    # differs from an uninterrupted one (-156.9 and -222.8 seen against -161.5; solved is -200): it
    # must still be a trained policy, far above a random one (about -1,200).
    assert json.loads((out / "eval.json").read_text())["mean_return"][0] >= -400


@pytest.mark.slow  # a SAC compile
def test_sac_resume_is_refused_with_a_checkpoint(tmp_path, capsys):
    """brax 0.14.2's SAC cannot restore (restore_checkpoint_path fails at its first evaluation):
    --resume says so before anything compiles, and the checkpoint's policy still loads."""
    config = SACConfig(num_timesteps=1024, num_envs=8, min_replay_size=256, batch_size=32, grad_updates_per_step=1,
                       num_evals=3, num_eval_envs=4, hidden=(16,))
    out = tmp_path / "sac"
    brax_run.train_brax("pendulum-mjx", config, out_dir=out, progress=False, checkpoint_seconds=0, stop_after_evals=2)
    assert cli_main(["train", "--out", str(out), "--resume"]) == 2
    assert "SAC cannot restart" in capsys.readouterr().err
    assert load_policy(out)(np.zeros(3, np.float32)).shape == (1,)
