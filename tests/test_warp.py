"""impl="warp" through the env API and the DQN, checked on the CPU: MuJoCo Warp runs its kernels
on the CPU too, so these run wherever warp-lang and mujoco-warp are installed
(`pip install -e '.[test,warp]'`) and are skipped without them. `envs.make(..., impl="warp")`
refuses a machine without a CUDA GPU, so the tests lift that check. The GPU results are in
docs/randomization.md."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_rollout

pytest.importorskip("warp", reason="impl='warp' needs warp-lang: pip install -e '.[test,warp]'")
pytest.importorskip("mujoco_warp", reason="impl='warp' needs mujoco-warp: pip install -e '.[test,warp]'")

import envs  # noqa: E402
from agents import DQNConfig, train_run  # noqa: E402
from envs import mjx_env, mjx_warp  # noqa: E402
from envs.wrappers import BatchedAutoReset, VmapWrapper  # noqa: E402

TINY = DQNConfig(total_steps=400, learning_starts=64, batch_size=32, buffer_size=256, eval_every=200,
                 eval_episodes=2, hidden=(16,))


@pytest.fixture(autouse=True)
def warp_on_the_cpu(monkeypatch):
    monkeypatch.setattr(mjx_env, "require_warp", lambda: None)


def test_every_leaf_of_a_warp_batch_has_the_batch_axis():
    """MuJoCo Warp's buffers shared by all worlds (MJX's DATA_NON_VMAP: the contact pool,
    `nacon`, ...) stay out of the state, so per-env and per-seed code can treat it leaf by leaf."""
    env = VmapWrapper(envs.make("cartpole-mjx", impl="warp"), 3)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    stepped = jax.jit(env.step)(state, jnp.zeros(3, jnp.int32))
    for batch in (state, stepped):
        shapes = {jax.tree_util.keystr(path): leaf.shape for path, leaf in jax.tree_util.tree_leaves_with_path(batch)}
        assert {name: shape for name, shape in shapes.items() if shape[:1] != (3,)} == {}
        assert not any("contact__" in name for name in shapes)


@pytest.mark.parametrize("env_name", ["cartpole-mjx", "acrobot-mjx"])
def test_auto_reset_batch_follows_jax(env_name):
    """64 envs, 200 random steps with auto-resets, both reset strategies: Warp ends where JAX does."""
    def final_obs(impl, reset_by_index):
        env = BatchedAutoReset(envs.make(env_name, impl=impl), 64, reset_by_index=reset_by_index)
        actions = jax.random.randint(jax.random.PRNGKey(1), (200, 64), 0, env.num_actions)

        def run(key):
            state, _ = jax.lax.scan(lambda s, a: (env.step(s, a), None), env.reset(key), actions)
            return state.obs

        return np.asarray(jax.jit(run)(jax.random.PRNGKey(0)))

    for reset_by_index in (False, True):
        np.testing.assert_allclose(final_obs("warp", reset_by_index), final_obs("jax", reset_by_index), atol=1e-4)


def test_on_a_gpu_a_warp_batch_resets_by_index_to_the_selects_states(monkeypatch):
    """A Warp env's reset is Warp's forward pass, so on a GPU too its batch resets only the envs
    that ended and, under a vmap over seeds, decides once for all of them; the states are those of
    the select that builds a fresh episode for every env on every step."""
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    env = envs.make("cartpole-mjx", impl="warp")
    across = BatchedAutoReset(env, 16, under_vmap=True)
    selected = BatchedAutoReset(env, 16, reset_by_index=False, under_vmap=True)
    assert across.reset_by_index and across.reset_across_vmap and not selected.reset_by_index
    actions = jax.random.randint(jax.random.PRNGKey(1), (100, 16), 0, env.num_actions)

    def run(wrapped, key):
        def body(state, action):
            state = wrapped.step(state, action)
            return state, (state.obs, state.done)

        return jax.lax.scan(body, wrapped.reset(key), actions)[1]

    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    obs, done = jax.jit(jax.vmap(lambda key: run(selected, key)))(keys)
    assert 20 < int(done.sum()) < 2 * 16 * 100 / 2  # many episodes end, on some steps only
    for a, b in zip(jax.jit(jax.vmap(lambda key: run(across, key)))(keys), (obs, done)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.parametrize("seeds, seed_axis", [(1, None), (2, "vmap"), (2, "map")])
def test_dqn_trains_with_warp_as_with_jax(seeds, seed_axis):
    """One seed runs unbatched, vmapped seeds batch the evaluation's while loop (whose batched
    condition batches its whole carry): Warp's run ends with JAX's parameters to rounding."""
    runs = {impl: train_run("cartpole-mjx", TINY, seeds=seeds, env_options={"impl": impl}, progress=False,
                            seed_axis=seed_axis, judge_every=1) for impl in ("warp", "jax")}
    for ours, reference in zip(jax.tree.leaves(runs["warp"].params), jax.tree.leaves(runs["jax"].params)):
        np.testing.assert_allclose(np.asarray(ours), np.asarray(reference), atol=1e-5)
    assert runs["warp"].mean_return == runs["jax"].mean_return


def contact_rollout(steps: int = 10, num_envs: int = 4, **overrides):
    """Gymnasium's half_cheetah.xml (ground contacts), `num_envs` envs under random actions:
    qpos and qvel, info["overflow"], done, reward and obs after each step."""
    from benchmarks.contact_task import contact_task_name

    env = VmapWrapper(envs.make(contact_task_name(), **overrides), num_envs)
    actions = jax.random.uniform(jax.random.PRNGKey(1), (steps, num_envs, env.action_size), minval=-1, maxval=1)

    def run(key):
        def body(state, action):
            new = env.step(state, action)
            physics = jnp.concatenate([new.pipeline_state.qpos, new.pipeline_state.qvel], -1)
            return new, (physics, new.info["overflow"], new.done, new.reward, new.obs, state.obs)

        return jax.lax.scan(body, env.reset(key), actions)[1]

    return jax.tree.map(np.asarray, jax.jit(run)(jax.random.PRNGKey(0)))


def test_warp_follows_jax_on_a_contact_model_at_the_default_sizes(capfd):
    """The default buffers (MJX's JAX implementation's bounds: 16 contacts and 70 rows per env
    for half_cheetah.xml) hold every step, and Warp follows JAX over 10 steps (50 physics steps) to
    1e-4 in positions and 1e-3 (3e-4 relative) in velocities: float32 rounding that contact
    dynamics under random actions grow (to 1e-2 by step 40, each implementation as near C MuJoCo
    as the other)."""
    from benchmarks.contact_task import contact_task_name

    task = envs.make(contact_task_name(), impl="warp").unwrapped
    assert (task.warp_buffers.nconmax, task.warp_buffers.njmax) == (16, 70)
    warp, jax_ = contact_rollout(impl="warp"), contact_rollout()
    assert warp[1].sum() == 0 and warp[2].sum() == 0
    nq = task.mj_model.nq
    np.testing.assert_allclose(warp[0][..., :nq], jax_[0][..., :nq], atol=1e-4)  # positions
    np.testing.assert_allclose(warp[0][..., nq:], jax_[0][..., nq:], atol=1e-3, rtol=1e-3)  # velocities, up to ~5
    assert "overflow" not in capfd.readouterr().out


def test_an_undersized_warp_buffer_flags_the_step_never_a_silent_wrong_one(capfd):
    """One contact for 4 envs' ground contacts, or 4 constraint rows for 8+: every such step is
    flagged (1.0 contacts, 2.0 rows), ends its episode with reward 0 and the previous observation,
    and MuJoCo Warp's own print flood is off (the training run prints one line instead)."""
    physics, overflow, done, reward, obs, previous_obs = contact_rollout(steps=4, impl="warp", naconmax=1)
    flagged = overflow > 0
    assert set(np.unique(overflow)) <= {0.0, 1.0} and flagged.mean() > 0.5
    assert (done[flagged] == 1).all() and (reward[flagged] == 0).all()
    np.testing.assert_array_equal(obs[flagged], previous_obs[flagged])
    overflow = contact_rollout(steps=4, impl="warp", njmax=4)[1]
    assert 2.0 in overflow and 1.0 not in overflow
    assert "overflow" not in capfd.readouterr().out


