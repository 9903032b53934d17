"""envs.to_gymnasium: the suite's envs behind Gymnasium's API, checked with Gymnasium's
own tools (check_env, CartPole-v1, SyncVectorEnv's same-step autoreset)."""

import os
import subprocess
import sys
import textwrap
import warnings

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence
from gymnasium.vector import AutoresetMode, SyncVectorEnv

import envs
from envs.registry import _REGISTRY

# check_env warns about any infinite Box bound. Our observation spaces are unbounded
# on purpose (no env declares bounds), as are the velocities of Gymnasium's CartPole-v1.
UNBOUNDED_OBS_WARNINGS = ("observation space minimum value is -infinity", "observation space maximum value is infinity")
# ... and recommends a symmetric, normalized action Box; Gymnasium's own tasks with another ctrlrange get it too.
NORMALIZED_ACTION_WARNING = "we recommend using a symmetric and normalized space"


def warns_of_action_space(space) -> bool:
    """Whether check_env gives NORMALIZED_ACTION_WARNING for an action space: a Box with a bound
    outside [-1, 1], or a pair neither symmetric nor starting at 0 (gymnasium/utils/env_checker.py).
    Humanoid's [-0.4, 0.4] passes; InvertedPendulum's [-3, 3] does not."""
    if not isinstance(space, gymnasium.spaces.Box):
        return False
    low, high = space.low, space.high
    return bool(np.any((low != 0) & (np.abs(low) != np.abs(high))) or np.any(low < -1) or np.any(high > 1))

# A tiny continuous task: a block pushed by two motors with different ctrlranges.
SLIDER_XML = """
<mujoco model="gym_interop_slider">
  <option timestep="0.05"><flag contact="disable"/></option>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="block">
      <joint name="slide" type="slide" axis="1 0 0" damping="0.5"/>
      <geom name="block" type="box" size="0.1 0.1 0.1" mass="1"/>
    </body>
  </worldbody>
  <actuator>
    <motor name="push" joint="slide" gear="1" ctrlrange="-1 2"/>
    <motor name="nudge" joint="slide" gear="1" ctrlrange="-0.5 0.5"/>
  </actuator>
</mujoco>
"""
SLIDER = "gym-interop-slider"


class Slider(envs.MjxEnv):
    """Continuous actions of size 2; ends past x = 1; a nudge above 0.45 (ctrl) makes the physics NaN."""

    observation_size = 2

    def initial_qpos_qvel(self, key):
        return jax.random.uniform(key, (1,), minval=-0.1, maxval=0.1), jnp.zeros(1)

    def observation(self, data):
        return jnp.concatenate([data.qpos, data.qvel])

    def reward(self, data, action, prev):
        return data.qpos[0] - prev.qpos[0]

    def terminated(self, data):
        return jnp.abs(data.qpos[0]) > 1.0

    def post_step(self, prev, data):
        # A stand-in for a physics blow-up, to check the NaN flag reaches Gymnasium's info.
        return data.replace(qvel=jnp.where(data.ctrl[1] > 0.45, jnp.nan, data.qvel))


@pytest.fixture(scope="module")
def slider(tmp_path_factory):
    path = tmp_path_factory.mktemp("gym_interop") / "slider.xml"
    path.write_text(SLIDER_XML)
    envs.register(SLIDER, lambda: Slider(path), episode_length=20)
    yield SLIDER
    _REGISTRY.pop(SLIDER)  # no public unregister; keep the registry as other tests expect it


