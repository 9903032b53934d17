"""TD3 (`agents.td3`, FastTD3's recipe): its config, the C51 projection, exploration noise, the
delayed actor, bf16, seeds under map and vmap, exact resume (from a host copy of the train state,
and through `train_run` stopped and resumed), and a learning canary on a toy task."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_sac import assert_trees_equal, drift, mapped, run_chunks

import envs
from agents.sac import Transition, unpack
from agents.td3 import TD3, TD3Config, n_step_rows, project, train

SMALL = TD3Config(num_timesteps=392, num_envs=4, batch_size=16, num_updates=2, min_replay_size=32,
                  max_replay_size=256, num_evals=4, num_eval_envs=3, actor_hidden=(8,), critic_hidden=(8,),
                  num_atoms=11, v_min=-20.0, v_max=5.0)


# ---- the config ---------------------------------------------------------------------
def test_chunks_are_timed_as_sacs():
    config = TD3Config(num_timesteps=1000, num_envs=16, min_replay_size=100, num_evals=4, num_updates=3,
                       policy_frequency=2)
    assert config.prefill_steps == 112  # 100 rounded up to 7 batches of 16
    assert config.num_chunks == 3 and config.iterations_per_chunk == 19  # ceil(888 / (3 * 16))
    assert config.eval_every == 19 * 16 and config.total_steps == 112 + 3 * 304 >= config.num_timesteps
    assert config.actor_updates_per_chunk == 19 * 3 // 2
    assert SMALL.total_steps == SMALL.num_timesteps


@pytest.mark.parametrize("field,value,message", [
    ("num_envs", 0, "TD3Config.num_envs must be"),
    ("tau", 0.0, "TD3Config.tau must be"),
    ("discounting", 1.5, "TD3Config.discounting must be"),
    ("num_atoms", 1, "TD3Config.num_atoms must be"),
    ("policy_frequency", 0, "TD3Config.policy_frequency must be"),
    ("compute_dtype", "float16", "TD3Config.compute_dtype must be one of 'float32', 'bfloat16'"),
    ("actor_hidden", (), "TD3Config.actor_hidden needs at least one layer"),
    ("critic_hidden", (8, 0), "TD3Config.critic_hidden"),
    ("std_min", 0.5, r"std_min \(0.5\) must not exceed std_max \(0.4\); swap them"),
    ("v_min", 5.0, r"v_min \(5.0\) must be below v_max \(5.0\)"),
    ("min_replay_size", 392, "min_replay_size .* must be below num_timesteps"),
    ("max_replay_size", 8, "max_replay_size .* raise it to 32"),
    ("solve_return", float("nan"), "TD3Config.solve_return"),
    ("noise_correlation", 1.0, r"TD3Config.noise_correlation .* in \[0, 0.999\]"),
])
def test_bad_settings_are_refused_with_the_option_and_the_fix(field, value, message):
    base = dataclasses.replace(SMALL, std_max=0.4) if field == "std_min" else SMALL
    with pytest.raises(ValueError, match=message):
        dataclasses.replace(base, **{field: value})


def test_a_discrete_env_is_refused():
    with pytest.raises(ValueError, match="continuous-action env"):
        TD3(SMALL, envs.make("cartpole"))


@pytest.mark.parametrize("argv, message", [
    (["--env", "cartpole", "--agent", "td3"], "choose --agent dqn"),
    (["--env", "pendulum-mjx", "--agent", "td3", "--compute_dtype", "fp8"], "TD3Config.compute_dtype must be one of"),
    (["--env", "pendulum-mjx", "--agent", "td3", "--v_min", "60"], r"v_min \(60.0\) must be below v_max \(50.0\)"),
    (["--env", "pendulum-mjx", "--agent", "td3", "--replay", "prioritized"], "--replay chooses DQN's replay"),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_the_command_line_refuses_bad_td3_runs_before_anything_compiles(argv, message, monkeypatch):
    from agents.cli import UsageError
    from agents.cli import main as cli_main

    monkeypatch.setattr("agents.run.train_run", lambda *a, **k: pytest.fail("training started"))
    with pytest.raises(UsageError, match=message):
        cli_main(["train", *argv])


def test_the_command_line_takes_the_task_recipe_and_every_field(monkeypatch):
    from agents import brax_defaults
    from agents.cli import main as cli_main

    seen = {}
    monkeypatch.setattr("agents.run.train_run", lambda env, config, **k: seen.update(config=config, **k))
    monkeypatch.setattr("agents.commands._report", lambda *a: 0)
    argv = ["train", "--env", "hopper", "--agent", "td3", "--compute_dtype", "float32", "--actor_hidden", "64,64",
            "--use_cdq", "false", "--seeds", "4"]
    assert cli_main(argv) == 0
    assert seen["config"] == TD3Config(**{**brax_defaults.settings("hopper", "td3"), "compute_dtype": "float32",
                                          "actor_hidden": (64, 64), "use_cdq": False})
    assert seen["seeds"] == 4


# ---- the distributional critic's projection ----------------------------------------------
def test_the_projection_moves_the_mean_keeps_the_mass_and_clips_to_the_support():
    support = jnp.linspace(-10.0, 10.0, 21)
    probs = jax.nn.softmax(jax.random.normal(jax.random.PRNGKey(0), (6, 21)))
    same = project(probs, jnp.zeros(6), jnp.ones(6), support)
    np.testing.assert_array_equal(np.asarray(same), np.asarray(probs))  # on the atoms: unchanged
    reward, discount = jnp.array([0.3, -1.7, 2.0, 0.0, 0.55, 0.25]), jnp.array([0.9, 0.5, 0.0, 0.99, 0.7, 0.1])
    moved = project(probs, reward, discount, support)
    np.testing.assert_allclose(np.asarray(moved.sum(-1)), 1.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray((moved * support).sum(-1)),
                               np.asarray(reward + discount * (probs * support).sum(-1)), rtol=1e-5, atol=1e-5)
    assert float(moved[2, 12]) == pytest.approx(1.0)  # discount 0: all mass on the reward, 2.0
    beyond = project(probs, jnp.full(6, 100.0), jnp.ones(6), support)
    np.testing.assert_allclose(np.asarray(beyond[:, -1]), 1.0, rtol=1e-6)  # clipped onto v_max


# ---- acting and the actor's schedule ---------------------------------------------------------
@pytest.mark.slow  # a compile of its own
def test_each_env_keeps_its_noise_scale_until_its_episode_ends():
    config = dataclasses.replace(SMALL, min_replay_size=0, std_min=0.1, std_max=0.3)
    td3 = TD3(config, drift(episode_length=3))
    ts = jax.jit(td3.init)(jax.random.PRNGKey(0))
    collect = jax.jit(td3.collect)
    scales = [np.asarray(ts.noise_scale)]
    for i in range(6):
        ts, _ = collect(ts, jax.random.PRNGKey(i))
        scales.append(np.asarray(ts.noise_scale))
    scales = np.stack(scales)
    assert np.all((scales >= 0.1) & (scales <= 0.3)) and len(np.unique(scales[0])) == config.num_envs
    # Episodes of 3 steps: the scale holds within an episode and is drawn anew at steps 3 and 6.
    np.testing.assert_array_equal(scales[1], scales[0])
    np.testing.assert_array_equal(scales[2], scales[0])
    assert np.all(scales[3] != scales[2]) and np.all(scales[6] != scales[5])
    np.testing.assert_array_equal(scales[5], scales[3])


@pytest.mark.parametrize("correlation", [pytest.param(0.0, marks=pytest.mark.slow), 0.9])  # white noise: slow
def test_correlated_noise_keeps_its_std_and_carries_over_from_step_to_step(correlation):
    """noise_correlation c: each env's noise is AR(1), so consecutive actions' noise correlates by c at the
    same std (the actor does not learn in `collect`, and without a normalizer acts as it did on each row)."""
    config = dataclasses.replace(SMALL, num_envs=64, min_replay_size=0, max_replay_size=4096, std_min=0.2,
                                 std_max=0.2, noise_correlation=correlation, normalize_observations=False)
    td3 = TD3(config, drift(episode_length=1000))
    ts = jax.jit(td3.init)(jax.random.PRNGKey(0))
    collect = jax.jit(td3.collect)
    for i in range(48):
        ts, _ = collect(ts, jax.random.PRNGKey(i))
    rows = unpack(ts.buffer.data[:int(ts.buffer.size)], td3.obs_size, td3.action_size)
    noise = np.asarray(rows.action - td3.policy(ts.params, rows.obs)).reshape(48, 64, -1)
    assert noise.std() == pytest.approx(0.2, rel=0.1)
    lag_one = np.corrcoef(noise[1:].ravel(), noise[:-1].ravel())[0, 1]
    assert lag_one == pytest.approx(correlation, abs=0.06)


def collected(env, steps, num_steps):
    td3 = TD3(dataclasses.replace(SMALL, num_envs=1, min_replay_size=0, num_steps=num_steps), env)
    ts = jax.jit(td3.init)(jax.random.PRNGKey(0))
    collect = jax.jit(td3.collect)
    for i in range(steps):
        ts, _ = collect(ts, jax.random.PRNGKey(i))
    return jax.tree.map(np.asarray, unpack(ts.buffer.data[:int(ts.buffer.size)], 2, 1))


@pytest.mark.slow  # a compile of its own; the resume test runs n-step rows in the default run
def test_n_step_rows_sum_discounted_rewards_up_to_the_episode_end():
    """Three-step rows against the one-step rows of the same run (the same actions): each sums
    up to three rewards, stops at a termination (no bootstrap) or a truncation (bootstrapping
    from that final observation), and its discount is gamma**(steps - 1) * (1 - terminated)."""
    env, gamma = drift(episode_length=4, terminate_at=0.9), SMALL.discounting
    one, three = collected(env, 12, 1), collected(env, 12, 3)
    assert len(one.reward) == 12 and len(three.reward) == 10  # the last two steps' rows are not complete yet
    ends = (one.discount == 0) | (np.round(one.next_obs[:, 1] * 10) == 4)  # terminated, or truncated at 4 steps
    assert ends[:10].sum() >= 3 and (one.discount[:10] == 0).any()
    for t in range(10):
        reward, k = 0.0, t
        while True:
            reward += gamma ** (k - t) * one.reward[k]
            if ends[k] or k == t + 2:
                break
            k += 1
        np.testing.assert_allclose(three.reward[t], reward, rtol=1e-5)
        np.testing.assert_allclose(three.discount[t], gamma ** (k - t) * one.discount[k], rtol=1e-6)
        np.testing.assert_array_equal(three.next_obs[t], one.next_obs[k])
        np.testing.assert_array_equal(three.obs[t], one.obs[t])


def test_an_n_step_row_is_finite_when_a_step_after_its_end_is_not_physics():
    """The step after an episode's end is the next episode's; a NaN reward there is not the row's (it is stored)."""
    steps = Transition(obs=jnp.zeros((3, 1, 2)), action=jnp.zeros((3, 1, 1)), reward=jnp.array([[1.0], [2.0], [jnp.nan]]),
                       discount=jnp.ones((3, 1)), next_obs=jnp.zeros((3, 1, 2)))
    row, keep = n_step_rows(steps, ended=jnp.array([[0.0], [1.0], [1.0]]), valid=jnp.array([[1.0], [1.0], [0.0]]),
                            discounting=0.5)
    assert bool(keep[0]) and float(row.reward[0]) == 2.0 and float(row.discount[0]) == 0.5