def test_brax_training_wrappers_end_an_overflowing_episode():
    """Brax's own training stack (episode limit, vmap, auto-reset) over `envs.to_brax`: a step
    Warp could not hold arrives as the end of its episode, flagged, with reward 0."""
    from brax.envs.wrappers.training import wrap

    from benchmarks.contact_task import contact_task_name

    env = envs.to_brax(contact_task_name(), impl="warp", naconmax=1)
    batch = wrap(env, episode_length=env.episode_length)
    state = jax.jit(batch.reset)(jax.random.split(jax.random.PRNGKey(0), 4))
    step = jax.jit(batch.step)
    for _ in range(3):
        state = step(state, jnp.zeros((4, env.action_size)))
        flagged = np.asarray(state.info["overflow"]) > 0
        assert flagged.any()
        assert (np.asarray(state.done)[flagged] == 1).all() and (np.asarray(state.reward)[flagged] == 0).all()


def test_the_overflow_bits_are_mujoco_warps():
    from mujoco.mjx.third_party.mujoco_warp._src.types import OverflowType

    assert mjx_warp.CONTACT_OVERFLOW == OverflowType.BROADPHASE | OverflowType.NARROWPHASE | OverflowType.CCD
    assert mjx_warp.CONSTRAINT_OVERFLOW == OverflowType.NEFC | OverflowType.NJMAX_NNZ


