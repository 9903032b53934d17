"""The export cache: a second run loads the traced training chunk instead of tracing it,
with identical results; anything that could change the program misses; a bad file is
traced again; nothing is written while the cache is off."""

import dataclasses
import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents import jax_compile_cache, traced_programs
from agents.dqn import DQN, DQNConfig
from agents.run import CLOCK_KEYS, key_parts as agent_key_parts, seed_keys, train_run

# Slow run: processes that load each other's traced programs (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

TINY = DQNConfig(total_steps=200, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                 eval_episodes=4, hidden=(16,))


@pytest.fixture
def cache_dir(tmp_path):
    directory = traced_programs.enable(tmp_path / "export")
    yield directory
    traced_programs.disable()


@pytest.fixture
def chunk_traces(monkeypatch):
    """How often a chunk's training steps are traced (a run that loads them from the cache never calls them)."""
    calls = []
    original = DQN.train_steps

    def counted(self, ts, *args, **kwargs):
        calls.append(1)
        return original(self, ts, *args, **kwargs)

    monkeypatch.setattr(DQN, "train_steps", counted)
    return calls


def leaves(tree) -> list[np.ndarray]:
    return [np.asarray(x) for x in jax.tree.leaves(tree)]


def assert_same_run(a, b):
    drop_speed = [{k: v for k, v in r.items() if k not in CLOCK_KEYS} for r in a.history]
    assert drop_speed == [{k: v for k, v in r.items() if k not in CLOCK_KEYS} for r in b.history]
    assert a.mean_return == b.mean_return
    for x, y in zip(leaves(a.train_state), leaves(b.train_state), strict=True):
        np.testing.assert_array_equal(x, y)


def test_a_second_run_loads_the_traced_chunk_with_identical_results(tmp_path, chunk_traces):
    traced_programs.disable()
    plain = train_run("cartpole", TINY, progress=False, judge_every=1)
    assert len(chunk_traces) == 1
    traced_programs.enable(tmp_path / "export")
    try:
        first = train_run("cartpole", TINY, progress=False, judge_every=1)
        assert len(chunk_traces) == 2  # traced, exported and written
        files = sorted((tmp_path / "export").iterdir())
        assert [f.suffix for f in files] == [".pkl"] * 3  # the chunk's two halves and the final evaluation
        second = train_run("cartpole", TINY, progress=False, judge_every=1)
        assert len(chunk_traces) == 2  # loaded: not traced
        assert sorted((tmp_path / "export").iterdir()) == files
    finally:
        traced_programs.disable()
    assert_same_run(first, plain)
    assert_same_run(second, plain)


def chunk_file(cache_dir, env_name, config=TINY, seeds=1, env_options=None):
    env = envs.make(env_name, **(env_options or {}))
    dqn = DQN(config, env)
    ts = jax.eval_shape(jax.vmap(dqn.init), seed_keys(0, seeds))
    ts = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), ts)  # concrete arguments, as train_run passes
    key_parts = traced_programs.program_key_parts("DQN.chunk", env, env_name, env_options, agent_key_parts(dqn, seeds))
    return traced_programs.cache_file(cache_dir, key_parts, (ts,))


def test_whatever_could_change_the_chunk_changes_its_file(tmp_path):
    base = chunk_file(tmp_path, "cartpole")
    assert chunk_file(tmp_path, "cartpole") == base  # stable
    changed = [
        chunk_file(tmp_path, "cartpole", dataclasses.replace(TINY, learning_rate=1e-3)),
        chunk_file(tmp_path, "cartpole", dataclasses.replace(TINY, eval_episodes=8)),
        chunk_file(tmp_path, "cartpole", seeds=2),
        chunk_file(tmp_path, "cartpole", env_options={"gravity": 9.81}),  # same shapes, other constants
        chunk_file(tmp_path, "cartpole", env_options={"episode_length": 200}),
        chunk_file(tmp_path, "cartpole-mjx"),
    ]
    assert len({base, *changed}) == len(changed) + 1


