"""PPO and SAC through the one run lifecycle (`agents.run.train_run`, `mjxsuite train --agent ppo|sac`):
the run directory DQN writes, many seeds, exact resume, one `load_policy`, `eval` and `rollout`.

The references are independent of the lifecycle: the saved policy against the agent's own
policy on the in-memory parameters through the env's own `action_to_ctrl`; a resumed run
against an uninterrupted one; the policies on Gymnasium's own env (slow).
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
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents import brax_defaults, checkpoint, load_policy, registry, train_run
from agents.cli import UsageError
from agents.cli import main as cli_main
from agents.ppo import PPO, PPOConfig
from agents.run import break_ties, seed_keys
from agents.sac import SACConfig
from agents.td3 import TD3Config

TINY_PPO = PPOConfig(num_timesteps=512, num_envs=8, batch_size=8, num_minibatches=4, unroll_length=8,
                     num_updates_per_batch=1, num_evals=3, num_eval_envs=4, policy_hidden=(16,), value_hidden=(16,))
TINY_PPO_ARGS = ["--steps", "512", "--num_envs", "8", "--batch_size", "8", "--num_minibatches", "4",
                 "--unroll_length", "8", "--num_updates_per_batch", "1", "--num_evals", "3", "--num_eval_envs", "4",
                 "--policy_hidden", "16", "--value_hidden", "16"]
TINY_SAC = SACConfig(num_timesteps=640, num_envs=8, min_replay_size=128, max_replay_size=256, batch_size=32,
                     grad_updates_per_step=1, num_evals=4, num_eval_envs=4, hidden=(16,))


@pytest.mark.parametrize("argv, message", [
    (["--env", "pendulum-mjx", "--agent", "dqn"], "choose --agent ppo or sac"),
    (["--env", "cartpole", "--agent", "ppo"], "choose --agent dqn"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--num_envz", "8"], "unknown option --num_envz for `mjxsuite train`; did you mean --num_envs"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--num_envs", "0"], "PPOConfig.num_envs must be an integer >= 1"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--learning_rate", "fast"], "bad value for --learning_rate"),
    (["--env", "pendulum-mjx", "--num_envs", "48"], "must divide batch_size * num_minibatches"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--preset", "playground"], "choose one of default"),
    (["--env", "cartpole", "--preset", "playground"], "choose one of default, many-envs"),
    (["--env", "pendulum-mjx", "--agent", "sac", "--steps", "1000"], "must be below num_timesteps"),
    (["--env", "pendulum-mjx", "--agent", "ppo", "--replay", "uniform"], "--replay chooses DQN's replay"),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_train_refuses_before_anything_compiles(argv, message, monkeypatch):
    """Wrong agent for the task, unknown fields, bad values and combinations the agents refuse."""
    monkeypatch.setattr("agents.run.train_run", lambda *a, **k: pytest.fail("training started"))
    with pytest.raises(UsageError, match=message.replace("(", r"\(").replace(")", r"\)").replace("*", r"\*")):
        cli_main(["train", *argv])


def test_the_table_holds_valid_recipes_for_tasks_registered_or_not():
    """Every row of agents/brax_defaults.py is a valid config of our PPO or SAC; rows for tasks
    that are not registered cost nothing."""
    for task, agents in brax_defaults.SETTINGS.items():
        for agent, presets in agents.items():
            assert "default" in presets, (task, agent)
            for preset in presets:
                registry.config_class(agent)(**brax_defaults.settings(task, agent, preset))
    assert brax_defaults.settings("my-own-task", "ppo") == {}  # the base recipe
    assert brax_defaults.presets("cartpole-swingup-mjx", "ppo") == ["default", "pixels", "playground"]
    # every DeepMind Control Suite task trains with a GPU-sized recipe (a task without a row would
    # take the base recipe, sized for a CPU: dm_control's finger did, and stood still on a GPU)
    suite = [name for name in envs.names() if name.startswith("dmc-")]
    assert [name for name in suite if brax_defaults.settings(name, "ppo").get("num_envs", 0) < 2048] == []


def test_default_agent_follows_the_action_space_and_steps_are_per_seed(monkeypatch, capsys):
    seen = {}
    monkeypatch.setattr("agents.run.train_run", lambda env, config, **k: seen.update(config=config, **k))
    monkeypatch.setattr("agents.commands._report", lambda *a: 0)
    assert cli_main(["train", "--env", "pendulum-mjx", "--learning_rate", "3e-4", "--seeds", "3"]) == 0
    assert seen["config"] == PPOConfig(**{**brax_defaults.settings("pendulum-mjx", "ppo"), "learning_rate": 3e-4})
    assert seen["seeds"] == 3
    assert cli_main(["train", "--env", "half-cheetah", "--steps", "300000"]) == 0  # the table's choice
    assert seen["config"] == SACConfig(**{**brax_defaults.settings("half-cheetah", "sac"), "num_timesteps": 300_000})
    assert cli_main(["train", "--env", "pendulum-mjx", "--agent", "ppo", "--steps", "60000"]) == 0
    assert "note: num_timesteps 60,000 rounded up to" in capsys.readouterr().err  # said before compiling


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ppo")
    result = train_run("pendulum-mjx", TINY_PPO, seeds=2, seed=3, out_dir=out, progress=False, checkpoint_seconds=0)
    return out, result


@pytest.mark.slow
def test_a_ppo_run_writes_dqns_run_directory(tiny_run, tmp_path):
    out, result = tiny_run
    saved = checkpoint.load_config(out)
    assert (saved.agent, saved.env, saved.seeds, saved.seed, saved.config) == ("ppo", "pendulum-mjx", 2, 3, TINY_PPO)
    records = [json.loads(line) for line in (out / checkpoint.METRICS_FILE).read_text().splitlines()]
    assert [r["chunk"] for r in records] == [0, 1] and [r["env_steps"] for r in records] == [[256, 256], [512, 512]]
    assert checkpoint.load_best_returns(out) == pytest.approx(np.max([r["eval_return"] for r in records], axis=0))
    summary = json.loads((out / "eval.json").read_text())
    dqn_out = tmp_path / "dqn"
    from agents import DQNConfig

    train_run("cartpole", DQNConfig(total_steps=200, learning_starts=32, batch_size=32, eval_every=100,
                                    eval_episodes=2, hidden=(8,)), out_dir=dqn_out, progress=False)
    assert summary.keys() == json.loads((dqn_out / "eval.json").read_text()).keys()  # one eval.json for every agent
    assert summary["agent"] == "ppo" and len(summary["mean_return"]) == 2 and summary["best_seed"] == result.best_seed


@pytest.mark.slow  # tiny_run is trained for the slow run's tests beside it
def test_the_saved_policy_acts_as_the_agent_does(tiny_run):
    """load_policy(DIR, seed_index=i) against the agent's own policy on seed i's returned
    parameters, through the env's own action_to_ctrl: the same float32 torques."""
    out, result = tiny_run
    env = envs.make("pendulum-mjx")
    ppo = PPO(TINY_PPO, env)
    obs = np.asarray(jax.random.normal(jax.random.PRNGKey(0), (32, env.observation_size)), np.float32)
    for i in range(2):
        params = jax.tree.map(lambda x: x[i], result.params)
        expected = np.asarray(jax.jit(lambda o: env.unwrapped.action_to_ctrl(ppo.policy(params, o)))(obs))
        policy = load_policy(out, seed_index=i)
        np.testing.assert_array_equal(policy(obs), expected)
        np.testing.assert_array_equal(policy(obs[0]), expected[0])
    assert policy(obs).dtype == np.float32 and np.abs(expected).max() <= 2.0  # pendulum's ctrlrange is +-2 N m
    with pytest.raises(ValueError, match="observations have size 3"):
        policy(np.zeros(4))