def check_env_warnings(env, **kwargs):
    """Run Gymnasium's check_env; return its warnings other than the unbounded-observation ones."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env, **kwargs)
    return [str(w.message) for w in caught if not any(s in str(w.message) for s in UNBOUNDED_OBS_WARNINGS)]


# ---- Gymnasium's env checker ---------------------------------------------------------
@pytest.mark.parametrize("name", ["cartpole", "cartpole-mjx"])
def test_check_env_passes_for_discrete_envs(name):
    env = envs.to_gymnasium(name)
    assert isinstance(env, gymnasium.Env)
    assert env.observation_space == gymnasium.spaces.Box(-np.inf, np.inf, (4,), np.float32)
    assert env.action_space == gymnasium.spaces.Discrete(2)
    # Rendering needs an OpenGL context; it is checked in a subprocess below.
    assert check_env_warnings(env, skip_render_check=True) == []


def test_check_env_passes_for_a_continuous_env(slider):
    env = envs.to_gymnasium(slider)
    # Gymnasium's action space: the actuators' ctrlrange, not the env's own [-1, 1].
    low, high = np.array([-1.0, -0.5], np.float32), np.array([2.0, 0.5], np.float32)
    assert env.action_space == gymnasium.spaces.Box(low, high, (2,), np.float32)
    # check_env recommends [-1, 1] for any other Box (Gymnasium's InvertedPendulum-v5, [-3, 3], gets it too).
    assert [NORMALIZED_ACTION_WARNING in w for w in check_env_warnings(env, skip_render_check=True)] == [True]


def test_continuous_actions_are_the_ctrl_gymnasium_sets(slider):
    """An action in Gymnasium's space reaches MuJoCo as that very ctrl, edges included."""
    env = envs.to_gymnasium(slider)
    env.reset(seed=0)
    for action in ([2.0, -0.5], [-1.0, 0.25], [0.5, 0.0], [1.25, 0.125]):
        env.step(np.array(action))
        np.testing.assert_allclose(np.asarray(env.state.pipeline_state.ctrl), action, rtol=0, atol=1e-7)


@pytest.mark.slow  # every task built (no compile)
def test_every_registered_env_has_gymnasiums_spaces():
    """Every registered env's spaces as a `gymnasium.Env`: Gymnasium's own action space for its
    MuJoCo tasks, a float32 Box of the task's observation size."""
    for name in envs.names():
        env, ours = envs.to_gymnasium(name), envs.make(name)
        gymnasium_id = getattr(ours.unwrapped, "gymnasium_id", None)
        if gymnasium_id is not None:
            assert env.action_space == gymnasium.make(gymnasium_id).action_space, name
        assert env.observation_space.shape == (ours.observation_size,) and env.observation_space.dtype == np.float32


# check_env steps each env through the adapter's one code path: one task of each kind (analytic,
# classic control as MJCF, dm_control-like, Gymnasium's MuJoCo tasks), the spaces of every task
# above. Contacts are the physics' (each task's own proof), not the adapter's; MJX compiles of the
# contact tasks take up to a minute each on a small CPU.
CHECK_ENV_TASKS = ["acrobot", "pendulum-mjx", "cartpole-swingup-mjx", "half-cheetah"]


@pytest.mark.slow
@pytest.mark.parametrize("name", CHECK_ENV_TASKS)
def test_check_env_passes_for_every_kind_of_env(name):
    env = envs.to_gymnasium(name)
    space = env.action_space
    # A continuous env's space is its ctrlrange; check_env recommends a symmetric Box inside [-1, 1].
    found = check_env_warnings(env, skip_render_check=True)
    assert [NORMALIZED_ACTION_WARNING in w for w in found] == ([True] if warns_of_action_space(space) else []), found
    vector = envs.to_gymnasium(name, num_envs=3)
    obs, _ = vector.reset(seed=0)
    assert obs.shape == (3, env.observation_space.shape[0]) and obs.dtype == np.float32
    vector.action_space.seed(0)
    for _ in range(3):
        obs, *_ = vector.step(vector.action_space.sample())
        assert obs in vector.observation_space


# ---- against Gymnasium's CartPole-v1 -------------------------------------------------
def start_from(ours, gym_env):
    """Put Gymnasium's CartPole state into our env (the reset distributions draw differently)."""
    state = jnp.asarray(gym_env.unwrapped.state, jnp.float32)
    ours.state = ours.state.replace(pipeline_state=envs.CartPoleState.from_array(state), obs=state)


