import atexit
import importlib.metadata
import os
import shutil
import tempfile

# Tests run on the CPU; keep XLA from grabbing every core's worth of threads per test.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
# The tests' programs are compiled far more than they run: XLA:CPU's LLVM backend at optimization level 1
# (XLA's own HLO passes, fusion included, unchanged) compiles them faster. It rounds some results otherwise
# than users' level, so the proofs against Gymnasium and dm_control (`envs.compile_cache.PROOF_COMPILER_OPTIONS`)
# and a test that holds two different programs to the same bits compile as users' programs do (`USERS_CODEGEN`);
# level 0 also parted programs that users' level makes bit-equal.
# And the CPU compiler options `mjxsuite train` uses for its programs (`agents.device_options.CPU_COMPILER_OPTIONS`)
# for every program the tests compile, their directly jitted DQN and MJX programs too: half the compile
# time. Subprocesses inherit both; tests/test_sharding.py adds its device count. jaxlib 0.11's XLA
# no longer has the second flag (its classic emitters are retired) and aborts on an unknown XLA_FLAGS entry.
USERS_CODEGEN = {"xla_backend_optimization_level": 3}  # XLA's default
_FLAGS = ["--xla_backend_optimization_level=1"]
if tuple(int(part) for part in importlib.metadata.version("jaxlib").split(".")[:2]) < (0, 11):
    _FLAGS.append("--xla_cpu_use_fusion_emitters=false")
os.environ["XLA_FLAGS"] = " ".join([os.environ.get("XLA_FLAGS", ""), *_FLAGS]).strip()

# Many tests compile the same programs (the same tiny training run, evaluation, rollout):
# JAX's persistent compilation cache, in a directory of this session's own (deleted at exit,
# never ~/.cache), compiles each once and loads it afterwards. It is keyed by the compiled
# program itself, so a test that changes what is traced (a monkeypatched step) misses it.
# Subprocesses the tests start (the CLI, kill -9 and resume, two-process runs) inherit it
# through MJXSUITE_COMPILE_CACHE, with `agents.traced_programs` beside it as a user has it.
# `make test` runs two pytest-xdist workers: each takes a directory of its own (as a sequential
# run has), not the one of the process that started them, which their environment inherits;
# one directory shared by concurrent writers would need JAX's file lock, which a test's own
# subprocess (the CLI, unlocked) would then trip over.
_PREFIX = "mjxsuite-test-compile-cache-"
_CACHE_DIR = tempfile.mkdtemp(prefix=_PREFIX)
atexit.register(shutil.rmtree, _CACHE_DIR, ignore_errors=True)
_INHERITED = os.environ.get("MJXSUITE_COMPILE_CACHE")
if _INHERITED is None or (os.environ.get("PYTEST_XDIST_WORKER") and os.path.basename(_INHERITED).startswith(_PREFIX)):
    os.environ["MJXSUITE_COMPILE_CACHE"] = _CACHE_DIR

import jax  # noqa: E402 (after the environment above)
import pytest  # noqa: E402

from agents import traced_programs  # noqa: E402
from envs.compile_cache import PROOF_COMPILER_OPTIONS  # noqa: E402

PROOF_COMPILER_OPTIONS.update(USERS_CODEGEN)  # the proofs against Gymnasium and dm_control compile as users' programs

if os.environ["MJXSUITE_COMPILE_CACHE"] == _CACHE_DIR:
    jax.config.update("jax_compilation_cache_dir", _CACHE_DIR)
    # As `agents.jax_compile_cache.enable()`: the tests' programs are small, each well under
    # JAX's default one-second threshold, and they add up.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
else:
    shutil.rmtree(_CACHE_DIR, ignore_errors=True)