@pytest.mark.parametrize("policy_frequency,actor_steps", [(2, 1), (4, 0)])
def test_the_actor_steps_once_every_policy_frequency_critic_updates(policy_frequency, actor_steps):
    td3 = TD3(dataclasses.replace(SMALL, policy_frequency=policy_frequency), drift())
    ts = jax.jit(td3.init)(jax.random.PRNGKey(0))
    new, stats = jax.jit(td3.update)(ts, jax.random.PRNGKey(1), jnp.asarray(0))  # updates 0 and 1 of a chunk
    assert int(new.actor_opt_state[0].count) == actor_steps
    assert int(new.critic_opt_state[0].count) == 2
    moved = not all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(new.params[1]), jax.tree.leaves(ts.params[1])))
    assert moved == bool(actor_steps) and (float(stats["actor_loss"]) != 0.0) == bool(actor_steps)


def test_the_delayed_actor_stays_a_branch_when_seeds_are_vmapped():
    """Its schedule is the same for every seed, so under vmap the actor's update is skipped, not
    computed and thrown away (a batched predicate would turn the cond into a select)."""
    td3 = TD3(SMALL, drift())
    ts = jax.eval_shape(jax.vmap(td3.init), jax.random.split(jax.random.PRNGKey(0), 3))
    assert str(jax.make_jaxpr(jax.vmap(td3.train_steps))(ts)).count("cond[") == 1


