"""The GPU's fused Q-network kernels (`agents.fused_mlp`), interpreted on the CPU, against Flax."""

import jax
import numpy as np
import pytest

import envs
from agents import device_options, fused_mlp
from agents.dqn import DQN, DQNConfig
from agents.networks import QNetwork

# Slow run: the fused network kernels against Flax (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow


@pytest.mark.parametrize("hidden,rows,features,actions", [
    ((64, 64), 64, 4, 2),  # the default network on its replayed batch
    ((16,), 200, 6, 3),  # rows over several blocks, none a power of two
    ((48, 32, 8), 1, 4, 2),  # three hidden layers, one row
])
def test_kernels_compute_the_flax_network_and_its_gradients(hidden, rows, features, actions):
    net = QNetwork(actions, hidden, transposed_kernel_gradient=False)
    obs = jax.random.normal(jax.random.PRNGKey(1), (rows, features))
    params = jax.vmap(lambda k: net.init(k, obs))(jax.random.split(jax.random.PRNGKey(0), 3))  # 3 agents
    cotangent = jax.random.normal(jax.random.PRNGKey(2), (rows, actions))

    def grads(q_values):
        loss = lambda p, x: (q_values(p, x) * cotangent).sum()
        return jax.jit(jax.vmap(jax.value_and_grad(loss, argnums=(0, 1)), (0, None)))(params, obs)

    flax_value, flax_grads = grads(net.apply)
    fused_value, fused_grads = grads(lambda p, x: fused_mlp.q_values(p, x, interpret=True))
    np.testing.assert_allclose(fused_value, flax_value, rtol=1e-5, atol=1e-5)
    for a, b in zip(jax.tree.leaves(fused_grads), jax.tree.leaves(flax_grads), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-5)
    assert any(np.abs(np.asarray(g)).max() > 0 for g in jax.tree.leaves(fused_grads))


def test_the_update_uses_the_kernels_only_for_many_agents_of_a_narrow_network_on_accelerators():
    cartpole, many = envs.make("cartpole"), device_options.FUSED_MIN_AGENTS
    assert DQN(DQNConfig(), cartpole, platform="gpu", agents=many).fused_network
    assert not DQN(DQNConfig(), cartpole, platform="gpu", agents=many - 1).fused_network  # GPU mostly idle
    assert not DQN(DQNConfig(), cartpole, platform="cpu", agents=many).fused_network
    assert not DQN(DQNConfig(dueling=True), cartpole, platform="gpu", agents=many).fused_network
    assert not DQN(DQNConfig(hidden=(120, 84)), cartpole, platform="gpu", agents=many).fused_network  # XLA wins


def test_the_judge_runs_the_kernels_and_scores_its_episodes_as_flax_does():
    """Where the update uses the kernels, the greedy evaluation does too (its 64 episodes are
    many rows per agent); interpreted on the CPU, the same actions and returns as Flax's network,
    and the kernel is really in the program (a Pallas call in its jaxpr)."""
    cartpole, config = envs.make("cartpole"), DQNConfig(eval_episodes=8)
    fused = DQN(config, cartpole, platform="gpu", agents=device_options.FUSED_MIN_AGENTS)
    flax = DQN(config, cartpole, platform="cpu")
    assert fused.fused_network and not flax.fused_network
    params = flax.init(jax.random.PRNGKey(0)).params
    key = jax.random.PRNGKey(3)
    assert "pallas_call" in str(jax.make_jaxpr(fused.evaluate)(params, key))
    assert "pallas_call" not in str(jax.make_jaxpr(flax.evaluate)(params, key))
    fused_returns = jax.jit(fused.evaluate)(params, key)
    np.testing.assert_array_equal(fused_returns, jax.jit(flax.evaluate)(params, key))
    assert len(set(np.asarray(fused_returns).tolist())) > 1  # episodes of different lengths