@pytest.mark.parametrize("agent", ["dqn", "ppo", "sac", "td3"])
def test_fresh_params_have_inits_shapes_without_touching_an_env(agent, monkeypatch):
    """`load_policy` restores a checkpoint into the shapes of `fresh_params`, not of `init`, whose trace steps the
    envs (a pixel run's renderer and first fill): the parameters' shapes and types, and no env reset or step."""
    from agents import DQNConfig
    config = {"dqn": DQNConfig(hidden=(8,)), "ppo": TINY_PPO, "sac": TINY_SAC,
              "td3": TD3Config(num_envs=8, batch_size=8, min_replay_size=16, max_replay_size=64, actor_hidden=(8,),
                               critic_hidden=(8,), num_atoms=5)}[agent]
    learner = registry.make(config, envs.make("cartpole" if agent == "dqn" else "pendulum-mjx"))
    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    expected = jax.eval_shape(jax.vmap(learner.init), keys).params
    for env in {learner.env, learner.train_env}:
        monkeypatch.setattr(env, "reset", lambda *_: pytest.fail("fresh_params reset an env"), raising=False)
        monkeypatch.setattr(env, "step", lambda *_: pytest.fail("fresh_params stepped an env"), raising=False)
    shapes = jax.eval_shape(jax.vmap(learner.fresh_params), keys)
    assert jax.tree.structure(shapes) == jax.tree.structure(expected)
    assert jax.tree.leaves(shapes) == jax.tree.leaves(expected)