@pytest.mark.slow  # a compile of its own
def test_bfloat16_runs_the_networks_matmuls_in_bf16_with_float32_params():
    td3 = TD3(dataclasses.replace(SMALL, compute_dtype="bfloat16"), drift())
    ts = jax.jit(td3.init)(jax.random.PRNGKey(0))
    assert all(leaf.dtype == jnp.float32 for leaf in jax.tree.leaves((ts.params[1], ts.critic_params)))
    text = str(jax.make_jaxpr(td3.critic_loss)(ts.critic_params, ts, td3_batch(td3, ts), jax.random.PRNGKey(1)))
    assert "bf16" in text
    actions = jax.jit(td3.policy)(ts.params, jnp.zeros((5, 2)))
    assert actions.dtype == jnp.float32
    ts, trained, _ = jax.jit(td3.train_steps)(ts)
    assert np.isfinite(float(trained["critic_loss"])) and np.isfinite(float(trained["actor_loss"]))


def test_the_layer_norm_critic_normalizes_each_hidden_layer_before_its_relu():
    from agents.td3 import DistributionalQ
    obs, action = jax.random.normal(jax.random.PRNGKey(1), (4, 3)), jax.random.normal(jax.random.PRNGKey(2), (4, 2))
    critic = DistributionalQ(num_atoms=5, hidden=(8, 6), layer_norm=True)
    params = critic.init(jax.random.PRNGKey(0), obs, action)
    p = jax.tree.map(np.asarray, params["params"])
    x = np.concatenate([obs, action], axis=-1)
    for i in range(2):  # numpy's layer norm (flax's epsilon, 1e-6), then ReLU
        x = x @ p[f"Dense_{i}"]["kernel"] + p[f"Dense_{i}"]["bias"]
        x = (x - x.mean(-1, keepdims=True)) / np.sqrt(x.var(-1, keepdims=True) + 1e-6)
        x = np.maximum(x * p[f"LayerNorm_{i}"]["scale"] + p[f"LayerNorm_{i}"]["bias"], 0.0)
    expected = x @ p["Dense_2"]["kernel"] + p["Dense_2"]["bias"]
    np.testing.assert_allclose(critic.apply(params, obs, action), expected, rtol=1e-5, atol=1e-5)
    plain = DistributionalQ(num_atoms=5, hidden=(8, 6)).init(jax.random.PRNGKey(0), obs, action)["params"]
    assert sorted(plain) == ["Dense_0", "Dense_1", "Dense_2"]


