"""Our ids in Gymnasium's registry (`envs.interop.gymnasium_ids`) and their vector env
(`envs.interop.gymnasium.JaxVectorEnv`), checked against Gymnasium's own envs under its own
`SyncVectorEnv`, in both autoreset modes."""

import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium
import jax
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.wrappers.vector import JaxToNumpy

import envs
from envs.interop.gymnasium import JaxVectorEnv, RegisteredEnv
from envs.interop.gymnasium_ids import IDS, full_id

ROOT = Path(__file__).resolve().parents[1]
MODES = [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP]
ALL_IDS = sorted(IDS)
THEIRS = [i for i in ALL_IDS if i in gymnasium.registry]  # Gymnasium has its own env of that id


def their_space(space):
    """Gymnasium's space as ours declares it: a float64 Box (MuJoCo's) as float32, same bounds."""
    if isinstance(space, gymnasium.spaces.Box) and space.dtype == np.float64:
        return gymnasium.spaces.Box(space.low.astype(np.float32), space.high.astype(np.float32), space.shape, np.float32)
    return space


# ---- the registry ----------------------------------------------------------------------
def test_ids_are_registered_when_gymnasium_is_imported_without_importing_the_suite():
    """The .pth hook: a fresh process that imports only gymnasium finds every id, and neither
    the suite nor JAX was imported for it."""
    script = textwrap.dedent("""
        import sys, gymnasium
        ids = sorted(k for k in gymnasium.registry if k.startswith("mjxsuite/"))
        print(ids)
        print(sorted(m for m in ("envs", "jax", "mujoco") if m in sys.modules))
        spec = gymnasium.spec("mjxsuite/Hopper-v5")
        print(spec.entry_point, spec.vector_entry_point, spec.max_episode_steps, spec.kwargs)
    """)
    out = subprocess.run([sys.executable, "-c", script], cwd="/", capture_output=True, text=True, check=True)
    ids, loaded, spec = out.stdout.strip().splitlines()
    assert ids == str(sorted(full_id(i) for i in IDS)), out.stderr
    assert loaded == "[]"
    assert spec == "envs.interop.gymnasium:make_env envs.interop.gymnasium:make_vector_env 1000 {'task': 'hopper'}"


def test_every_id_names_a_task_with_gymnasiums_time_limit():
    # every task the suite registers has an id (other test files register their own tasks in this process)
    ours = {name for name in envs.names() if not name.startswith(("test-", "my-")) and name != "puck"}
    assert {task for task, _ in IDS.values()} == ours
    assert len([i for i in THEIRS if i.endswith("-v5")]) == 10  # Gymnasium's ten MuJoCo v5 tasks we have
    for gymnasium_id, (task, steps) in IDS.items():
        assert envs.options(task)["episode_length"] == steps, gymnasium_id
        spec = gymnasium.spec(full_id(gymnasium_id))
        if gymnasium_id in gymnasium.registry:
            theirs = gymnasium.spec(gymnasium_id)
            assert (spec.max_episode_steps, spec.reward_threshold) == (theirs.max_episode_steps, theirs.reward_threshold)
        if getattr(envs.make(task).unwrapped, "gymnasium_id", None):
            assert envs.make(task).unwrapped.gymnasium_id == gymnasium_id


@pytest.mark.parametrize("gymnasium_id", ALL_IDS)
def test_make_and_make_vec_give_gymnasiums_spaces(gymnasium_id):
    single = gymnasium.make(full_id(gymnasium_id))
    vector = gymnasium.make_vec(full_id(gymnasium_id), num_envs=3)
    assert isinstance(single.unwrapped, RegisteredEnv) and isinstance(vector, JaxVectorEnv)
    assert vector.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert single.spec.max_episode_steps == IDS[gymnasium_id][1]
    if gymnasium_id in gymnasium.registry:
        theirs = gymnasium.make(gymnasium_id)
        expected = their_space(theirs.observation_space), theirs.action_space
    else:  # an MJX-only task: the spaces of envs.to_gymnasium
        plain = envs.to_gymnasium(IDS[gymnasium_id][0])
        expected = plain.observation_space, plain.action_space
    assert (single.observation_space, single.action_space) == expected
    assert (vector.single_observation_space, vector.single_action_space) == expected
    assert vector.observation_space == gymnasium.vector.utils.batch_space(expected[0], 3)
    assert vector.action_space == gymnasium.vector.utils.batch_space(expected[1], 3)


