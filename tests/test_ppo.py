"""PPO (agents/ppo.py): Brax's training step reproduced, seeds vmapped, exact resume, faults kept
from the learner, and a slow run judged on Gymnasium's InvertedPendulum-v5."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents.ppo import PPO, PPOConfig, TrainState, train
from conftest import USERS_CODEGEN
from test_sac import assert_trees_equal, mapped, run_chunks as sac_run_chunks


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


@pytest.mark.slow
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


def run_chunks(ppo, ts, chunks, batched=None, users_codegen=False):
    """`chunks` chunks as train_run drives them (`test_sac.run_chunks`), the judge recording no episode."""
    return sac_run_chunks(ppo, ts, chunks, batched, record=False, users_codegen=users_codegen)


@pytest.mark.heavy
def test_seed_i_of_many_is_a_one_seed_run_of_seed_i():
    env = slide(terminate_beyond=1.5)
    ppo = PPO(SMALL, env)
    keys = jax.random.split(jax.random.PRNGKey(7), 2)
    # Bit for bit where compiled as users' programs are (XLA:CPU's level 1 rounds the vmapped chunk otherwise).
    singles = [run_chunks(ppo, jax.jit(ppo.init, compiler_options=USERS_CODEGEN)(key), 2, users_codegen=True)
               for key in keys]
    for batched in (jax.vmap, mapped):
        many, records = run_chunks(ppo, jax.jit(batched(ppo.init), compiler_options=USERS_CODEGEN)(keys), 2, batched,
                                   users_codegen=True)
        for i, (one, one_records) in enumerate(singles):
            assert_trees_equal(jax.tree.map(lambda x: x[i], many), one)  # bit for bit, every leaf of the state
            for a, b in zip(records, one_records, strict=True):
                assert {k: float(v[i]) for k, v in a.items() if v is not None} == {
                    k: float(v) for k, v in b.items() if v is not None}
    first = [np.asarray(jax.tree.leaves(one.params[1])[0]) for one, _ in singles]
    assert not np.allclose(first[0], first[1])  # independent keys, different agents
    assert {"loss", "policy_loss", "v_loss", "entropy_loss", "episodes", "train_return", "nan_episodes",
            "overflow_contacts", "overflow_constraints", "env_steps", "eval_return", "best_return"} <= set(records[0])
    assert int(singles[0][0].env_steps) == 2 * SMALL.eval_every
    assert float(records[-1]["episodes"][0]) > 0  # episodes end (|x| > 1.5 or the time limit) and are counted


@pytest.mark.slow
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


def test_the_policy_is_brax_deterministic_policy_on_brax_parameter_layout():
    """`params` has the layout of Brax's PPO parameters (what `benchmarks.brax_trainers` builds), and
    `policy` acts as Brax's deterministic policy does, in [-1, 1]."""
    from benchmarks import brax_trainers

    env = slide()
    ppo = PPO(SMALL, env)
    ts = jax.jit(ppo.init)(jax.random.PRNGKey(0))
    brax_config = SMALL
    template = brax_trainers.params_template(brax_config, env.observation_size, env.action_size)
    assert jax.tree.structure(template) == jax.tree.structure(ts.params)
    for a, b in zip(jax.tree.leaves(template), jax.tree.leaves(ts.params), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
    obs = 10 * jax.random.normal(jax.random.PRNGKey(1), (32, env.observation_size))
    ours = jax.jit(ppo.policy)(ts.params, obs)
    brax = brax_trainers.deterministic_policy(brax_config, env.observation_size, env.action_size)(ts.params, obs, None)
    np.testing.assert_array_equal(np.asarray(ours), np.asarray(brax))
    assert ours.shape == (32, 1) and np.all(np.abs(np.asarray(ours)) <= 1.0)


def test_truncation_reaches_the_loss_and_a_physics_fault_is_a_truncation():
    """The unroll keeps Brax's meaning: `truncation` 1 where the time limit ended an episode
    (Brax's GAE bootstraps there), `discount` 0 wherever an episode ended. A step whose physics
    failed (`info["nan"]`, MJX's `info["overflow"]`) is marked a truncation, so it teaches no
    value and no advantage, and is counted."""
    ppo = PPO(SMALL, slide(episode_length=3))
    ts = ppo.init(jax.random.PRNGKey(0))
    _, data = ppo.collect(ts, jax.random.PRNGKey(1))
    assert data.observation.shape == (SMALL.batch_size * SMALL.num_minibatches, SMALL.unroll_length, 2)
    truncation = np.asarray(data.extras["state_extras"]["truncation"])
    # Row r is unroll r // num_envs of env r % num_envs; each env's unrolls follow one another, and
    # every third step of an env ends its episode by the time limit.
    rows, steps = np.arange(truncation.shape[0])[:, None], np.arange(SMALL.unroll_length)[None, :]
    env_step = rows // SMALL.num_envs * SMALL.unroll_length + steps
    np.testing.assert_array_equal(truncation, (env_step % 3 == 2).astype(np.float32))
    np.testing.assert_array_equal(np.asarray(data.discount), 1.0 - truncation)
    extras = dict(data.extras["state_extras"])
    nan = np.zeros_like(truncation)
    nan[0, 0] = 1.0
    overflow = np.zeros_like(truncation)
    overflow[1, 1], overflow[2, 1] = 1.0, 3.0
    faulty = data._replace(extras={**data.extras, "state_extras": {**extras, "nan": jnp.asarray(nan),
                                                                   "overflow": jnp.asarray(overflow)}})
    learned, stats = ppo.without_faults(faulty)
    marked = np.asarray(learned.extras["state_extras"]["truncation"])
    assert set(learned.extras["state_extras"]) == {"truncation"}
    assert marked[0, 0] == marked[1, 1] == marked[2, 1] == 1.0
    np.testing.assert_array_equal(np.delete(marked.ravel(), [0, SMALL.unroll_length + 1, 2 * SMALL.unroll_length + 1]),
                                  np.delete(truncation.ravel(), [0, SMALL.unroll_length + 1, 2 * SMALL.unroll_length + 1]))
    assert (float(stats["nan_episodes"]), int(stats["overflow_contacts"]), int(stats["overflow_constraints"])) == (1, 2, 1)
    assert float(stats["episodes"]) == truncation.sum()


def test_judge_keeps_the_best_parameters_and_the_first_solving_step():
    ppo = PPO(dataclasses.replace(SMALL, solve_return=-1e9), slide())  # any evaluation solves it
    ts = jax.jit(ppo.init)(jax.random.PRNGKey(0))
    ts = ts.replace(env_steps=jnp.int32(256))
    judged, metrics = jax.jit(ppo.evaluate_and_keep_best)(ts, jax.random.PRNGKey(1))
    assert int(judged.solve_step) == 256 and float(judged.best_return) == float(metrics["eval_return"])
    assert metrics["eval_episode"].length > 0 and metrics["eval_episode"].action.shape == (20, 1)
    returns = ppo.evaluate(ts.params, jax.random.PRNGKey(1))
    assert returns.shape == (SMALL.eval_episodes,) and float(returns.mean()) == float(metrics["eval_return"])
    not_better = judged.replace(env_steps=jnp.int32(512), best_return=jnp.float32(1e9))
    later, _ = jax.jit(ppo.evaluate_and_keep_best)(not_better, jax.random.PRNGKey(1))
    assert int(later.solve_step) == 256  # the first solving step stays
    assert_trees_equal(later.best_params, judged.best_params)  # not better than 1e9: the best stays
    unsolvable, _ = jax.jit(PPO(SMALL, slide()).evaluate_and_keep_best)(ts, jax.random.PRNGKey(1))  # no solve_return
    assert int(unsolvable.solve_step) == -1


@pytest.mark.heavy  # ~10 s: the default run stays under 6 minutes on 2 cores
def test_a_sweep_agent_is_a_separate_run_of_its_config():
    """`hyperparams` (a sweep's traced values) give each agent the run of its own config, up to
    float rounding: XLA simplifies products with a constant learning rate or discount
    differently from products with a traced one (a last-bit difference per update)."""
    from agents.ppo import Hyperparams

    env = slide(terminate_beyond=1.5)
    configs = [dataclasses.replace(SMALL, learning_rate=1e-3, entropy_cost=1e-2, discounting=0.9),
               dataclasses.replace(SMALL, gae_lambda=0.8, reward_scaling=0.5)]
    ppo = PPO(SMALL, env)
    key = jax.random.PRNGKey(2)
    swept, _ = run_chunks(ppo, jax.jit(jax.vmap(ppo.init, in_axes=(None, 0)))(key, Hyperparams.stacked(configs)), 1,
                          jax.vmap)
    for i, config in enumerate(configs):
        alone, _ = run_chunks(PPO(config, env), jax.jit(PPO(config, env).init)(key), 1)
        for a, b in zip(jax.tree.leaves(jax.tree.map(lambda x: x[i], swept.replace(hyperparams=None))),
                        jax.tree.leaves(alone), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-4, atol=1e-6)
    other, _ = run_chunks(PPO(configs[1], env), jax.jit(PPO(configs[1], env).init)(key), 1)
    assert not np.allclose(np.asarray(swept.params[1]["params"]["hidden_0"]["kernel"][0]),
                           np.asarray(other.params[1]["params"]["hidden_0"]["kernel"]), rtol=1e-4, atol=1e-6)


def test_on_the_cpu_a_sweeps_seeds_start_one_after_another_each_with_its_hyperparameters():
    """train_run's init on the CPU runs the agents one after another (`agents.run.seeds_init`); a sweep's init takes
    each agent's hyperparameters beside its key, so mapping must pass both."""
    from agents.ppo import Hyperparams
    from agents.run import seeds_init

    ppo = PPO(SMALL, slide(terminate_beyond=1.5))
    hyperparams = Hyperparams.stacked([dataclasses.replace(SMALL, learning_rate=lr) for lr in (1e-3, 3e-4)])
    keys = jax.random.split(jax.random.PRNGKey(3), 2)
    one_after_another = jax.jit(seeds_init(ppo, 2))(keys, hyperparams)
    batched = jax.jit(jax.vmap(ppo.init))(keys, hyperparams)
    assert_trees_equal(one_after_another.hyperparams, hyperparams)
    for a, b in zip(jax.tree.leaves(one_after_another), jax.tree.leaves(batched), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-6, atol=1e-7)