@pytest.mark.slow
def test_eval_and_rollout_read_a_ppo_run(tiny_run, tmp_path, capsys):
    out, _ = tiny_run
    assert cli_main(["eval", "--checkpoint", str(out), "--episodes", "4"]) == 0
    printed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert printed["env"] == "pendulum-mjx" and len(printed["mean_return"]) == 2
    assert np.isfinite(printed["mean_return"]).all()
    assert cli_main(["rollout", "--checkpoint", str(out), "--rerun", str(tmp_path / "r.rrd")]) == 0
    assert "1 episodes" in capsys.readouterr().out


def _leaves(out):
    run = checkpoint.load_config(out)
    agent = registry.make(run.config, envs.make(run.env))
    template = jax.eval_shape(jax.vmap(agent.init), seed_keys(run.seed, run.seeds))
    return jax.tree.leaves(checkpoint.load_state(out, run.env, template)[0])


SLOW_SAVES = """
import os, sys, time
rename = os.replace
def slow_rename(src, dst):
    time.sleep(0.2)
    rename(src, dst)
os.replace = slow_rename
from agents.cli import main
sys.exit(main(sys.argv[1:]))
"""


def kill_9_then_resume(tmp_path, agent: str, config, judge_every: int | None = None) -> None:
    """SIGKILL of `mjxsuite train --agent AGENT` once a checkpoint exists (saves slowed down, so the
    kill lands mid-run), then `mjxsuite train --out D --resume`: the uninterrupted run's train state,
    replay buffers included, and its eval.json."""
    train_run("pendulum-mjx", config, out_dir=tmp_path / "whole", progress=False, judge_every=judge_every)
    args = [f"--{f.name}={','.join(map(str, v)) if isinstance(v, tuple) else v}"
            for f in dataclasses.fields(config) if (v := getattr(config, f.name)) is not None]
    args += [] if judge_every is None else ["--judge-every", str(judge_every)]
    out = tmp_path / "killed"
    process = subprocess.Popen([sys.executable, "-c", SLOW_SAVES, "train", "--env", "pendulum-mjx", "--agent", agent,
                                "--out", str(out), "--checkpoint-seconds", "0", *args], env=_env(),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 180
        while checkpoint.chunks_saved(out) < 1 and time.monotonic() < deadline and process.poll() is None:
            time.sleep(0.01)
    finally:
        process.send_signal(signal.SIGKILL)
        process.wait()
    assert 1 <= checkpoint.chunks_saved(out) < config.num_chunks and not (out / "eval.json").exists()
    assert cli_main(["train", "--out", str(out), "--resume"]) == 0
    for a, b in zip(_leaves(tmp_path / "whole"), _leaves(out), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    ours, theirs = (json.loads((d / "eval.json").read_text()) for d in (out, tmp_path / "whole"))
    for key in ("mean_return", "solve_step", "best_seed", "judged_chunks", "chunks"):
        assert ours[key] == theirs[key], key


@pytest.mark.slow  # two compiling subprocesses; tests/test_ppo.py and tests/test_sac.py resume exactly in the default run
@pytest.mark.parametrize("agent, config", [("ppo", TINY_PPO), ("sac", TINY_SAC)], ids=["ppo", "sac"])
def test_kill_9_after_a_checkpoint_then_resume_is_exact(tmp_path, agent, config):
    kill_9_then_resume(tmp_path, agent, dataclasses.replace(config, num_evals=7))


@pytest.mark.heavy  # ~20 s: the DQN signal tests (test_faults.py) cover the same lifecycle in the default run
def test_sigterm_stops_a_ppo_run_and_resume_ends_it_as_the_uninterrupted_run(tmp_path, capsys):
    whole = train_run("pendulum-mjx", TINY_PPO, out_dir=tmp_path / "whole", progress=False)

    def signalled(index, ts, record):  # after the first chunk, as a scheduler would
        if index == 0:
            os.kill(os.getpid(), signal.SIGTERM)

    stopped = train_run("pendulum-mjx", TINY_PPO, out_dir=tmp_path / "part", progress=False, on_chunk=signalled)
    assert stopped.interrupted and stopped.stop_signal == "SIGTERM" and stopped.saved_chunks == 1
    assert cli_main(["train", "--out", str(tmp_path / "part"), "--resume"]) == 0
    for a, b in zip(_leaves(tmp_path / "whole"), _leaves(tmp_path / "part"), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert json.loads((tmp_path / "part" / "eval.json").read_text())["mean_return"] == whole.mean_return


@pytest.mark.slow
def test_ties_between_seeds_are_broken_by_a_longer_evaluation():
    """Seeds tied in the final evaluation are judged again on longer episodes; a clear winner
    needs no second evaluation."""
    from agents import DQN, DQNConfig

    config = DQNConfig(hidden=(8,), eval_episodes=2)
    dqn = DQN(config, envs.make("cartpole", episode_length=20))
    params = jax.vmap(dqn.init)(seed_keys(0, 3)).params
    assert break_ties(dqn, "cartpole", {"episode_length": 20}, params, [1.0, 5.0, 3.0], 0) == (1, {})
    longer = jax.vmap(lambda p, k: DQN(config, envs.make("cartpole", episode_length=80)).evaluate(p, k, 8).mean())
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(0), 2), i))(jnp.arange(2))
    expected = np.asarray(longer(jax.tree.map(lambda x: x[:2], params), keys))
    best, measured = break_ties(dqn, "cartpole", {"episode_length": 20}, params, [20.0, 20.0, 3.0], 0)
    assert best == int(np.argmax(expected)) and measured == pytest.approx({0: expected[0], 1: expected[1]})
    # seeds 5 and 6 of a run (a process's slice): keyed by their index in the run, not in the slice
    _, sliced = break_ties(dqn, "cartpole", {"episode_length": 20}, params, [20.0, 20.0, 3.0], 0, first=5)
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.fold_in(jax.random.PRNGKey(0), 2), i))(jnp.arange(5, 7))
    assert sliced == pytest.approx(dict(zip((5, 6), np.asarray(longer(jax.tree.map(lambda x: x[:2], params), keys)))))