def test_gymnasium_keyword_arguments_and_time_limit_reach_the_task():
    vector = gymnasium.make_vec("mjxsuite/Hopper-v5", num_envs=2, ctrl_cost_weight=0.5, reset_noise_scale=0.02,
                                max_episode_steps=7)
    assert vector.env.unwrapped.params.ctrl_cost_weight == 0.5 and vector.env.unwrapped.params.reset_noise_scale == 0.02
    assert vector.episode_length == 7
    single = gymnasium.make("mjxsuite/Hopper-v5", ctrl_cost_weight=0.5, max_episode_steps=7)
    assert single.unwrapped.env.unwrapped.params.ctrl_cost_weight == 0.5 and single.spec.max_episode_steps == 7
    assert gymnasium.make_vec("mjxsuite/CartPoleMjx-v0", num_envs=2, impl="jax").env.unwrapped.impl == "jax"


def test_bad_options_are_clear_errors():
    with pytest.raises(ValueError, match=r"autoreset_mode=.* is not supported; pass gymnasium.vector.AutoresetMode"):
        gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=2, autoreset_mode=AutoresetMode.DISABLED)
    with pytest.raises(ValueError, match=r"autoreset_mode='same' is not supported"):  # what was passed (#82)
        gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=2, autoreset_mode="same")
    for make in (gymnasium.make, lambda *a, **k: gymnasium.make_vec(*a, num_envs=2, **k)):  # v5's frame_skip (#95)
        with pytest.raises(ValueError, match=r"env 'hopper' through Gymnasium: frame_skip=5 is not taken\. .*"
                                             r"envs\.options\('hopper'\) lists them"):
            make("mjxsuite/Hopper-v5", frame_skip=5)
    with pytest.raises(ValueError, match=r"pass max_episode_steps=\.\.\., not episode_length"):
        gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=2, episode_length=5)
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['gravitee'\] for env 'cartpole'"):
        gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=2, gravitee=1.0)
    with pytest.raises(ValueError, match=r"num_envs must be a positive int, got 0"):
        gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=0)
    vector = gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=2)
    with pytest.raises(gymnasium.error.ResetNeeded, match="call reset"):
        vector.step(np.zeros(2, int))
    vector.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions of shape \(3,\) do not fit the action space .*expected shape \(2,\)"):
        vector.step(np.zeros(3, int))


# ---- step for step against SyncVectorEnv over Gymnasium's env ---------------------------------
def row(tree, i):
    return jax.tree.map(lambda x: np.asarray(x[i]), tree)


def match_state(theirs: gymnasium.Env, state, i: int) -> None:
    """Gymnasium's sub-env `i` put into our env i's state (our envs are step-equal to Gymnasium's
    from the same state: tests/gymnasium_mujoco.py, tests/test_gym_interop.py)."""
    env = theirs.unwrapped
    if hasattr(env, "set_state"):  # a MuJoCo task
        data = row(state.pipeline_state, i)
        env.set_state(data.qpos.astype(np.float64), data.qvel.astype(np.float64))
        env.data.qacc_warmstart[:] = data.qacc_warmstart
    else:  # CartPole-v1 and Acrobot-v1 keep their state as an array: CartPole's is its observation
        ours = state.pipeline_state if isinstance(state.pipeline_state, jax.Array) else state.obs
        env.state = np.asarray(ours[i], np.float64)