GYMNASIUM_TASKS = ["half-cheetah", "hopper", "walker2d", "ant", "humanoid", "swimmer", "reacher", "pusher",
                   "inverted-pendulum", "inverted-double-pendulum"]


def assert_alike_under_both(env_name: str, steps: int, num_envs: int = 4) -> np.ndarray:
    """`random_rollout` under impl="warp" and impl="jax": the same observations and rewards to float32 contact
    rounding; returns impl="jax"'s observations."""
    (warp_obs, warp_reward), (jax_obs, jax_reward) = (random_rollout(env_name, impl, steps, num_envs)
                                                      for impl in ("warp", "jax"))
    np.testing.assert_allclose(warp_obs, jax_obs, atol=2e-3, rtol=2e-3)
    np.testing.assert_allclose(warp_reward, jax_reward, atol=2e-3, rtol=2e-3)
    return jax_obs


@pytest.mark.parametrize("env_name", GYMNASIUM_TASKS)
def test_gymnasium_tasks_step_alike_under_both_implementations(env_name):
    """What lets a run trained with impl="warp" act anywhere with impl="jax" (`checkpoint.saved_env`):
    4 envs, 10 random steps, the same observations and rewards to float32 contact rounding."""
    assert_alike_under_both(env_name, 10)


# One task of each dm_control domain that steps under Warp, and finger turn's per-episode target.
DM_CONTROL_TASKS = ["dmc-acrobot-swingup", "dmc-ball-in-cup-catch", "dmc-cartpole-swingup", "dmc-cheetah-run",
                    "dmc-finger-turn-easy", "dmc-fish-swim", "dmc-hopper-stand", "dmc-humanoid-walk",
                    "dmc-manipulator-bring-ball", "dmc-pendulum-swingup", "dmc-point-mass-easy", "dmc-quadruped-walk",
                    "dmc-reacher-easy", "dmc-swimmer-swimmer6", "dmc-walker-walk"]


@pytest.mark.slow
@pytest.mark.parametrize("env_name", DM_CONTROL_TASKS)
def test_dm_control_tasks_step_alike_under_both_implementations(env_name):
    """A run trained with impl="warp" sees what impl="jax", the proofs' physics, gives: 2 envs, 30 random
    steps, the same observations and rewards to float32 contact rounding."""
    assert_alike_under_both(env_name, 30, num_envs=2)


@pytest.mark.slow
def test_cheetahs_settling_steps_under_warp_end_where_jaxs_do():
    """Under impl="warp" cheetah's settling steps at reset run on MuJoCo Warp's worlds (`DmcCheetahRun._settle`):
    16 resets end in the states of MJX-JAX's settle, to float32 contact rounding."""
    def reset_states(impl):
        env = VmapWrapper(envs.make("dmc-cheetah-run", impl=impl), 16)
        data = jax.jit(env.reset)(jax.random.PRNGKey(0)).pipeline_state
        return np.asarray(data.qpos), np.asarray(data.qvel)

    (warp_qpos, warp_qvel), (jax_qpos, jax_qvel) = reset_states("warp"), reset_states("jax")
    np.testing.assert_allclose(warp_qpos, jax_qpos, atol=2e-3)
    np.testing.assert_allclose(warp_qvel, jax_qvel, atol=2e-3)
    assert np.abs(warp_qvel).max() > 1e-3  # still moving after 2 s: a settle from the drawn joints, not a copy


