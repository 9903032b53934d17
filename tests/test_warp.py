"""impl="warp" through the env API and the DQN, checked on the CPU: MuJoCo Warp runs its kernels
on the CPU too, so these run wherever warp-lang and mujoco-warp are installed
(`pip install -e '.[test,warp]'`) and are skipped without them. `envs.make(..., impl="warp")`
refuses a machine without a CUDA GPU, so the tests lift that check. The GPU results are in
docs/randomization.md."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("warp", reason="impl='warp' needs warp-lang: pip install -e '.[test,warp]'")
pytest.importorskip("mujoco_warp", reason="impl='warp' needs mujoco-warp: pip install -e '.[test,warp]'")

import envs  # noqa: E402
from agents import DQNConfig, train_run  # noqa: E402
from envs import mjx_env  # noqa: E402
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


@pytest.mark.parametrize("seeds, seed_axis", [(1, None), (2, "vmap"), (2, "map")])
def test_dqn_trains_with_warp_as_with_jax(seeds, seed_axis):
    """One seed runs unbatched, vmapped seeds batch the evaluation's while loop (whose batched
    condition batches its whole carry): Warp's run ends with JAX's parameters to rounding."""
    runs = {impl: train_run("cartpole-mjx", TINY, seeds=seeds, env_options={"impl": impl}, progress=False,
                            seed_axis=seed_axis) for impl in ("warp", "jax")}
    for ours, reference in zip(jax.tree.leaves(runs["warp"].params), jax.tree.leaves(runs["jax"].params)):
        np.testing.assert_allclose(np.asarray(ours), np.asarray(reference), atol=1e-5)
    assert runs["warp"].mean_return == runs["jax"].mean_return