def lockstep(gymnasium_id: str, mode: AutoresetMode, num_envs: int, limit: int, steps: int, atol: float | None,
             seed: int = 0) -> dict[str, int]:
    """Our vector env and SyncVectorEnv over Gymnasium's env (its TimeLimit at `limit`) in `mode`,
    the same random actions; before each step every sub-env that steps is put into our env's state.
    Every step's terminated and truncated must be equal, rewards and observations close, and the
    final observations (SAME_STEP) close where both masks say an episode ended. Returns how many
    episodes ended by termination and by truncation. `atol=None`: values are not compared (a task
    whose single steps differ from Gymnasium's where MJX's contacts do, shown in its own tests)."""
    ours = gymnasium.make_vec(full_id(gymnasium_id), num_envs=num_envs, max_episode_steps=limit, autoreset_mode=mode)
    reference = SyncVectorEnv([lambda: gymnasium.make(gymnasium_id, max_episode_steps=limit)] * num_envs,
                              autoreset_mode=mode)
    obs, _ = ours.reset(seed=seed)
    reference.reset(seed=seed)
    reference.action_space.seed(seed)
    restarting = np.zeros(num_envs, bool)  # NEXT_STEP: ended on the last step, restarting now
    ended_by = {"terminated": 0, "truncated": 0}
    for step in range(steps):
        for i, sub_env in enumerate(reference.envs):
            if not restarting[i]:
                match_state(sub_env, ours.state, i)
        actions = reference.action_space.sample()
        got = ours.step(actions)
        expected = reference.step(actions)
        obs, rewards, terminated, truncated, info = (jax.tree.map(np.asarray, x) for x in got)
        ref_obs, ref_rewards, ref_terminated, ref_truncated, ref_info = expected
        where = f"{gymnasium_id} {mode} step {step}"
        np.testing.assert_array_equal(terminated, ref_terminated, err_msg=where)
        np.testing.assert_array_equal(truncated, ref_truncated, err_msg=where)
        ended = terminated | truncated
        # A new episode's first observation: ours and Gymnasium's draw it differently.
        fresh = restarting if mode == AutoresetMode.NEXT_STEP else ended
        assert obs.shape == ref_obs.shape and rewards.shape == ref_rewards.shape, where
        if atol is not None:
            np.testing.assert_allclose(rewards, ref_rewards, atol=atol, rtol=1e-4, err_msg=where)
            np.testing.assert_allclose(obs[~fresh], ref_obs[~fresh], atol=atol, rtol=1e-4, err_msg=where)
        if mode == AutoresetMode.NEXT_STEP:
            assert info == {} and not np.any(rewards[restarting]) and not np.any(ended[restarting]), where
            restarting = ended
        else:
            assert set(info) == {"final_obs", "_final_obs", "final_info", "_final_info"} and info["final_info"] == {}
            mask = ref_info.get("_final_obs", np.zeros(num_envs, bool))
            np.testing.assert_array_equal(info["_final_obs"], mask, err_msg=where)
            np.testing.assert_array_equal(info["_final_info"], ref_info.get("_final_info", mask), err_msg=where)
            assert not np.any(info["final_obs"][~mask])
            for i in np.flatnonzero(mask):
                assert info["final_obs"][i].shape == ref_info["final_obs"][i].shape, where
                if atol is not None:
                    np.testing.assert_allclose(info["final_obs"][i], ref_info["final_obs"][i], atol=atol, rtol=1e-4,
                                               err_msg=where)
        ended_by["terminated"] += int(terminated.sum())
        ended_by["truncated"] += int(truncated.sum())
    return ended_by


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.name)
def test_cartpole_steps_as_syncvectorenv_over_gymnasiums_cartpole(mode):
    ended_by = lockstep("CartPole-v1", mode, num_envs=6, limit=12, steps=80, atol=1e-5)
    assert ended_by["terminated"] >= 3 and ended_by["truncated"] >= 3, ended_by