@pytest.mark.slow
def test_the_tie_break_compiled_for_every_seed_measures_as_the_tied_seeds_program():
    """Where at least half the seeds tie, a run on one GPU measures them with the tie-break's
    program for every seed (compiled beside training): the same returns as the tied seeds'
    own program, rows by their index in the run."""
    from agents import DQN, DQNConfig
    from agents.run import tie_break_program

    dqn = DQN(DQNConfig(hidden=(8,), eval_episodes=2), envs.make("cartpole", episode_length=20))
    params = jax.vmap(dqn.init)(seed_keys(0, 4)).params
    every_seed = tie_break_program(dqn, "cartpole", {"episode_length": 20})
    for returns in ([20.0, 3.0, 20.0, 20.0], [20.0, 3.0, 3.0, 20.0]):  # three of four tie; two of four
        expected = break_ties(dqn, "cartpole", {"episode_length": 20}, params, returns, 0, first=8)
        got = break_ties(dqn, "cartpole", {"episode_length": 20}, params, returns, 0, first=8, every_seed=every_seed)
        assert got[0] == expected[0] and got[1] == pytest.approx(expected[1], abs=1e-6)
        assert sorted(got[1]) == [8 + i for i, r in enumerate(returns) if r == 20.0]


# ---- slow: the README's PPO job, judged on Gymnasium ----------------------------------------
def _cli(*argv: str) -> list[str]:
    return [sys.executable, "-m", "agents.cli", *argv]


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "MJXSUITE_COMPILE_CACHE": "0"}