def test_random_episodes_reproduce_gymnasium_cartpole():
    """Whole episodes from Gymnasium's start states under random actions, float32 against float64."""
    ours, theirs = envs.to_gymnasium("cartpole"), gymnasium.make("CartPole-v1")
    rng = np.random.default_rng(0)
    for seed in range(10):
        theirs.reset(seed=seed)
        ours.reset(seed=seed)
        start_from(ours, theirs)
        for step in range(1, 501):
            action = int(rng.integers(2))
            expected = theirs.step(action)
            obs, reward, terminated, truncated, info = ours.step(action)
            assert obs.dtype == np.float32 and isinstance(reward, float) and info == {}
            np.testing.assert_allclose(obs, expected[0], atol=1e-5)
            assert (reward, terminated, truncated) == expected[1:4], (seed, step)
            if terminated or truncated:
                break
        assert terminated and step < 100  # random actions drop the pole quickly


def balancing_action(obs):
    return int(0.1 * obs[0] + 0.5 * obs[1] + obs[2] + 0.5 * obs[3] > 0)


def test_balanced_episode_truncates_at_step_500_like_gymnasium():
    """A balancing policy through 500 steps. CartPole is unstable open-loop: a rounding
    difference grows ~e^50 over 10 s, so each step starts from Gymnasium's state again;
    the step counter, and so the truncation, is ours throughout."""
    ours, theirs = envs.to_gymnasium("cartpole"), gymnasium.make("CartPole-v1")
    obs, _ = theirs.reset(seed=1)
    ours.reset(seed=1)
    for step in range(1, 501):
        start_from(ours, theirs)
        action = balancing_action(obs)
        obs, *flags = theirs.step(action)
        our_obs, *our_flags = ours.step(action)
        np.testing.assert_allclose(our_obs, obs, atol=1e-5)
        assert our_flags[:3] == flags[:3], step
    assert flags[1:3] == [False, True] and step == 500


def test_termination_on_the_last_step_is_also_a_truncation_as_in_gymnasium():
    """Gymnasium's TimeLimit sets truncated on the limit's step even when it terminates."""
    theirs = gymnasium.make("CartPole-v1")
    theirs.reset(seed=3)
    actions = [1] * 100
    length = next(t for t, a in enumerate(actions, 1) if theirs.step(a)[2])
    theirs = gymnasium.make("CartPole-v1", max_episode_steps=length)
    ours = envs.to_gymnasium("cartpole", episode_length=length)
    theirs.reset(seed=3)
    ours.reset(seed=3)
    start_from(ours, theirs)
    for action in actions[:length]:
        expected, got = theirs.step(action), ours.step(action)
    assert expected[2:4] == (True, True) and got[2:4] == (True, True)


# ---- the vector env ------------------------------------------------------------------
def test_vector_env_spaces_and_metadata():
    vector = envs.to_gymnasium("cartpole-mjx", num_envs=5)
    assert isinstance(vector, gymnasium.vector.VectorEnv)
    assert vector.metadata["autoreset_mode"] is AutoresetMode.SAME_STEP
    assert vector.single_observation_space == gymnasium.spaces.Box(-np.inf, np.inf, (4,), np.float32)
    assert vector.single_action_space == gymnasium.spaces.Discrete(2)
    assert vector.observation_space.shape == (5, 4)
    assert vector.action_space == gymnasium.spaces.MultiDiscrete([2] * 5)
    obs, info = vector.reset(seed=0)
    assert obs.shape == (5, 4) and obs.dtype == np.float32 and info == {}
    assert len({tuple(row) for row in obs}) == 5  # each sub-env draws its own start