@pytest.mark.slow  # about 20 s each on a small CPU, most of it MJX's compile
@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.name)
def test_inverted_pendulum_steps_as_syncvectorenv_over_gymnasiums(mode):
    """An MJX task (the smallest model that terminates) against Gymnasium's C MuJoCo env."""
    ended_by = lockstep("InvertedPendulum-v5", mode, num_envs=4, limit=10, steps=40, atol=1e-4)
    assert ended_by["terminated"] >= 2 and ended_by["truncated"] >= 2, ended_by


# The float32-against-float64 tolerance of each task's values. Ant and Humanoid: flags and layout only,
# as MJX frames a steep capsule's floor contact differently from C MuJoCo (tests/test_ant.py shows it).
SLOW_TASKS = {"HalfCheetah-v5": 1e-3, "Hopper-v5": 1e-3, "Walker2d-v5": 1e-3, "Swimmer-v5": 1e-3,
              "InvertedDoublePendulum-v5": 1e-3, "Reacher-v5": 1e-3, "Ant-v5": None, "Humanoid-v5": None,
              "Pusher-v5": 1e-3, "Acrobot-v1": 1e-4}


# The autoreset modes are the wrapper's, one code path for every task, and each task's physics is
# proven step for step in its own test file: every mode on one task, and one mode on a task with
# floor contacts that terminates (Hopper) and on the analytic-equations twin (Acrobot).
LOCKSTEP_CASES = [("HalfCheetah-v5", mode) for mode in MODES] + [(task, MODES[0]) for task in ("Hopper-v5", "Acrobot-v1")]


@pytest.mark.slow  # an MJX compile of each task on a small CPU takes tens of seconds
@pytest.mark.parametrize("gymnasium_id, mode", LOCKSTEP_CASES, ids=lambda c: getattr(c, "name", c))
def test_every_gymnasium_task_steps_as_syncvectorenv(gymnasium_id, mode):
    ended_by = lockstep(gymnasium_id, mode, num_envs=3, limit=8, steps=25, atol=SLOW_TASKS[gymnasium_id])
    assert ended_by["truncated"] >= 3, ended_by


# ---- seeding and the array wrappers ---------------------------------------------------------
def rollout(vector, seed, steps=30):
    vector.action_space.seed(1)
    obs, _ = vector.reset(seed=seed)
    out = [np.concatenate([np.asarray(obs), np.zeros((len(obs), 3))], axis=1)]
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = vector.step(vector.action_space.sample())
        out.append(np.concatenate([np.asarray(obs), np.asarray(reward)[:, None], np.asarray(terminated)[:, None],
                                   np.asarray(truncated)[:, None]], axis=1))
    return np.stack(out)


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.name)
def test_same_seed_same_episodes(mode):
    make = lambda: gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=4, max_episode_steps=9, autoreset_mode=mode)
    first, second = make(), make()
    a, b = rollout(first, 5), rollout(second, 5)
    np.testing.assert_array_equal(a, b)
    assert a[:, :, -1].any()  # the rollout went through autoresets
    assert not np.array_equal(rollout(first, 6)[0], a[0])
    assert len({tuple(r) for r in a[0]}) == 4  # each env draws its own start
    # Unseeded resets continue the seeded generator: the same sequence of episodes.
    starts = [[np.asarray(v.reset(seed=3)[0])] + [np.asarray(v.reset()[0]) for _ in range(2)] for v in (first, second)]
    np.testing.assert_array_equal(starts[0], starts[1])
    assert first._step._cache_size() == 1


