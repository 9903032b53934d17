"""DQN: targets, truncation handling, determinism, checkpoint/resume, policy loading, CLI errors."""

import dataclasses
import json
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import USERS_CODEGEN
from jax.flatten_util import ravel_pytree

import envs
from agents import DQN, DQNConfig, checkpoint, device_options, load_policy, train, train_run
from agents.cli import main as cli_main
from agents.dqn import greedy, unpack
from agents.run import CLOCK_KEYS, _train_steps, run_keys, seed_batched


class Counter(envs.Env):
    """obs = [steps taken]; reward 1; terminates at `terminate_at` steps if given."""

    observation_size = 1
    num_actions = 2

    def __init__(self, terminate_at=None):
        self.terminate_at = terminate_at

    def reset(self, key):
        zero = jnp.zeros(())
        return envs.State(jnp.zeros(()), jnp.zeros((1,)), zero, zero, info={"truncation": zero, "nan": zero})

    def step(self, state, action):
        self.check_action(action)
        t = state.pipeline_state + 1
        done = jnp.zeros(()) if self.terminate_at is None else (t >= self.terminate_at).astype(jnp.float32)
        return state.replace(pipeline_state=t, obs=t[None], reward=jnp.ones(()), done=done)


SMALL = DQNConfig(total_steps=400, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                  eval_episodes=4, hidden=(16,))


def collected_rows(env, steps=7):
    dqn = DQN(SMALL, env)
    ts = dqn.init(jax.random.PRNGKey(0))
    for _ in range(steps):
        ts, _ = dqn.collect(ts, 1.0)
    rows = np.asarray(ts.buffer.data[:steps])
    return dqn, ts, unpack(jnp.asarray(rows), 1)


def test_truncation_bootstraps_from_the_true_final_observation():
    dqn, ts, batch = collected_rows(envs.TimeLimit(Counter(), episode_length=3))
    np.testing.assert_array_equal(np.asarray(batch.terminated), 0.0)  # only truncation ends episodes
    # Episodes of 3 steps: next_obs is 1, 2, 3 then 1, 2, 3 ... never the reset observation 0.
    np.testing.assert_array_equal(np.asarray(batch.next_obs[:, 0]), [1, 2, 3, 1, 2, 3, 1])
    np.testing.assert_array_equal(np.asarray(batch.obs[:, 0]), [0, 1, 2, 0, 1, 2, 0])
    targets = dqn.td_targets(ts.params, ts.params, batch)
    next_q = dqn.q_values(ts.params, batch.next_obs).max(-1)  # double DQN picks argmax of the same net here
    np.testing.assert_allclose(np.asarray(targets), np.asarray(1.0 + SMALL.gamma * next_q), rtol=1e-6)


def test_termination_does_not_bootstrap():
    dqn, ts, batch = collected_rows(envs.TimeLimit(Counter(terminate_at=3), episode_length=100))
    np.testing.assert_array_equal(np.asarray(batch.terminated), [0, 0, 1, 0, 0, 1, 0])
    targets = np.asarray(dqn.td_targets(ts.params, ts.params, batch))
    np.testing.assert_allclose(targets[[2, 5]], 1.0)
    assert np.all(np.abs(targets[[0, 1, 3, 4, 6]] - 1.0) > 1e-6)


@pytest.mark.parametrize("num_actions", [1, 2, 3, 5])
def test_greedy_is_jnp_argmax_and_the_value_there(num_actions):
    rng = np.random.default_rng(num_actions)
    q = rng.normal(size=(6, 40, num_actions)).astype(np.float32)
    q[:, :10] = np.round(q[:, :10])  # ties
    special = [np.nan, np.inf, -np.inf, 0.0, -0.0]
    q[:, 10:30] = rng.choice(special, size=(6, 20, num_actions))  # NaN, infinities and signed zeros
    action, value = jax.jit(greedy)(jnp.asarray(q))
    expected = np.asarray(jnp.argmax(jnp.asarray(q), axis=-1))
    np.testing.assert_array_equal(np.asarray(action), expected)
    assert action.dtype == jnp.int32
    np.testing.assert_array_equal(np.asarray(value), np.take_along_axis(q, expected[..., None], axis=-1)[..., 0])