def test_vector_env_matches_gymnasiums_same_step_autoreset():
    """Each step of our vmapped env against Gymnasium's SyncVectorEnv (SAME_STEP) over our
    single envs, both started from the same sub-env states: rewards, flags, the final
    observations and the info layout (final_obs, final_info and their masks) must agree,
    and our auto-reset observations must be fresh starts."""
    num_envs, name = 6, "cartpole"
    ours = envs.to_gymnasium(name, num_envs=num_envs, episode_length=15)  # some truncate, some terminate
    reference = SyncVectorEnv(
        [lambda: envs.to_gymnasium(name, episode_length=15) for _ in range(num_envs)],
        autoreset_mode=AutoresetMode.SAME_STEP,
    )
    ours.reset(seed=0)
    reference.reset(seed=0)
    rng = np.random.default_rng(0)
    ended_by = {"terminated": 0, "truncated": 0}
    for _ in range(200):  # until both kinds of ending were checked; ~28% of random episodes end before 15 steps
        if min(ended_by.values()) >= 3:
            break
        for i, sub_env in enumerate(reference.envs):
            sub_env.state = jax.tree.map(lambda x, i=i: x[i], ours.state)
        actions = rng.integers(0, 2, num_envs)
        obs, rewards, terminated, truncated, info = ours.step(actions)
        ref_obs, ref_rewards, ref_terminated, ref_truncated, ref_info = reference.step(actions)
        ended = terminated | truncated
        np.testing.assert_array_equal(rewards, ref_rewards)
        assert rewards.dtype == ref_rewards.dtype == np.float64
        np.testing.assert_array_equal(terminated, ref_terminated)
        np.testing.assert_array_equal(truncated, ref_truncated)
        np.testing.assert_allclose(obs[~ended], ref_obs[~ended], atol=1e-6)
        assert info.keys() == ref_info.keys()
        assert data_equivalence(info, ref_info), (info, ref_info)
        if ended.any():
            assert np.all(np.abs(obs[ended]) <= 0.05)  # a new episode's first observation
            ended_by["terminated"] += int(terminated.sum())
            ended_by["truncated"] += int(truncated.sum())
    assert ended_by["terminated"] > 0 and ended_by["truncated"] > 0, ended_by


def test_vector_env_continuous_and_nan_final_info(slider):
    vector = envs.to_gymnasium(slider, num_envs=3)
    low, high = np.array([-1.0, -0.5], np.float32), np.array([2.0, 0.5], np.float32)
    assert vector.action_space == gymnasium.spaces.Box(np.tile(low, (3, 1)), np.tile(high, (3, 1)), (3, 2), np.float32)
    vector.reset(seed=0)
    actions = np.array([[0.5, 0.0], [0.5, 0.5], [0.0, 0.0]])  # env 1's nudge blows up the physics
    obs, rewards, terminated, _, info = vector.step(actions)
    assert terminated.tolist() == [False, True, False] and rewards[1] == 0.0
    assert info["_final_obs"].tolist() == [False, True, False]
    assert info["final_info"]["nan"].tolist() == [False, True, False]
    assert np.isfinite(obs).all() and np.isfinite(info["final_obs"][1]).all()


def test_single_env_reports_nan_in_info(slider):
    env = envs.to_gymnasium(slider)
    env.reset(seed=0)
    assert env.step(np.array([0.1, 0.0]))[4] == {}
    _, reward, terminated, truncated, info = env.step([0.1, 0.5])
    assert info == {"nan": True} and terminated and not truncated and reward == 0.0


# ---- seeding, compile-once, errors ---------------------------------------------------
def rollout(env, seed, actions):
    observations = [env.reset(seed=seed)[0]]
    for action in actions:
        observations.append(env.step(action)[0])
    return np.stack(observations)


def test_same_seed_same_episode_and_one_compilation():
    actions = [0, 1, 1, 0, 1]
    first, second = envs.to_gymnasium("cartpole"), envs.to_gymnasium("cartpole")
    np.testing.assert_array_equal(rollout(first, 7, actions), rollout(second, 7, actions))
    assert not np.array_equal(rollout(first, 8, actions)[0], rollout(first, 7, actions)[0])
    # Unseeded resets continue the seeded generator: the same sequence of episodes.
    starts = [[env.reset(seed=4)[0]] + [env.reset()[0] for _ in range(3)] for env in (first, second)]
    np.testing.assert_array_equal(starts[0], starts[1])
    # Python ints, numpy ints and 0-d arrays all hit the one compiled step.
    for action in (1, np.int64(0), np.array(1, np.int32)):
        first.step(action)
    assert first._step._cache_size() == 1 and first._reset._cache_size() == 1

    vector_a, vector_b = envs.to_gymnasium("cartpole", num_envs=4), envs.to_gymnasium("cartpole", num_envs=4)
    batch_actions = [np.array([0, 1, 1, 0])] * 30
    np.testing.assert_array_equal(rollout(vector_a, 3, batch_actions), rollout(vector_b, 3, batch_actions))
    assert vector_a._step._cache_size() == 1