@pytest.mark.slow
def test_training_and_judging_a_ppo_run_need_no_rerun(tmp_path):
    """GPU machines may lack rerun-sdk (it is large): only --rerun and `rollout` may import it."""
    out = tmp_path / "run"
    no_rerun = "import sys; sys.modules['rerun'] = None; from agents.cli import main; sys.exit(main())"
    for argv in (["train", "--env", "pendulum-mjx", "--agent", "ppo", *TINY_PPO_ARGS, "--out", str(out)],
                 ["eval", "--checkpoint", str(out), "--episodes", "2"]):
        done = subprocess.run([sys.executable, "-c", no_rerun, *argv], env=_env(), capture_output=True, text=True)
        assert done.returncode == 0, done.stderr[-2000:]




def test_sweeps_name_another_agents_field_and_refuse_repeated_values(capsys):
    """`--gamma` on PPO is DQN's name for PPO's `discounting`; a value listed twice would train the
    same agents twice. Both refused before anything compiles, naming the fix."""
    with pytest.raises(UsageError, match=r"PPOConfig has no field gamma \(gamma is discounting here\)"):
        cli_main(["sweep", "--env", "pendulum-mjx", "--agent", "ppo", "--gamma", "0.9,0.99"])
    with pytest.raises(SystemExit):
        cli_main(["sweep", "--env", "cartpole", "--learning_rate", "1e-3,5e-4,1e-3"])
    assert "lists 0.001 more than once; give each value once" in capsys.readouterr().err


def test_a_gpu_sized_run_on_a_cpu_says_so_before_it_starts_naming_the_cpu_preset(capsys):
    from agents import commands

    hopper = PPOConfig(**brax_defaults.settings("hopper", "ppo"))
    commands.say_gpu_sized("hopper", "ppo", hopper, 1, gpus=[])
    said = capsys.readouterr().err
    cpu = PPOConfig(**brax_defaults.settings("hopper", "ppo", "cpu"))
    assert (f"hopper's PPO recipe trains {hopper.total_steps / 1e6:.1f}M env steps, sized for a GPU: on this CPU "
            f"that takes hours; --preset cpu trains a smaller one ({cpu.total_steps:,} env steps)") in said
    commands.say_gpu_sized("dmc-cartpole-balance", "ppo", PPOConfig(**brax_defaults.settings("dmc-cartpole-balance",
                                                                                      "ppo")), 1, gpus=[])
    td3 = TD3Config(**brax_defaults.settings("dmc-cartpole-balance", "td3", "cpu"))
    assert ("on this CPU that takes hours; --agent td3 --preset cpu trains a smaller one "
            f"({td3.total_steps:,} env steps)") in capsys.readouterr().err  # PPO has no cpu preset there
    pixels = TD3Config(**brax_defaults.settings("dmc-cartpole-balance", "td3", "pixels"))  # 0.5M steps: a CPU's hours
    commands.say_gpu_sized("dmc-cartpole-balance", "td3", pixels, 1, gpus=[], pixels=True)
    assert ("TD3 recipe from camera images trains 0.5M env steps, sized for a GPU: on this CPU that takes hours; camera "
            "images come from MJX's ray caster here") in capsys.readouterr().err
    hopper_td3 = TD3Config(**brax_defaults.settings("hopper", "td3"))  # 0.7M steps, 4 updates per 16: an hour's
    commands.say_gpu_sized("hopper", "td3", hopper_td3, 1, gpus=[])
    assert ("hopper's TD3 recipe trains 0.7M env steps, sized for a GPU: on this CPU that takes hours; --preset cpu "
            "trains a smaller one (300,064 env steps)") in capsys.readouterr().err
    cpu_td3 = TD3Config(**brax_defaults.settings("hopper", "td3", "cpu"))  # SAC's and TD3's limit is per seed
    assert brax_defaults.gpu_sized_note("hopper", "td3", cpu_td3.total_steps, 4) is None
    commands.say_gpu_sized("hopper", "ppo", hopper, 1, gpus=["0"])  # a GPU: nothing to say
    commands.say_gpu_sized("pendulum-mjx", "ppo", PPOConfig(num_timesteps=100_000), 1, gpus=[])
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("agent", ["ppo", "sac", "td3"])
def test_every_gymnasium_and_dm_control_task_has_a_cpu_preset_that_keeps_the_tasks_own_fields(agent):
    """`--preset cpu`: the task's row resized for a CPU (envs, batches, networks, steps), its reward
    scaling, discount, critic support and solve_return kept; nothing to warn about on a CPU. Every agent
    has it on Gymnasium's tasks, SAC and TD3 on dm_control's."""
    from agents import commands, registry

    dm_control = [name for name, *_ in envs.TASKS if name.startswith("dmc-")]
    assert len(dm_control) >= 39
    for task in dm_control:
        assert ("cpu" in brax_defaults.presets(task, agent)) == (agent != "ppo"), task
    for task in [*brax_defaults.GYMNASIUM_TASKS, *(dm_control if agent != "ppo" else [])]:
        assert "cpu" in brax_defaults.presets(task, agent)
        config = commands.agent_config(task, agent, "cpu", {}, None, None)
        row = brax_defaults.settings(task, agent)
        assert brax_defaults.gpu_sized_note(task, agent, config.total_steps, 1) is None, task
        base = registry.config_class(agent)()
        for field in ("reward_scaling", "discounting", "solve_return", "v_min", "v_max", "entropy_cost"):
            if field in row:
                assert getattr(config, field) == row[field], (task, field)
        if row.get("num_timesteps", 0) > brax_defaults.CPU_SIZES[agent]["num_timesteps"]:
            assert config.num_envs == brax_defaults.CPU_SIZES[agent]["num_envs"] <= 64, task
            for field in brax_defaults.CPU_DROPPED:
                if hasattr(base, field):
                    assert getattr(config, field) == getattr(base, field), (task, field)
    hopper = commands.agent_config("hopper", "ppo", "cpu", {"num_envs": "32"}, None, None)  # options still apply
    assert hopper.num_envs == 32 and hopper.num_evals == 21 and hopper.discounting == 0.99