def test_a_changed_mjcf_model_changes_the_env_fingerprint():
    default = traced_programs.env_fingerprint(envs.make("cartpole-mjx"))
    assert default == traced_programs.env_fingerprint(envs.make("cartpole-mjx"))
    heavier = envs.CartPoleMjx()
    heavier.mj_model.body_mass[-1] *= 2  # as if the user's XML file had changed
    assert traced_programs.env_fingerprint(envs.TimeLimit(heavier, 500))["mj_model"] != default["mj_model"]


def test_an_env_without_source_file_is_not_cached():
    typed_at_a_prompt = type("Typed", (envs.CartPole,), {"__module__": "__typed_at_a_prompt__"})
    assert traced_programs.env_fingerprint(typed_at_a_prompt()) is None


def step(state: envs.State, scale):
    """A small program whose input and output trees hold a custom node (a flax dataclass)."""
    obs = state.obs * scale + 1
    return state.replace(obs=obs, reward=obs.sum()), {"mean": obs.mean()}


def example_args():
    # Distinct buffers: one buffer donated twice is an error.
    return envs.State(jnp.zeros(2), jnp.arange(3.0), jnp.zeros(()), jnp.zeros(()),
                      info={"truncation": jnp.zeros(())}), jnp.float32(2.0)


@pytest.mark.parametrize("damage", ["garbage", "truncated"])
def test_a_corrupt_file_is_traced_again_and_overwritten(cache_dir, damage):
    expected = jax.jit(step)(*example_args())
    first = traced_programs.cached_lower(step, example_args(), "step", cache_dir).compile()
    (path,) = cache_dir.iterdir()
    good = path.read_bytes()
    damaged = b"not a cached program" if damage == "garbage" else good[: len(good) // 2]
    path.write_bytes(damaged)
    with pytest.warns(UserWarning, match="unreadable cached program"):
        again = traced_programs.cached_lower(step, example_args(), "step", cache_dir).compile()
    assert not first.hit and not again.hit
    assert path.read_bytes() != damaged and list(cache_dir.iterdir()) == [path]  # rewritten in place
    loaded = traced_programs.cached_lower(step, example_args(), "step", cache_dir).compile()
    assert loaded.hit
    for program in (first, again, loaded):
        for x, y in zip(leaves(program(*example_args())), leaves(expected), strict=True):
            np.testing.assert_array_equal(x, y)


def test_donation_is_kept_for_the_first_argument_only(cache_dir):
    """As `jax.jit(fn, donate_argnums=0)`: a second argument (a key, say) is neither donated nor
    warned about ("Some donated buffers were not usable")."""
    def step_with_key(state, key):
        return step(state, *example_args()[1:]), jax.random.split(key)[0]

    for _ in range(2):  # written, then loaded
        args = (*example_args()[:1], jax.random.PRNGKey(0))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            lowered = traced_programs.cached_lower(step_with_key, args, "step-with-key", cache_dir, donate=True)
            program = lowered.compile()
        program(*args)
        assert args[0].obs.is_deleted() and not args[1].is_deleted()
    assert program.hit


@pytest.fixture
def no_jax_cache_dir():
    """A process where JAX's own cache directory is unset (tests/conftest.py sets one for the
    session, which `jax_compile_cache.enable()` would respect)."""
    names = ("jax_compilation_cache_dir", "jax_persistent_cache_min_compile_time_secs",
             "jax_persistent_cache_min_entry_size_bytes", "jax_enable_compilation_cache")
    saved = {name: getattr(jax.config, name) for name in names}
    jax.config.update("jax_compilation_cache_dir", None)
    yield
    for name, value in saved.items():
        jax.config.update(name, value)


def test_nothing_is_written_while_the_cache_is_off(monkeypatch, tmp_path, no_jax_cache_dir):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.setenv(jax_compile_cache.ENV_VAR, "0")
    assert jax_compile_cache.enable() is None and traced_programs.directory() is None
    train_run("cartpole", TINY, progress=False)
    assert not (tmp_path / "xdg").exists()


def test_the_compile_cache_switch_turns_the_export_cache_on_and_off(monkeypatch, tmp_path, no_jax_cache_dir):
    """`jax_compile_cache.enable()` (what the CLI calls) puts the export cache inside its directory."""
    monkeypatch.setenv(jax_compile_cache.ENV_VAR, str(tmp_path / "jax"))
    try:
        assert jax_compile_cache.enable() == tmp_path / "jax"
        assert traced_programs.directory() == tmp_path / "jax" / traced_programs.SUBDIR
        jax_compile_cache.disable()
        assert traced_programs.directory() is None
    finally:
        traced_programs.disable()


@pytest.mark.slow  # ~8 s: test_a_second_run_loads_the_traced_chunk_with_identical_results keeps the cache in the default run
def test_eval_and_rollout_commands_load_their_traced_programs(tmp_path, monkeypatch, capsys):
    """A second `mjxsuite eval` / `rollout` (greedy or random policy) traces no env step and prints the same."""
    from agents import cli
    from agents.cli import main as cli_main

    run = str(tmp_path / "run")
    train_run("cartpole", TINY, out_dir=run, progress=False)
    monkeypatch.setattr(cli, "_use_compile_cache", lambda args: traced_programs.enable(tmp_path / "export"))
    env_steps = []
    step = envs.CartPole.step
    monkeypatch.setattr(envs.CartPole, "step", lambda self, *args: env_steps.append(1) or step(self, *args))
    commands = [["eval", "--checkpoint", run, "--episodes", "3"],
                ["rollout", "--checkpoint", run, "--rerun", str(tmp_path / "greedy.rrd"), "--overwrite"],
                ["rollout", "--env", "cartpole", "--num-envs", "2", "--rerun", str(tmp_path / "random.rrd"),
                 "--overwrite"]]
    try:
        printed = []
        for command in commands:
            traced = len(env_steps)
            assert cli_main(command) == 0
            assert len(env_steps) > traced  # traced, exported and written
            printed.append(capsys.readouterr().out)
        assert len(list((tmp_path / "export").iterdir())) == len(commands)
        for command, first in zip(commands, printed):
            traced = len(env_steps)
            assert cli_main(command) == 0
            assert len(env_steps) == traced  # loaded: not traced
            assert capsys.readouterr().out == first
    finally:
        traced_programs.disable()


def test_the_first_eval_of_a_run_loads_the_program_of_its_final_evaluation(tmp_path, monkeypatch, capsys):
    """`mjxsuite eval` with the run's own number of episodes (its default) traces no env step after
    the run: the run's final evaluation exported that program. Other episode counts are other
    programs, traced once each."""
    from agents import cli
    from agents.cli import main as cli_main

    run = str(tmp_path / "run")
    traced_programs.enable(tmp_path / "export")
    try:
        train_run("cartpole", TINY, out_dir=run, progress=False)
        monkeypatch.setattr(cli, "_use_compile_cache", lambda args: traced_programs.enable(tmp_path / "export"))
        env_steps = []
        step = envs.CartPole.step
        monkeypatch.setattr(envs.CartPole, "step", lambda self, *args: env_steps.append(1) or step(self, *args))
        assert cli_main(["eval", "--checkpoint", run]) == 0
        assert env_steps == []
        printed = capsys.readouterr().out
        assert f"over {TINY.eval_episodes} episodes" in printed
        assert json.loads(printed.splitlines()[-1])["episodes"] == TINY.eval_episodes
        assert cli_main(["eval", "--checkpoint", run, "--episodes", str(TINY.eval_episodes + 1)]) == 0
        assert env_steps  # another program
    finally:
        traced_programs.disable()


def test_a_warp_env_is_not_traced_for_the_cache():
    """`jax.export` refuses MuJoCo Warp's FFI calls, after a whole trace: a Warp env's programs
    skip the export cache (plain `jax.jit`) rather than trace twice and warn with the program."""
    env = envs.make("cartpole-mjx")
    assert traced_programs.program_key_parts("P", env, "cartpole-mjx", {}) is not None
    env.unwrapped.impl = "warp"  # what MjxEnv sets for impl="warp" (Warp itself needs a GPU)
    assert traced_programs.program_key_parts("P", env, "cartpole-mjx", {"impl": "warp"}) is None