@pytest.mark.parametrize("penalty", [0.0, 1e-3])
def test_the_pre_tanh_penalty_alone_pulls_a_saturated_actor_off_its_bound(penalty):
    """With a flat critic (its last layer zeroed: every action the same value) and an actor held at
    +1 (its head's bias 5), only the penalty moves the actor (no weight decay), towards 0."""
    td3 = TD3(dataclasses.replace(SMALL, pre_tanh_penalty=penalty, weight_decay=0.0), drift())
    ts = jax.jit(td3.init)(jax.random.PRNGKey(0))
    last = f"Dense_{len(SMALL.critic_hidden)}"
    flat = jax.tree.map(jnp.zeros_like, ts.critic_params["params"][last])
    critic = {"params": {**ts.critic_params["params"], last: flat}}
    normalizer, actor = ts.params
    head = f"Dense_{len(SMALL.actor_hidden)}"
    saturated = {"params": {**actor["params"], head: {**actor["params"][head], "bias": jnp.full(td3.action_size, 5.0)}}}
    ts = ts.replace(params=(normalizer, saturated), critic_params=critic)
    batch = td3_batch(td3, ts)
    obs = td3.inputs.features(normalizer, None, batch.obs)
    _, pre_tanh = td3.actor.apply(saturated, obs, with_pre_tanh=True)
    loss, saturation = td3.actor_loss(saturated, ts, obs)
    np.testing.assert_allclose(loss, -td3.twin_values(jnp.full(SMALL.num_atoms, 1 / SMALL.num_atoms))
                               + penalty * np.mean(np.square(pre_tanh)), rtol=1e-5)
    assert saturation == 1.0 and td3.actor_loss(actor, ts, obs)[1] == 0.0  # the metric tells the held actor apart
    moved, _ = td3.step_actor(ts, obs)
    bias = moved.params[1]["params"][head]["bias"]
    if penalty:
        assert np.all(np.asarray(bias) < 5.0)
    else:
        np.testing.assert_array_equal(bias, 5.0)