def test_a_reset_reports_the_overflow_of_its_warp_work():
    """A contact pool of one for four worlds: cheetah's settling steps (`draw_start`) run out of it, and its
    reset says so (`info["overflow"]`, which an auto-reset adds to the step that ended the episode)."""
    env = envs.make("dmc-cheetah-run", impl="warp", naconmax=1)
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    assert np.asarray(jax.jit(jax.vmap(env.draw_start))(keys)[2]["overflow"]).tolist() == [1.0] * 4
    assert np.asarray(jax.jit(jax.vmap(env.reset))(keys).info["overflow"]).tolist() == [1.0] * 4
    roomy = envs.make("dmc-cheetah-run", impl="warp")
    assert not np.asarray(jax.jit(jax.vmap(roomy.reset))(keys).info["overflow"]).any()


@pytest.mark.slow
def test_dm_controls_touch_readings_under_warp_are_the_last_substeps():
    """dm_control's legacy step keeps the last substep's touch readings (`DmControlEnv.refresh`), under
    MuJoCo Warp too: finger spin's observations, touch included, as with impl="jax" over 60 steps."""
    jax_obs = assert_alike_under_both("dmc-finger-spin", 60)
    assert np.any(jax_obs[..., -2:] > 0)  # the last two entries, log1p of the touches, were compared touching


@pytest.mark.slow
@pytest.mark.parametrize("env_name", ["dmc-cheetah-run", "dmc-finger-spin"])
def test_the_refresh_without_the_constraint_stage_gives_a_whole_forward_passes_observations(env_name, monkeypatch):
    """Under Warp, `DmControlEnv.refresh` skips collision and the solve (mj_step1 never reaches them):
    the observations and rewards, finger's touch included, are those of a whole forward pass, bit for bit."""
    from envs.tasks.dm_control_suite import DmControlEnv

    def whole_forward(self, model, data):
        fresh = mjx_env.mjx.forward(model, data)
        return fresh.replace(sensordata=fresh.sensordata.at[..., self._acc_sensors].set(
            data.sensordata[..., self._acc_sensors]))

    skipped = random_rollout(env_name, "warp", 40, num_envs=2)
    monkeypatch.setattr(DmControlEnv, "refresh", whole_forward)
    whole = random_rollout(env_name, "warp", 40, num_envs=2)
    np.testing.assert_array_equal(skipped[0], whole[0])
    np.testing.assert_array_equal(skipped[1], whole[1])


@pytest.mark.parametrize("env_name, warp_calls", [("dmc-pendulum-swingup", 1), ("dmc-walker-walk", 2)])
def test_a_task_that_reads_the_kinematics_alone_makes_one_warp_call_per_step(env_name, warp_calls):
    """The legacy-step refresh of a task that reads only the kinematics is MJX-JAX's kinematics, so
    its step's program calls MuJoCo Warp once (the physics); walker walk reads its speed sensor and
    refreshes with Warp's forward pass, a second call (`DmControlEnv.refresh`)."""
    env = VmapWrapper(envs.make(env_name, impl="warp"), 4)
    state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    action = jax.ShapeDtypeStruct((4, env.action_size), jnp.float32)
    assert str(jax.make_jaxpr(env.step)(state, action)).count("ffi_call") == warp_calls


def test_warp_launches_counts_the_kernels_of_a_step(tmp_path):
    """`benchmarks.warp_launches` on Warp's CPU kernels: the pendulum's step launches Warp's physics
    kernels only (its refresh is MJX-JAX's), fewer than walker walk's, which adds Warp's forward pass."""
    from benchmarks import warp_launches

    target = tmp_path / "launches.json"
    warp_launches.main(["--tasks", "dmc-pendulum-swingup", "dmc-walker-walk", "--envs", "2", "--json", str(target)])
    records = json.loads(target.read_text())
    pendulum, walker = (record["launches_per_step"] for record in records)
    assert 0 < pendulum < walker
    assert [record["overflow_steps"] for record in records] == [0, 0]