@pytest.mark.parametrize("action", [2, -1, 0.5, np.float32(1.0), [0, 1], np.array([1]), True, "left"])
def test_bad_discrete_action_names_the_env(action):
    env = envs.to_gymnasium("cartpole")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"env 'cartpole': action .* is outside the action space Discrete\(2\)"):
        env.step(action)


@pytest.mark.parametrize("action", [[2.5, 0.0], [0.0, -0.6], [-1.5, 0.0], [0.0], [np.nan, 0.0], 0.5, [[0.1, 0.1]]])
def test_bad_continuous_action_names_the_env(slider, action):
    env = envs.to_gymnasium(slider)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=rf"env '{SLIDER}': action .* is outside the action space Box"):
        env.step(action)


def test_bad_vector_actions_name_the_env():
    vector = envs.to_gymnasium("cartpole", num_envs=3)
    vector.reset(seed=0)
    for actions in ([0, 1], [0, 1, 2], np.zeros(3)):
        with pytest.raises(ValueError, match=r"env 'cartpole': action .* outside the action space MultiDiscrete"):
            vector.step(actions)


def test_unknown_env_and_option_are_clear_errors():
    with pytest.raises(ValueError, match=r"unknown env 'no-such-env'; registered envs: \[.*'cartpole'"):
        envs.to_gymnasium("no-such-env")
    with pytest.raises(ValueError, match=r"unknown option\(s\) \['gravitee'\] for env 'cartpole'"):
        envs.to_gymnasium("cartpole", gravitee=1.0)
    with pytest.raises(ValueError, match=r"env 'cartpole': render_mode 'human' is not supported"):
        envs.to_gymnasium("cartpole", render_mode="human")
    with pytest.raises(ValueError, match=r"env 'cartpole': num_envs must be a positive int"):
        envs.to_gymnasium("cartpole", num_envs=0)
    with pytest.raises(ValueError, match=r"env 'cartpole': reset takes no options"):
        envs.to_gymnasium("cartpole").reset(options={"low": -0.1})


def test_overrides_reach_the_jax_env():
    env = envs.to_gymnasium("cartpole", episode_length=3, force_mag=0.0)
    env.reset(seed=0)
    flags = [env.step(1)[3] for _ in range(3)]
    assert flags == [False, False, True]
    assert env.env.unwrapped.physics.force_mag == 0.0
    assert env.spec.kwargs == {"name": "cartpole", "episode_length": 3, "force_mag": 0.0}


def test_step_before_reset_and_after_the_end_follow_gymnasium():
    env = envs.to_gymnasium("cartpole", episode_length=2)
    with pytest.raises(gymnasium.error.ResetNeeded, match="env 'cartpole': call reset"):
        env.step(0)
    env.reset(seed=0)
    env.step(0)
    assert env.step(0)[3]  # truncated
    with pytest.warns(UserWarning, match="step\\(\\) called after the episode ended"):
        env.step(0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env.step(0)  # warned once per episode
        env.reset()
        env.step(0)


# ---- optional pieces: gymnasium missing, rendering -----------------------------------
def test_missing_gymnasium_is_a_clear_import_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "gymnasium", None)  # makes `import gymnasium` fail
    monkeypatch.delitem(sys.modules, "envs.interop.gymnasium")
    with pytest.raises(ImportError, match=r'pip install "mjxsuite\[gymnasium\]"'):
        envs.to_gymnasium("cartpole")


def run_python(code, **env_vars):
    """`code` in a fresh Python with `env_vars` over this environment (None: the variable unset)."""
    environment = {k: v for k, v in {**os.environ, **env_vars}.items() if v is not None}
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        check=False, capture_output=True, text=True, timeout=120, env=environment,
    )