@pytest.mark.slow  # a compile of its own
def test_a_uniform_first_fill_spreads_its_actions_over_the_box():
    """DrQ-v2 acts uniformly at random for its first steps (num_expl_steps); TD3's untrained actor with
    its noise (std at most std_max, 0.4) keeps near 0, so a critic learns little about the bounds."""
    def first_fill_actions(uniform):
        td3 = TD3(dataclasses.replace(SMALL, uniform_first_fill=uniform), drift())
        ts = jax.jit(td3.init)(jax.random.PRNGKey(0))
        return np.asarray(unpack(ts.buffer.data[:SMALL.min_replay_size], td3.obs_size, td3.action_size).action)

    uniform, actor = first_fill_actions(True), first_fill_actions(False)
    assert np.abs(uniform).max() <= 1.0 and 0.45 < uniform.std() < 0.7 and np.abs(uniform).max() > 0.9
    assert actor.std() < 0.4


def td3_batch(td3, ts):
    return unpack(ts.buffer.data[:8], td3.obs_size, td3.action_size)


# ---- seeds and exact resume -----------------------------------------------------------------
@pytest.mark.heavy  # three compiles of pendulum-mjx programs; the resume test below keeps one in the default run
def test_seed_i_of_a_batched_run_is_a_one_seed_run_of_seed_i():
    """Seeds mapped (train_run's way on the CPU) are one-seed runs bit for bit; vmapped (its way on
    accelerators) they agree to float rounding (Brax's normalizer divides by a per-seed count)."""
    td3 = TD3(SMALL, drift())
    keys = jax.random.split(jax.random.PRNGKey(7), 2)
    singles = [run_chunks(td3, jax.jit(td3.init)(key), SMALL.num_chunks)[0] for key in keys]
    ts, _ = run_chunks(td3, jax.jit(mapped(td3.init))(keys), SMALL.num_chunks, mapped)
    vmapped, history = run_chunks(td3, jax.jit(jax.vmap(td3.init))(keys), SMALL.num_chunks, jax.vmap)
    for i, single in enumerate(singles):
        assert_trees_equal(jax.tree.map(lambda x: x[i], ts), single)
        for a, b in zip(jax.tree.leaves(jax.tree.map(lambda x: x[i], vmapped)), jax.tree.leaves(single), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-5)
    assert int(singles[0].env_steps) == SMALL.total_steps
    assert int(singles[0].buffer.size) == SMALL.max_replay_size  # every step stored, and the buffer wrapped
    first = [np.asarray(jax.tree.leaves(s.params[1])[0]) for s in singles]
    assert not np.allclose(first[0], first[1])  # independent keys, different agents
    assert {"critic_loss", "actor_loss", "target_q", "episodes", "train_return", "nan_episodes", "env_steps",
            "eval_return", "best_return"} <= set(history[0])
    assert all(np.isfinite(np.asarray(history[-1][k])).all() for k in ("critic_loss", "actor_loss", "eval_return"))