# Parametrized cases of the heavy run (`make test-heavy`, out of CI: see docs/claims.md), beside the
# tests marked `heavy` where they are defined: a sibling case of each stays in the slow run.
HEAVY_CASES = {
    "tests/test_agents_cli.py::test_kill_9_after_a_checkpoint_then_resume_is_exact[sac]",
    "tests/test_walkers.py::test_steps_match_gymnasium[walker2d]",
    "tests/test_gym_vector.py::test_every_gymnasium_task_steps_as_syncvectorenv[Hopper-v5-NEXT_STEP]",
    "tests/test_gym_vector.py::test_every_gymnasium_task_steps_as_syncvectorenv[HalfCheetah-v5-NEXT_STEP]",
    "tests/test_gym_vector.py::test_every_gymnasium_task_steps_as_syncvectorenv[HalfCheetah-v5-SAME_STEP]",
    "tests/test_gym_interop.py::test_check_env_passes_for_every_kind_of_env[cartpole-swingup-mjx]",
    "tests/test_gym_interop.py::test_check_env_passes_for_every_kind_of_env[half-cheetah]",
    "tests/test_dqn.py::test_resume_reproduces_the_uninterrupted_run[cartpole-mjx-uniform]",
    "tests/test_dm_control.py::test_steps_match_dm_control[dmc-cheetah-run]",
    "tests/test_dm_control.py::test_reset_observation_is_dm_controls[dmc-cheetah-run]",
    "tests/test_dm_control.py::test_steps_match_dm_control[dmc-hopper-hop]",
    "tests/test_dm_control.py::test_reset_observation_is_dm_controls[dmc-hopper-hop]",
    "tests/test_dm_control.py::test_steps_near_the_goal_match_dm_control[dmc-cheetah-run]",
    "tests/test_dm_control.py::test_steps_near_the_goal_match_dm_control[dmc-hopper-hop]",
    "tests/test_dm_control.py::test_steps_near_the_goal_match_dm_control[dmc-hopper-stand]",
    "tests/test_dm_control.py::test_cheetah_reset_distribution_matches_dm_control",
    "tests/test_dm_control.py::test_steps_match_dm_control_other_tasks[dmc-walker-run]",
    "tests/test_dm_control.py::test_steps_match_dm_control_other_tasks[dmc-walker-stand]",
    "tests/test_dm_control.py::test_steps_match_dm_control_in_x64[dmc-walker-walk]",
    "tests/test_dm_control.py::test_steps_near_the_goal_match_dm_control[dmc-cartpole-balance-sparse]",
    "tests/test_dm_control.py::test_steps_near_the_goal_match_dm_control[dmc-cartpole-swingup-sparse]",
    "tests/test_dm_control.py::test_steps_near_the_goal_match_dm_control[dmc-acrobot-swingup-sparse]",
    "tests/test_agents_cli.py::test_kill_9_after_a_checkpoint_then_resume_is_exact[ppo]",
    # Gymnasium's hopper steps (half-cheetah, ant, swimmer, reacher and the inverted pendulum's stay in
    # the slow run), and reacher's target under auto-reset (a compile of its own; its distribution and
    # its drawing stay)
    "tests/test_walkers.py::test_steps_match_gymnasium[hopper]",
    "tests/test_dm_control.py::test_reacher_target_moves_with_each_episode_under_auto_reset",
    "tests/test_readme_task.py::test_python_blocks_marked_run_run[docs/randomization.md:4]",
    # the signal handler under the other signal at each moment (each moment's first signal runs by default)
    "tests/test_faults.py::test_a_signal_stops_the_run_cleanly_and_resume_continues_it[during compile-SIGTERM]",
    "tests/test_faults.py::test_a_signal_stops_the_run_cleanly_and_resume_continues_it[during training-SIGINT]",
    "tests/test_faults.py::test_a_signal_stops_the_run_cleanly_and_resume_continues_it[during a save-SIGTERM]",
    "tests/test_faults.py::test_a_signal_stops_the_run_cleanly_and_resume_continues_it[during the final evaluation-SIGINT]",
    # bring_peg's steps (bring_ball's, the same arm and grips, stay; bring_peg's reset distribution stays), and two
    # benchmark scripts at tiny sizes, as the others (each task in a process of its own; td3_speed's seed axes)
    "tests/test_dm_control_manipulator.py::test_steps_match_dm_control[dmc-manipulator-bring-peg]",
    "tests/test_bench.py::test_each_task_alone_gathers_every_tasks_records_from_a_process_of_its_own",
    "tests/test_td3.py::test_td3_speed_times_seeds_vmapped_and_mapped",
}


@pytest.hookimpl(tryfirst=True)  # before `-m` selects
def pytest_collection_modifyitems(config, items):
    for item in items:
        if item.nodeid in HEAVY_CASES:
            item.add_marker(pytest.mark.heavy)


@pytest.fixture(autouse=True)
def _export_cache_off_between_tests():
    """In-process CLI tests turn on the export cache (`jax_compile_cache.enable()`, as the CLI
    does); it keys traced programs by config and env, not by code, so it must not carry
    over into a test that traces its own variant (a monkeypatched backend choice)."""
    yield
    traced_programs.disable()


def random_rollout(env_name: str, impl: str = "jax", steps: int = 30, num_envs: int = 4):
    """(observations, rewards) of `num_envs` envs of `envs.make(env_name, impl=impl)` over `steps`
    uniform random actions, as numpy arrays (steps, num_envs, ...)."""
    import numpy as np

    import envs
    from envs.wrappers import VmapWrapper

    env = VmapWrapper(envs.make(env_name, impl=impl), num_envs)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, num_envs, env.action_size), minval=-1, maxval=1)

    def run(key):
        def step(state, action):
            state = env.step(state, action)
            return state, (state.obs, state.reward)

        return jax.lax.scan(step, env.reset(key), actions)[1]

    return jax.tree.map(np.asarray, jax.jit(run)(jax.random.PRNGKey(0)))