def test_every_agent_says_how_it_rounded_the_steps():
    from agents import DQNConfig
    from agents.td3 import TD3Config

    assert DQNConfig(total_steps=2_500).rounding() == ("total_steps 2,500 rounded up to 3,000 env steps: 3 chunks "
                                                       "of eval_every 1,000")
    assert DQNConfig(total_steps=3_000).rounding() == ""
    for config in (SACConfig(num_timesteps=30_001), TD3Config(num_timesteps=30_001)):
        assert config.rounding().startswith(f"num_timesteps 30,001 rounded up to {config.total_steps:,} env steps")
    assert SACConfig(num_timesteps=SACConfig().total_steps).rounding() == ""


def test_sweep_wording_names_the_real_reason_and_takes_negative_lists(monkeypatch):
    """Issue 63, cases 17, 7 and 22: an agent that cannot be swept says so first (not a field's range);
    a value list that starts with a negative number is read as values; a sweep's agents are named as
    config and seed, as --seeds counts them."""
    from agents import commands

    with pytest.raises(UsageError, match="--agent sac runs cannot be swept"):
        cli_main(["sweep", "--env", "pendulum-mjx", "--agent", "sac", "--learning_rate", "1e-3,3e-4", "--steps", "9"])
    with pytest.raises(UsageError, match="DQNConfig.learning_rate must be"):  # read as values, then refused
        cli_main(["sweep", "--env", "cartpole", "--learning_rate", "-1e-3,1e-3"])
    seen = {}
    monkeypatch.setattr("agents.run.train_run", lambda env, config, **k: seen.update(config=config))
    monkeypatch.setattr("agents.commands._report", lambda *a: 0)
    assert cli_main(["train", "--env", "pendulum-mjx", "--agent", "td3", "--v_min", "-1e2", "--v-max", "1e2"]) == 0
    assert (seen["config"].v_min, seen["config"].v_max) == (-100.0, 100.0)
    assert [commands.agent_label(i, 2, {"gamma": [0.9, 0.99]}) for i in (0, 3)] == \
        ["agent 0 (config 0, seed 0)", "agent 3 (config 1, seed 1)"]
    assert commands.agent_label(3, 4, None) == "seed 3"