def test_run_keys_are_the_seed_keys_split_and_the_evaluations_folded_in():
    training, evaluation = run_keys(3, 5)
    np.testing.assert_array_equal(training, jax.random.split(jax.random.PRNGKey(3), 5))
    np.testing.assert_array_equal(evaluation, jax.random.split(jax.random.fold_in(jax.random.PRNGKey(3), 1), 5))


def test_train_is_deterministic_and_vmaps_over_seeds():
    env = envs.make("cartpole")
    run = jax.jit(jax.vmap(lambda k: train(SMALL, env, k)))
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    (params_a, metrics_a), (params_b, _) = run(keys), run(keys)
    for a, b in zip(jax.tree.leaves(params_a), jax.tree.leaves(params_b)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # Independent keys give different agents.
    first = jax.tree.leaves(params_a)[0]
    assert not np.allclose(np.asarray(first[0]), np.asarray(first[1]))
    assert metrics_a["eval_return"].shape == (2, SMALL.num_chunks)


@pytest.mark.parametrize("name,replay", [("cartpole", "uniform"), ("cartpole", "prioritized"),
                                         pytest.param("cartpole-mjx", "uniform", marks=pytest.mark.slow)])
@pytest.mark.slow
def test_resume_reproduces_the_uninterrupted_run(tmp_path, name, replay):
    config = DQNConfig(**{**SMALL.__dict__, "replay": replay})
    whole = train_run(name, config, seeds=2, out_dir=tmp_path / "whole", progress=False)
    part = train_run(name, config, seeds=2, out_dir=tmp_path / "part", progress=False, stop_after_chunks=2)
    assert part.params is None  # stopped early
    resumed = train_run(name, config, seeds=2, out_dir=tmp_path / "part", progress=False, resume=True)
    for a, b in zip(jax.tree.leaves(whole.train_state), jax.tree.leaves(resumed.train_state)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    summary = json.loads((tmp_path / "whole" / "eval.json").read_text())
    assert summary["env"] == name and summary["seeds"] == 2 and len(summary["mean_return"]) == 2
    lines = (tmp_path / "whole" / "metrics.jsonl").read_text().splitlines()
    assert len(lines) == config.num_chunks and "eval_return" in json.loads(lines[-1])


def test_a_finished_runs_checkpoint_leaves_the_replay_out_and_resumes_to_its_evaluation(tmp_path):
    """The final save of a finished run skips the replay buffers (nothing reads them after the last
    chunk: most of a large run's bytes); a stopped run's checkpoint keeps them; --resume of the
    finished run compiles no training chunk and evaluates as the run did."""
    whole = train_run("cartpole", SMALL, seeds=2, out_dir=tmp_path / "whole", progress=False)
    part = train_run("cartpole", SMALL, seeds=2, out_dir=tmp_path / "part", progress=False, stop_after_chunks=2)
    (finished_meta, finished), (stopped_meta, stopped) = (
        checkpoint.read_leaves(out / checkpoint.STATE_FILE, "train_state") for out in (tmp_path / "whole", tmp_path / "part"))
    buffer_leaves = len(jax.tree.leaves(part.train_state.buffer))
    assert finished_meta["replay_left_out"] and not stopped_meta["replay_left_out"]
    assert len(finished) == len(stopped) - buffer_leaves
    expected = jax.tree.leaves(checkpoint.without_replay(whole.train_state))
    for a, b in zip(finished, expected, strict=True):
        np.testing.assert_array_equal(a, np.asarray(b))
    again = train_run("cartpole", SMALL, seeds=2, out_dir=tmp_path / "whole", progress=False, resume=True)
    assert again.train_state.buffer is None and again.history == [] and again.mean_return == whole.mean_return


def test_dispatching_the_next_chunk_ahead_changes_nothing():
    """Without `on_chunk` the next chunk starts before the host reads this one's metrics; with it,
    after: the same train state and metrics either way."""
    ahead = train_run("cartpole", SMALL, seeds=2, progress=False, judge_every=1)
    seen = []
    in_turn = train_run("cartpole", SMALL, seeds=2, progress=False, judge_every=1,
                        on_chunk=lambda index, ts, record: seen.append(index))
    assert seen == list(range(SMALL.num_chunks))
    for a, b in zip(jax.tree.leaves(ahead.train_state), jax.tree.leaves(in_turn.train_state), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    drop = set(CLOCK_KEYS)
    assert [{k: v for k, v in r.items() if k not in drop} for r in ahead.history] == \
        [{k: v for k, v in r.items() if k not in drop} for r in in_turn.history]


def test_load_policy_acts_greedily_on_one_or_many_observations(tmp_path):
    train_run("cartpole", SMALL, seeds=1, out_dir=tmp_path, progress=False)
    policy = load_policy(tmp_path)
    one = policy(np.zeros(4))
    many = policy(np.zeros((5, 4)))
    assert one.shape == () and many.shape == (5,) and many.dtype == np.int64
    assert set(np.unique(many)) <= {0, 1}
    with pytest.raises(ValueError, match="size 4"):
        policy(np.zeros(3))


def test_cli_train_and_eval(tmp_path, capsys):
    out = tmp_path / "run"
    code = cli_main(["train", "--env", "cartpole", "--steps", "200", "--out", str(out), "--eval_every", "100",
                     "--learning_starts", "64", "--eval-episodes", "4", "--hidden", "16"])
    assert code == 0
    assert {p.name for p in out.iterdir()} >= {"config.json", "metrics.jsonl", "eval.json", "best_params.ckpt",
                                                 "train_state.ckpt"}
    assert cli_main(["eval", "--checkpoint", str(out), "--episodes", "3"]) == 0
    assert '"episodes": 3' in capsys.readouterr().out


def test_cli_rejects_bad_input(tmp_path):
    with pytest.raises(SystemExit, match="unknown env 'nope'"):
        cli_main(["train", "--env", "nope"])
    with pytest.raises(SystemExit, match="unknown option --lerning_rate"):
        cli_main(["train", "--env", "cartpole", "--lerning_rate", "1"])
    with pytest.raises(SystemExit, match="target_update must be one of"):
        cli_main(["train", "--env", "cartpole", "--target_update", "soft"])
    with pytest.raises(SystemExit, match="bad value for --batch_size"):
        cli_main(["train", "--env", "cartpole", "--batch_size", "many"])


def test_unwritable_output_fails_before_training(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(ValueError, match="not a directory"):
        train_run("cartpole", SMALL, out_dir=blocker, progress=False)
    # /proc refuses new entries even to root.
    with pytest.raises(ValueError, match="cannot write"):
        train_run("cartpole", SMALL, out_dir="/proc/mjxsuite-test", progress=False)


@pytest.mark.slow
def test_every_option_trains_with_finite_losses():
    """Dueling head, prioritized replay, Huber loss, hard target copies, 4 envs, 2 updates every 2 steps."""
    config = DQNConfig(**{**SMALL.__dict__, "dueling": True, "replay": "prioritized", "loss": "huber",
                          "target_update": "hard", "target_period": 10, "num_envs": 4, "train_every": 2,
                          "gradient_steps": 2, "double_dqn": False, "max_grad_norm": None, "eval_every": 96})
    _, metrics = jax.jit(lambda k: train(config, envs.make("cartpole-mjx"), k))(jax.random.PRNGKey(0))
    assert np.isfinite(np.asarray(metrics["loss"])).all()
    assert np.asarray(metrics["loss"])[-1] > 0
    assert int(metrics["env_steps"][-1]) == config.num_chunks * config.eval_every


@pytest.mark.slow  # two compiles of a training
def test_mapped_and_vmapped_seeds_train_alike():
    """The CPU runs seeds one after another (`_map_in_place`), accelerators vmap them: the same
    agents either way, up to float rounding of batched against plain matmuls."""
    mapped = train_run("cartpole", SMALL, seeds=2, progress=False, seed_axis="map")
    vmapped = train_run("cartpole", SMALL, seeds=2, progress=False, seed_axis="vmap")
    for a, b in zip(jax.tree.leaves(mapped.train_state.params), jax.tree.leaves(vmapped.train_state.params),
                    strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-3, atol=1e-4)
    with pytest.raises(ValueError, match="seed_axis"):
        train_run("cartpole", SMALL, seeds=2, progress=False, seed_axis="pmap")


def test_seeds_run_one_after_another_update_the_donated_state_in_place():
    """Mapped seeds write each seed's new train state into the donated one: the chunk program holds one seed's
    state beside the run's, not a second copy of every seed's replay (as `lax.map`'s stacked outputs would)."""
    learner = DQN(dataclasses.replace(SMALL, buffer_size=200_000), envs.make("cartpole"), agents=4)
    ts = jax.eval_shape(jax.vmap(learner.init), jax.random.split(jax.random.PRNGKey(0), 4))
    state_bytes = sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(ts))
    program = jax.jit(seed_batched(partial(_train_steps, learner), 4, "map"), donate_argnums=0)
    memory = program.lower(ts).compile().memory_analysis()
    assert memory.alias_size_in_bytes >= state_bytes
    assert memory.temp_size_in_bytes < 0.5 * state_bytes, (memory.temp_size_in_bytes, state_bytes)


GPU_SHAPED = DQNConfig(total_steps=600, learning_starts=200, batch_size=32, buffer_size=4000, eval_every=200,
                       eval_episodes=4, hidden=(16,), num_envs=2, train_every=2, gradient_steps=2,
                       replay="prioritized")


def _train_chunks(dqn, chunks=3, compiler_options=None):
    ts = jax.jit(dqn.init, compiler_options=compiler_options)(jax.random.PRNGKey(0))
    chunk = jax.jit(dqn.chunk, compiler_options=compiler_options)
    for _ in range(chunks):
        ts, _ = chunk(ts)
    return ts


def _assert_trees_equal(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.slow  # issue #29: out of the default run (make test <= 8 min); compiles the accelerator's DQN program on the CPU (~25 s)
def test_the_accelerator_replay_is_exact_on_the_cpu(monkeypatch):
    """The replay `agents.device_options` picks for accelerators (gathers, scatters, level-by-level
    sum trees), run on the CPU, computes the CPU program's values bit for bit: with the
    CPU's optimizer, matmul and loops kept, a whole run (prioritized, several envs and
    updates per iteration) is identical."""
    from agents import device_options

    cpu = _train_chunks(DQN(GPU_SHAPED, envs.make("cartpole"), platform="cpu"), compiler_options=USERS_CODEGEN)
    monkeypatch.setattr(device_options, "flat_optimizer", lambda platform=None: True)
    monkeypatch.setattr(device_options, "transposed_kernel_gradient", lambda platform=None: True)
    monkeypatch.setattr(device_options, "unrolled_inner_loops", lambda platform=None: False)
    monkeypatch.setattr(device_options, "fused_q_network", lambda platform=None, agents=1: False)
    accelerator = DQN(GPU_SHAPED, envs.make("cartpole"), platform="gpu")
    assert accelerator.buffer.vectorized
    _assert_trees_equal(_train_chunks(accelerator, compiler_options=USERS_CODEGEN), cpu)


@pytest.mark.slow
def test_the_accelerator_update_differs_from_the_cpu_one_by_rounding_only():
    """Why the accelerator program's parameters are not the CPU's bit for bit: its Adam runs
    per parameter leaf, so gradient clipping sums the squared norm leaf by leaf rather than
    over one flat vector; its Dense layers take the plain product's kernel gradient (XLA
    sums in another order); its Q-network is `agents.fused_mlp`'s kernels (interpreted
    here), whose padded products sum in another order too; and its unrolled inner steps let XLA fuse, and so round,
    across steps. One update from the same state agrees to float rounding;
    over thousands of updates (and the greedy actions they change) the runs drift apart,
    so the GPU's training is judged by its solve rates (docs/results.md: 16/16)."""
    from agents import device_options

    cpu = DQN(GPU_SHAPED, envs.make("cartpole"), platform="cpu")
    gpu = DQN(GPU_SHAPED, envs.make("cartpole"), platform="gpu", agents=device_options.FUSED_MIN_AGENTS)
    assert gpu.fused_network
    ts = _train_chunks(cpu, chunks=1)  # a filled buffer; learning starts in the next chunk
    bits = jnp.arange(GPU_SHAPED.batch_size, dtype=jnp.uint32) * jnp.uint32(2654435761)
    flat, unravel = ravel_pytree(ts.params)
    per_leaf = jax.tree.map(lambda x: unravel(x) if x.shape == flat.shape else x, ts.opt_state)  # the same Adam state
    gpu_ts = ts.replace(opt_state=per_leaf)
    after_cpu, _ = jax.jit(lambda t: cpu.update(t, True, bits))(ts)
    after_gpu, _ = jax.jit(lambda t: gpu.update(t, True, bits))(gpu_ts)
    moved = False
    for new_cpu, new_gpu, old in zip(jax.tree.leaves(after_cpu.params), jax.tree.leaves(after_gpu.params),
                                     jax.tree.leaves(ts.params), strict=True):
        np.testing.assert_allclose(np.asarray(new_gpu), np.asarray(new_cpu), rtol=1e-5, atol=1e-7)
        moved |= not np.array_equal(np.asarray(new_cpu), np.asarray(old))
    assert moved


def test_a_batch_that_skips_idle_target_copies_copies_the_same():
    """`copy_where` with `batch_skips` (the accelerators' hard target update: one `lax.cond` for
    a vmapped batch, skipped when no agent copies) gives `jnp.where`'s values bit for bit:
    under vmap whether none, some or all agents copy, nested (a sweep's configs x seeds), with
    an unbatched side, and unbatched."""
    from agents.dqn import copy_where

    new = {"kernel": jnp.arange(24.0).reshape(4, 2, 3), "bias": jnp.arange(8.0).reshape(4, 2)}
    old = jax.tree.map(jnp.negative, new)
    plain = lambda c, n, o: copy_where(c, n, o, batch_skips=False)
    skips = lambda c, n, o: copy_where(c, n, o, batch_skips=True)
    for copy in ([0, 0, 0, 0], [0, 1, 0, 1], [1, 1, 1, 1]):
        copy = jnp.array(copy, bool)
        _assert_trees_equal(jax.jit(jax.vmap(skips))(copy, new, old), jax.vmap(plain)(copy, new, old))
    copy = jnp.array([[0, 1], [0, 0]], bool)
    nested = jax.tree.map(lambda x: x.reshape((2, 2) + x.shape[1:]), (new, old))
    _assert_trees_equal(jax.jit(jax.vmap(jax.vmap(skips)))(copy, *nested), jax.vmap(jax.vmap(plain))(copy, *nested))
    one_new, one_old = jax.tree.map(lambda x: x[0], (new, old))
    copy = jnp.array([1, 0, 0, 1], bool)
    _assert_trees_equal(jax.jit(jax.vmap(skips, in_axes=(0, None, None)))(copy, one_new, one_old),
                        jax.vmap(plain, in_axes=(0, None, None))(copy, one_new, one_old))
    _assert_trees_equal(skips(jnp.array(True), one_new, one_old), one_new)
    assert "stablehlo.case" in jax.jit(jax.vmap(skips)).lower(copy, new, old).as_text()  # one cond, not a select


@pytest.mark.heavy  # two compiles of a vmapped training chunk (~20 s); the test above checks copy_where itself
def test_vmapped_agents_train_the_same_when_the_batch_skips_idle_target_copies(monkeypatch):
    config = dataclasses.replace(GPU_SHAPED, target_update="hard", target_period=3, replay="uniform")

    def run():
        dqn = DQN(config, envs.make("cartpole"), platform="cpu")
        ts = jax.jit(jax.vmap(dqn.init))(jax.random.split(jax.random.PRNGKey(0), 3))
        chunk = jax.jit(jax.vmap(dqn.chunk))
        for _ in range(3):
            ts, _ = chunk(ts)
        return ts

    selected = run()
    monkeypatch.setattr(device_options, "batch_skips_idle_target_copies", lambda platform=None: True)
    skipped = run()
    assert int(selected.updates[0]) > config.target_period  # several copies happened
    _assert_trees_equal(skipped, selected)


def test_cpu_compile_options_unknown_to_this_xla_are_left_out():
    # jax 0.11's XLA:CPU refuses xla_cpu_use_fusion_emitters; a run must compile there all the same.
    assert not device_options.cpu_accepts("xla_cpu_no_such_option", False)
    assert device_options.known_cpu_options({"xla_cpu_no_such_option": False, "xla_backend_optimization_level": 1}) == {
        "xla_backend_optimization_level": 1}
    assert set(device_options.training_compiler_options("cpu")) <= set(device_options.CPU_COMPILER_OPTIONS)


def test_gpu_training_options_are_options_this_xla_knows():
    # CI has no GPU; XLA parses every platform's debug options on any, so a misspelt option or
    # value (command buffer kinds, scheduling mode) fails here as it would on a GPU. A misspelt
    # value is refused, as the last line shows.
    options = device_options.training_compiler_options("gpu")
    assert options["xla_gpu_command_buffer_scheduling_mode"] == "CONCURRENT"
    program = jax.jit(lambda x: x + 1).lower(jax.ShapeDtypeStruct((), jnp.float32))
    program.compile(options)
    with pytest.raises(Exception, match="not a valid enum value"):
        program.compile({**options, "xla_gpu_command_buffer_scheduling_mode": "CONCURENT"})


@pytest.mark.parametrize("agent", ["dqn", "ppo", "sac", "td3"])
def test_a_chunk_gives_back_the_train_state_types_it_took_so_its_jitted_program_compiles_once(agent):
    """Every agent's first train state (`first_state`) is typed as its chunks leave it, weak types included: a
    weakly typed first best_return made every jitted chunk program compile twice, once for the first chunk."""
    from test_ppo import SMALL as PPO_SMALL
    from test_sac import SMALL as SAC_SMALL, drift
    from test_td3 import SMALL as TD3_SMALL

    from agents import PPO, SAC, TD3

    learner = {"dqn": lambda: DQN(SMALL, envs.make("cartpole")), "ppo": lambda: PPO(PPO_SMALL, drift()),
               "sac": lambda: SAC(SAC_SMALL, drift()), "td3": lambda: TD3(TD3_SMALL, drift())}[agent]()
    first = jax.eval_shape(learner.init, jax.random.PRNGKey(0))
    later = jax.eval_shape(lambda ts: learner.chunk(ts, record=False)[0], first)
    typed = lambda ts: [(jax.tree_util.keystr(path), x.shape, x.dtype, x.weak_type)
                        for path, x in jax.tree_util.tree_flatten_with_path(ts)[0]]
    assert typed(later) == typed(first)
