"""PPO (agents/ppo.py): Brax's training step reproduced, seeds vmapped, exact resume, faults kept
from the learner, and a slow run judged on Gymnasium's InvertedPendulum-v5."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents.ppo import PPO, PPOConfig, TrainState, train


class Slide(envs.Env):
    """A point on a line pushed by the action: obs [x, v], reward 1 - x^2, cheap to compile.
    `start`: the first x (None: drawn uniformly from [-1, 1]); `terminate_beyond`: |x| that ends
    an episode (None: never)."""

    observation_size = 2
    action_size = 1

    def __init__(self, start=None, terminate_beyond=None):
        self.start, self.terminate_beyond = start, terminate_beyond

    def reset(self, key):
        x = jnp.float32(self.start) if self.start is not None else jax.random.uniform(key, (), minval=-1.0, maxval=1.0)
        zero = jnp.zeros(())
        return envs.State(jnp.stack([x, zero]), jnp.stack([x, zero]), zero, zero, info={"truncation": zero, "nan": zero})

    def step(self, state, action):
        self.check_action(action)
        x, v = state.pipeline_state
        v = 0.9 * v + 0.1 * action[0]
        x = x + 0.1 * v
        done = jnp.zeros(()) if self.terminate_beyond is None else (jnp.abs(x) > self.terminate_beyond).astype(jnp.float32)
        obs = jnp.stack([x, v])
        return state.replace(pipeline_state=obs, obs=obs, reward=1.0 - x**2, done=done)


SMALL = PPOConfig(num_timesteps=3 * 256, num_envs=8, unroll_length=8, batch_size=8, num_minibatches=4,
                  num_updates_per_batch=2, num_evals=4, num_eval_envs=4, policy_hidden=(16,), value_hidden=(16,),
                  learning_rate=3e-3)


def slide(episode_length=20, **kwargs):
    return envs.TimeLimit(Slide(**kwargs), episode_length=episode_length)


def assert_trees_equal(a, b):
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_config_rounds_like_brax_and_says_so():
    assert SMALL.env_steps_per_training_step == 256 and SMALL.num_chunks == 3
    assert (SMALL.eval_every, SMALL.total_steps, SMALL.rounding()) == (256, 768, "")
    rounded = PPOConfig(num_timesteps=300_000, num_evals=7)  # the inverted-pendulum recipe
    per_step = 64 * 16 * 16
    assert rounded.training_steps_per_chunk == -(-300_000 // (6 * per_step)) == 4
    assert rounded.eval_every == 4 * per_step and rounded.total_steps == 6 * 4 * per_step >= 300_000
    assert "rounded up to 393,216" in rounded.rounding() and rounded.eval_episodes == rounded.num_eval_envs
    with pytest.raises(ValueError, match=r"num_envs \(48\) must divide .* e\.g\. num_envs=32"):
        PPOConfig(num_envs=48)
    with pytest.raises(ValueError, match="num_evals"):
        PPOConfig(num_evals=1)
    with pytest.raises(ValueError, match="policy_hidden"):
        PPOConfig(policy_hidden=())
    with pytest.raises(ValueError, match="max_grad_norm"):
        PPOConfig(max_grad_norm=0.0)
    with pytest.raises(ValueError, match="discrete"):
        PPO(SMALL, envs.make("cartpole"))


def test_a_training_step_is_braxs():
    """One training step from Brax's own start (its network init, its keys, envs that all begin
    at the same state) gives the parameters and normalizer that `brax...ppo.train` returns."""
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as brax_ppo

    config = PPOConfig(num_timesteps=256, num_envs=16, unroll_length=8, batch_size=8, num_minibatches=4,
                       num_updates_per_batch=2, num_evals=2, num_eval_envs=4, policy_hidden=(16,),
                       value_hidden=(16,), max_grad_norm=1.0)
    env = slide(episode_length=100, start=0.5)  # no episode ends within the step's 16 steps per env
    seed = 3
    _, brax_params, _ = brax_ppo.train(
        envs.to_brax(env), num_timesteps=config.num_timesteps, episode_length=env.episode_length,
        num_envs=config.num_envs, unroll_length=config.unroll_length, batch_size=config.batch_size,
        num_minibatches=config.num_minibatches, num_updates_per_batch=config.num_updates_per_batch,
        learning_rate=config.learning_rate, entropy_cost=config.entropy_cost, discounting=config.discounting,
        gae_lambda=config.gae_lambda, clipping_epsilon=config.clipping_epsilon, max_grad_norm=config.max_grad_norm,
        reward_scaling=config.reward_scaling, normalize_observations=True, num_evals=2, run_evals=False, seed=seed,
        network_factory=functools.partial(ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=(16,),
                                          value_hidden_layer_sizes=(16,)))
    # Brax's keys (ppo/train.py): the networks' from the seed's first half, the first epoch's from its second.
    global_key, local_key = jax.random.split(jax.random.PRNGKey(seed))
    local_key = jax.random.split(jax.random.fold_in(local_key, 0), 3)[0]
    epoch_key = jax.random.split(jax.random.split(local_key)[0], 1)[0]
    ppo = PPO(config, env)
    ts = ppo.init(jax.random.PRNGKey(0))
    params = ppo.init_params(*jax.random.split(global_key))
    ts = ts.replace(params=params, opt_state=ppo.optimizer.init(_nets(params)), key=epoch_key)
    ts, _ = jax.jit(ppo.training_step)(ts)
    assert int(ts.env_steps) == config.env_steps_per_training_step
    moved = [not np.array_equal(a, b) for a, b in zip(jax.tree.leaves(ts.params), jax.tree.leaves(params))]
    assert sum(moved) >= len(moved) - 2  # all but the normalizer's constants (std_eps, ...) changed
    assert_trees_equal(ts.params, brax_params)  # bit for bit


def _nets(params):
    from brax.training.agents.ppo import losses

    return losses.PPONetworkParams(policy=params[1], value=params[2])


def run_chunks(ppo, ts, chunks, batched=None):
    """`chunks` chunks as train_run drives them: training steps, then the judge (`batched`: over seeds)."""
    wrap = batched or (lambda f: f)
    train_steps, judge = jax.jit(wrap(ppo.train_steps)), jax.jit(wrap(functools.partial(ppo.judge, record=False)))
    records = []
    for _ in range(chunks):
        ts, trained, eval_key = train_steps(ts)
        ts, judged = judge(ts, eval_key)
        records.append({**trained, **judged})
    return ts, records


@pytest.mark.parametrize("batched", ["vmap", "map"])
def test_seed_i_of_many_is_a_one_seed_run_of_seed_i(batched):
    ppo = PPO(SMALL, slide(terminate_beyond=1.5))
    keys = jax.random.split(jax.random.PRNGKey(7), 2)
    over_seeds = jax.vmap if batched == "vmap" else (lambda f: lambda *a: jax.lax.map(lambda x: f(*x), a))
    many, many_records = run_chunks(ppo, jax.jit(jax.vmap(ppo.init))(keys), 2, over_seeds)
    for i in range(2):
        one, one_records = run_chunks(ppo, jax.jit(ppo.init)(keys[i]), 2)
        assert_trees_equal(jax.tree.map(lambda x: x[i], many), one)  # bit for bit, every leaf of the state
        for a, b in zip(many_records, one_records):
            assert {k: float(v[i]) for k, v in a.items() if v is not None} == {
                k: float(v) for k, v in b.items() if v is not None}
    assert not np.array_equal(np.asarray(jax.tree.leaves(many.params)[-1][0]), np.asarray(jax.tree.leaves(many.params)[-1][1]))


def test_a_run_resumed_from_a_host_copy_ends_as_an_uninterrupted_one():
    """The train state is the whole run: copied to numpy between chunks (what a checkpoint saves)
    and back, the run goes on as if nothing happened."""
    ppo = PPO(SMALL, slide(terminate_beyond=1.5))
    start = jax.jit(ppo.init)(jax.random.PRNGKey(1))
    whole, whole_records = run_chunks(ppo, start, 3)
    part, _ = run_chunks(ppo, start, 1)
    leaves, treedef = jax.tree.flatten(part)
    saved = [np.array(leaf) for leaf in leaves]  # what a checkpoint holds
    resumed, resumed_records = run_chunks(ppo, jax.tree.unflatten(treedef, [jnp.asarray(x) for x in saved]), 2)
    assert_trees_equal(resumed, whole)
    assert [float(r["eval_return"]) for r in resumed_records] == [float(r["eval_return"]) for r in whole_records[1:]]
    assert int(resumed.env_steps) == SMALL.total_steps


@pytest.mark.slow  # about 2 minutes of 2 CPU cores
def test_inverted_pendulum_recipe_balances_gymnasiums_inverted_pendulum():
    """The table's inverted-pendulum recipe (agents/brax_defaults.py, Brax's field names), trained
    by our PPO: its best deterministic policy, mapped to Gymnasium's action space as
    `load_policy` maps it, scores at least 950 on Gymnasium's own InvertedPendulum-v5 (C MuJoCo,
    10 episodes)."""
    import gymnasium

    from agents import brax_defaults

    config = PPOConfig(**brax_defaults.settings("inverted-pendulum", "ppo"))
    env = envs.make("inverted-pendulum")
    ppo = PPO(config, env)
    ts, records = run_chunks(ppo, jax.jit(ppo.init)(jax.random.PRNGKey(0)), config.num_chunks)
    print(config.rounding(), [round(float(r["eval_return"]), 1) for r in records])
    assert float(ts.best_return) >= config.solve_return and int(ts.solve_step) > 0
    low, high = env.action_low, env.action_high
    act = jax.jit(lambda obs: ppo.policy(ts.best_params, obs))
    gym_env = gymnasium.make(env.unwrapped.gymnasium_id)
    returns = []
    for episode in range(10):
        obs, _ = gym_env.reset(seed=episode)
        total, done = 0.0, False
        while not done:
            unit = np.asarray(act(jnp.asarray(obs, jnp.float32)))
            obs, reward, terminated, truncated, _ = gym_env.step(0.5 * (high + low) + np.clip(unit, -1, 1) * 0.5 * (high - low))
            total, done = total + float(reward), terminated or truncated
        returns.append(total)
    print("InvertedPendulum-v5 returns:", returns)
    assert np.mean(returns) >= 950