@pytest.mark.slow  # its kill -9 twin is slow too; PPO's resume and the DQN lifecycle tests run by default
def test_a_run_resumed_from_a_host_copy_of_its_state_ends_as_the_uninterrupted_run():
    """The whole state of a seed (replay, noise scales, correlated noise, the n-step window and envs
    included) is the train state: copied to numpy after a chunk and back, the run continues bit for bit."""
    td3 = TD3(dataclasses.replace(SMALL, num_steps=2, noise_correlation=0.5), drift())
    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    init = jax.jit(jax.vmap(td3.init))
    whole, whole_history = run_chunks(td3, init(keys), SMALL.num_chunks, jax.vmap)
    part, _ = run_chunks(td3, init(keys), 1, jax.vmap)
    saved = jax.tree.map(np.asarray, part)
    assert int(saved.buffer.size[0]) > SMALL.prefill_steps and saved.window[1].shape == (2, 2, SMALL.num_envs)
    resumed, resumed_history = run_chunks(td3, jax.tree.map(jnp.asarray, saved), SMALL.num_chunks - 1, jax.vmap)
    assert_trees_equal(resumed, whole)
    np.testing.assert_array_equal(resumed_history[-1]["eval_return"], whole_history[-1]["eval_return"])


TINY = TD3Config(num_timesteps=640, num_envs=8, min_replay_size=128, max_replay_size=256, batch_size=32,
                 num_updates=1, num_evals=4, num_eval_envs=4, actor_hidden=(16,), critic_hidden=(16,),
                 num_atoms=21, v_min=-20.0, v_max=5.0)