@pytest.mark.parametrize("mode", MODES, ids=lambda m: m.name)
def test_jax_to_numpy(mode):
    vector = JaxToNumpy(gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=3, max_episode_steps=4, autoreset_mode=mode))
    obs, info = vector.reset(seed=0)
    assert type(obs) is np.ndarray and obs.shape == (3, 4) and info == {}
    for _ in range(4):
        obs, reward, terminated, truncated, info = vector.step(np.array([0, 1, 0]))
    assert all(type(x) is np.ndarray for x in (obs, reward, terminated, truncated))
    assert truncated.all()
    if mode == AutoresetMode.SAME_STEP:
        assert type(info["final_obs"]) is np.ndarray and info["_final_obs"].all() and info["final_obs"].shape == (3, 4)


def test_jax_to_torch():
    torch = pytest.importorskip("torch")
    from gymnasium.wrappers.vector import JaxToTorch

    inner = gymnasium.make_vec("mjxsuite/InvertedPendulum-v5", num_envs=3, max_episode_steps=4,
                               autoreset_mode=AutoresetMode.SAME_STEP)
    vector = JaxToTorch(inner)
    actions = [[[0.5], [-3.0], [2.0]], [[1.0], [0.0], [-0.25]]] * 2  # forces in Gymnasium's [-3, 3]
    obs, _ = vector.reset(seed=0)
    assert isinstance(obs, torch.Tensor) and obs.shape == (3, 4) and obs.dtype == torch.float32
    through_torch = [obs.numpy().copy()]
    for action in actions:
        obs, reward, terminated, truncated, info = vector.step(torch.tensor(action))
        through_torch += [obs.numpy().copy(), reward.numpy().copy(), info["final_obs"].numpy().copy()]
    assert isinstance(reward, torch.Tensor) and bool(truncated.any())
    assert isinstance(info["final_obs"], torch.Tensor) and torch.equal(info["_final_obs"], terminated | truncated)
    # The same env through JaxToNumpy: torch's actions reached the envs as the numpy ones do.
    numpy_vector = JaxToNumpy(inner)
    through_numpy = [numpy_vector.reset(seed=0)[0]]
    for action in actions:
        obs, reward, _, _, info = numpy_vector.step(np.array(action, np.float32))
        through_numpy += [obs, reward, info["final_obs"]]
    for ours, theirs in zip(through_torch, through_numpy, strict=True):
        np.testing.assert_array_equal(ours, theirs)
    assert np.any(through_torch[1] != through_torch[4])  # the actions moved the carts differently


# ---- the PyTorch example and the benchmark ---------------------------------------------------
@pytest.mark.slow  # Hopper's MJX compile on a small CPU
def test_torch_example_trains_and_plays_gymnasiums_hopper():
    pytest.importorskip("torch")
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        import ppo_torch_hopper
    finally:
        sys.path.remove(str(ROOT / "examples"))
    result = ppo_torch_hopper.main(["--num-envs", "8", "--unroll-length", "8", "--batch-size", "4",
                                    "--num-minibatches", "2", "--update-epochs", "2", "--total-timesteps", "128",
                                    "--eval-episodes", "1", "--eval-max-steps", "20", "--device", "cpu"])
    assert result["env_steps"] == 128 and result["eval_env"] == "Hopper-v5"
    assert np.isfinite(result["eval_mean_return"]) and len(result["eval_returns"]) == 1


@pytest.mark.heavy  # an MJX compile and Gymnasium's spawned workers
def test_gym_vector_benchmark_runs_on_the_cpu():
    from benchmarks import gym_vector

    records = gym_vector.run_benchmark("mjxsuite/InvertedPendulum-v5", num_envs=2, steps=3, repeats=1,
                                       gymnasium_steps=5)
    loops = {r.get("loop"): r for r in records}
    assert loops["jax"]["steps_per_s"] > 0 and loops["gymnasium"]["steps_per_s"] > 0
    assert loops["gymnasium"]["env"] == "InvertedPendulum-v5"
    torch_loop = loops["torch"]
    assert torch_loop["steps_per_s"] > 0 if "skipped" not in torch_loop else "pip install" in torch_loop["skipped"]
    assert records[-1]["kind"] == "gym-vector-ratio"