def test_import_envs_does_not_need_gymnasium():
    result = run_python("""
        import sys
        sys.modules["gymnasium"] = None  # as if it were not installed
        import envs
        from envs import *
        print("ok", callable(to_gymnasium))
    """)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["ok", "True"]


@pytest.mark.slow  # ~8 s in a fresh process: the default run stays under 6 minutes on 2 cores
def test_rgb_array_rendering_headless():
    """check_env with its render checks, in a fresh process with MUJOCO_GL=egl."""
    result = run_python("""
        import warnings
        import numpy as np
        import envs
        from gymnasium.utils.env_checker import check_env
        # check_env's render checks rebuild the env; the analytic one compiles fast.
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(envs.to_gymnasium("cartpole", render_mode="rgb_array"))
        bad = [str(w.message) for w in caught if "infinity" not in str(w.message)]
        assert not bad, bad
        for name in ("cartpole", "cartpole-mjx"):
            env = envs.to_gymnasium(name, render_mode="rgb_array")
            env.reset(seed=0)
            first = env.render()
            for _ in range(10):
                env.step(1)
            later = env.render()
            assert first.dtype == np.uint8 and first.shape == (480, 640, 3), first.shape
            assert (first != later).any()  # the cart moved
            env.close()
            env.close()
        print("rendered")
    """, MUJOCO_GL="egl")
    if "needs an OpenGL context" in result.stderr:
        pytest.skip("no EGL on this machine: " + result.stderr.strip().splitlines()[-1])
    assert result.returncode == 0, result.stderr
    assert "rendered" in result.stdout


@pytest.mark.skipif(bool(os.environ.get("MUJOCO_GL") or os.environ.get("DISPLAY")), reason="a GL backend is configured")
@pytest.mark.filterwarnings("ignore:.*(DISPLAY|GLFW library)")  # GLFW's own complaints on the way to our error
def test_render_without_gl_is_a_clear_error():
    env = envs.to_gymnasium("cartpole", render_mode="rgb_array")
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match="env 'cartpole': render_mode='rgb_array' needs an OpenGL context.*MUJOCO_GL=egl"):
        env.render()


@pytest.mark.heavy  # compiles the camera's render three times (one env, a batch, make_vec)
def test_camera_tasks_are_gymnasium_envs_of_uint8_images():
    """observation="pixels" through Gymnasium: uint8 frames in a Box(0, 255) of the image's shape,
    from `to_gymnasium` (one env and a batch, final frames included) and `make_vec`, and check_env."""
    from gymnasium.utils.env_checker import check_env

    options = dict(observation="pixels", width=8, height=8, opt={"integrator": "Euler"})
    env = envs.to_gymnasium("cartpole-balance-mjx", episode_length=6, **options)
    assert env.observation_space == gymnasium.spaces.Box(0, 255, (8, 8, 3), np.uint8)
    obs, _ = env.reset(seed=0)
    assert obs.dtype == np.uint8 and obs in env.observation_space
    for _ in range(6):
        obs, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        assert obs in env.observation_space and isinstance(reward, float)
    assert truncated
    check_env(env, skip_render_check=True)
    vector = envs.to_gymnasium("cartpole-balance-mjx", num_envs=3, episode_length=6, **options)
    assert vector.reset(seed=0)[0].shape == (3, 8, 8, 3)
    finals = []
    for _ in range(6):
        obs, _, _, _, info = vector.step(vector.action_space.sample())
        assert obs in vector.observation_space
        finals += [info["final_obs"][i] for i in np.flatnonzero(info.get("_final_obs", []))]
    assert len(finals) == 3 and all(f.dtype == np.uint8 and f.shape == (8, 8, 3) for f in finals)
    made = gymnasium.make_vec("mjxsuite/CartPoleBalanceMjx-v0", num_envs=2, **options)
    assert made.single_observation_space == env.observation_space
    obs, _ = made.reset(seed=0)
    assert obs.shape == (2, 8, 8, 3) and obs.dtype == np.uint8
    assert made.step(made.action_space.sample())[0] in made.observation_space