@pytest.mark.heavy  # compiles pendulum-mjx's programs three times (as test_agents_cli's SAC resume)
def test_train_run_stopped_then_resumed_is_the_uninterrupted_run(tmp_path):
    from test_agents_cli import _leaves

    from agents.run import train_run

    whole = train_run("pendulum-mjx", TINY, seeds=2, out_dir=tmp_path / "whole", progress=False, judge_every=1)
    train_run("pendulum-mjx", TINY, seeds=2, out_dir=tmp_path / "part", progress=False, stop_after_chunks=1,
              judge_every=1)
    resumed = train_run("pendulum-mjx", TINY, seeds=2, out_dir=tmp_path / "part", progress=False, resume=True)
    for a, b in zip(_leaves(tmp_path / "whole"), _leaves(tmp_path / "part"), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert resumed.mean_return == whole.mean_return


@pytest.mark.heavy  # a compiling subprocess, killed, then resumed
def test_kill_9_after_a_checkpoint_then_resume_is_exact(tmp_path):
    """`mjxsuite train --agent td3` killed with SIGKILL once a checkpoint exists, then `--resume`:
    the uninterrupted run's train state, replay included (test_agents_cli's harness)."""
    from test_agents_cli import kill_9_then_resume

    kill_9_then_resume(tmp_path, "td3", dataclasses.replace(TINY, num_evals=7), judge_every=1)


# ---- learning -----------------------------------------------------------------------------------
CANARY = TD3Config(num_timesteps=4000, num_envs=8, batch_size=64, num_updates=2, min_replay_size=64,
                   max_replay_size=4096, num_evals=4, num_eval_envs=16, actor_hidden=(32, 32),
                   critic_hidden=(64, 64), num_atoms=51, v_min=-20.0, v_max=5.0)


@pytest.mark.slow  # a training to a threshold
def test_td3_learns_to_hold_the_drifting_point_at_zero():
    """A canary: Drift's untrained actor leaves the point where it starts (x ~ U(-1, 1), about -6.7
    a 20-step episode); the trained one pushes it to zero within a few steps."""
    env = drift()
    td3 = TD3(CANARY, env)
    key = jax.random.PRNGKey(0)
    untrained = jax.jit(td3.evaluate)(jax.jit(td3.init)(key).params, key).mean()
    best, metrics = jax.jit(lambda k: train(CANARY, env, k))(key)
    assert float(untrained) < -4.0, untrained
    assert float(metrics["eval_return"][-1]) > -1.5, metrics["eval_return"]
    assert np.all(np.asarray(metrics["nan_episodes"]) == 0)


@pytest.mark.parametrize("task", ["walker2d", "half-cheetah", "ant", "humanoid"])
def test_the_gymnasium_tasks_have_fasttd3_recipes(task):
    from agents import brax_defaults

    config = TD3Config(**brax_defaults.settings(task, "td3"))
    assert config.num_envs == 1024 and config.batch_size == 32768 and config.compute_dtype == "bfloat16"
    assert config.critic_hidden == (1024, 512, 256) and config.v_min < 0 < config.v_max
    # TD3 where its ten-minute run met issue 65's goal (docs/agents.md, "GPU results"); SAC where SAC's did
    assert brax_defaults.default_agent(task) == ("sac" if task == "half-cheetah" else "td3")


def test_hoppers_td3_recipe_is_fasttd3s_learning_at_the_cpu_sizes_with_a_layernorm_critic():
    """Hopper wants updates, not envs (docs/agents.md): its row is the "cpu" preset with the LayerNorm critic, trained
    for a GPU's ten minutes; TD3 is hopper's agent without --agent."""
    from agents import brax_defaults

    row = brax_defaults.settings("hopper", "td3")
    assert row == {**brax_defaults.settings("hopper", "td3", "cpu"), "num_timesteps": 700_000}
    assert brax_defaults.default_agent("hopper") == "td3"
    config = TD3Config(**row)
    assert (config.num_envs, config.batch_size, config.num_updates, config.critic_layer_norm) == (16, 256, 4, True)
    assert (config.tau, config.std_max, config.num_atoms) == (0.1, 0.4, 101)  # FastTD3's learning settings


def dm_control_td3_row():
    """`_DMC_TD3` as `settings` gives it, less a task's goal: walker walk's row without its solve_return."""
    from agents import brax_defaults

    return {k: v for k, v in brax_defaults.settings("dmc-walker-walk", "td3").items() if k != "solve_return"}


def test_td3_recipes_with_correlated_noise_are_the_dm_control_recipe_with_it():
    """Hopper stand's seeds learned to get up from both sides more often with AR(1) noise of correlation 0.97
    (docs/tasks.md, "Hopper stand with correlated noise"); its row is the dm_control recipe with that and 13 chunks of
    1.024M steps (the ten minutes filled). Hopper hop's seeds hopped with that noise and the swing-ups' discount 0.99
    ("Hopper hop with correlated noise"), where white noise left them at 1; humanoid walk's and the acrobot's seeds,
    near their floor with white noise, learned with both ("Humanoid walk and the acrobot with correlated noise").
    TD3 is their agent without --agent."""
    from agents import brax_defaults

    stand = brax_defaults.settings("dmc-hopper-stand", "td3")
    walk = brax_defaults.settings("dmc-walker-walk", "td3")
    assert stand == {**walk, "noise_correlation": 0.97, "num_timesteps": 13_312_000, "num_evals": 14, "solve_return": 700.0}
    for task in ("dmc-hopper-hop", "dmc-humanoid-walk", "dmc-acrobot-swingup"):
        row = brax_defaults.settings(task, "td3")
        assert row == {**dm_control_td3_row(), "noise_correlation": 0.97, "discounting": 0.99, "v_max": 100.0}, task
        assert TD3Config(**row).noise_correlation == 0.97 and brax_defaults.default_agent(task) == "td3"
    assert TD3Config(**walk).noise_correlation == 0.0 and brax_defaults.default_agent("dmc-hopper-stand") == "td3"


@pytest.mark.slow  # two compiles of pendulum-mjx's programs
def test_td3_speed_times_seeds_vmapped_and_mapped():
    """`python -m benchmarks.td3_speed --seed-axis map|vmap`: image networks' seeds are mapped on a GPU, so
    their speed is measured both ways; XLA's flop count is taken where the backend gives one."""
    from benchmarks import td3_speed

    small = dict(num_envs=8, batch_size=32, num_updates=2, min_replay_size=64, actor_hidden=(16,), critic_hidden=(16,))
    for axis in ("vmap", "map"):
        record = td3_speed.measure("pendulum-mjx", 2, small, iterations=2, repeats=1, parts=("act", "learn"),
                                   seed_axis=axis)
        assert record["seed_axis"] == axis and record["learn_gflop_per_update"] > 0
        assert record["act_env_steps_per_s_per_seed"] > 0 and record["learn_updates_per_s_per_seed"] > 0


def test_a_run_saved_with_a_retired_config_field_still_loads_and_an_unknown_one_says_so(tmp_path):
    """`image_seeds` (removed: it chose how a GPU batched pixel seeds) is left out of a saved run's
    config; a field no version had is a CheckpointError naming it."""
    from agents import checkpoint

    record = {"agent": "td3", "env": "pendulum-mjx", "seeds": 1, "config": dataclasses.asdict(TD3Config())}
    record["config"]["image_seeds"] = "vmap"
    (tmp_path / checkpoint.CONFIG_FILE).write_text(json.dumps(record))
    assert checkpoint.load_config(tmp_path).config == TD3Config()
    record["config"]["no_such_field"] = 1
    (tmp_path / checkpoint.CONFIG_FILE).write_text(json.dumps(record))
    with pytest.raises(checkpoint.CheckpointError, match="another mjxsuite version.*no_such_field"):
        checkpoint.load_config(tmp_path)


def test_td3_speed_refuses_a_part_it_does_not_time(capsys):
    from benchmarks import td3_speed

    with pytest.raises(SystemExit) as exit_info:
        td3_speed.main(["--parts", "learn,learn_blocks"])
    assert exit_info.value.code == 2 and "no part learn_blocks; the parts are act,learn" in capsys.readouterr().err


@pytest.mark.parametrize("task", ["dmc-finger-turn-hard", "dmc-fish-upright"])
def test_td3_is_the_default_agent_where_its_first_run_on_the_task_learned(task):
    """Finger turn_hard (822 at 4.1M steps, half of an H100) and fish upright (555 at 1M, a fifth) learned with the
    dm_control recipe itself (docs/tasks.md, "The other benchmarking tasks"); no other agent ran on them, so TD3 is
    their agent without --agent, on the recipe's row with no per-task change."""
    from agents import brax_defaults

    assert brax_defaults.default_agent(task) == "td3" and brax_defaults.settings(task, "td3") == dm_control_td3_row()
