"""The peers in the env-throughput benchmark: gymnax and MuJoCo Playground.

Each `*_rollout` returns `run(key) -> (total reward, final observations)`: `steps` steps of `num_envs`
auto-resetting envs under uniformly random actions, as one `lax.scan` — the same
loop `benchmarks.env_throughput.rollout_fn` runs for our envs, so the three are timed alike.
Returning both keeps XLA from dropping work whose result nobody reads.

Both peers are optional (the `bench` extra): a missing one raises `PeerMissing`
with the reason, and `benchmarks.env_throughput` records it as skipped.

- gymnax 1.0.1 `CartPole-v1`: the analytic Gymnasium equations. Its `step` takes
  a key per env and auto-resets with a select between the stepped and a freshly
  drawn state (like our `AutoReset`).
- MuJoCo Playground 0.2.0 `CartpoleBalance` (dm_control's cart-pole) with
  `impl="jax"` (its default is Warp), wrapped by its own
  `wrap_for_brax_training`, which auto-resets to a cached first state. Its model
  differs from ours: timestep 0.01, a slider range (one constraint row for the
  solver), joint damping; our CartPole has no constraints at all.
"""

from __future__ import annotations

import contextlib
import io

import jax
import jax.numpy as jnp

PEER_VERSIONS = {"gymnax": "1.0.1", "playground": "0.2.0"}
PEER_ENVS = {"gymnax": "CartPole-v1", "playground": "CartpoleBalance"}


class PeerMissing(RuntimeError):
    """A peer library is not installed (or does not import); the message says why."""


def _import(name: str, package: str):
    try:
        with contextlib.redirect_stdout(io.StringIO()):  # MJX's "Failed to import warp"
            return __import__(name, fromlist=["_"])
    except Exception as err:  # ImportError, or a peer's own import-time failure
        raise PeerMissing(
            f"{package}=={PEER_VERSIONS[package]} is not usable ({type(err).__name__}: {err}); "
            f"install it with: pip install --no-deps {package}=={PEER_VERSIONS[package]} "
            f"(and the bench extra: pip install 'mjxsuite[bench]')"
        ) from err


def random_actions(key: jax.Array, num_envs: int, num_actions: int) -> jax.Array:
    """Uniform action indices from one `random.bits` draw: half the random words of
    `random.randint`, so the policy costs the benchmarked envs as little as it can.
    The modulo's bias is below num_actions / 2**32. Every discrete library uses it."""
    return (jax.random.bits(key, (num_envs,), jnp.uint32) % num_actions).astype(jnp.int32)


def version(package: str) -> str | None:
    from importlib import metadata

    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return None


def gymnax_rollout(num_envs: int, steps: int):
    gymnax = _import("gymnax", "gymnax")
    env, params = gymnax.make("CartPole-v1")
    num_actions = env.num_actions
    step = jax.vmap(env.step, in_axes=(0, 0, 0, None))
    reset = jax.vmap(env.reset, in_axes=(0, None))

    def body(carry, _):
        state, key, total = carry
        key, action_key, step_key = jax.random.split(key, 3)
        action = random_actions(action_key, num_envs, num_actions)
        _, state, reward, _, _, _ = step(jax.random.split(step_key, num_envs), state, action, params)
        return (state, key, total + reward.sum()), None

    @jax.jit
    def run(key):
        key, reset_key = jax.random.split(key)
        _, state = reset(jax.random.split(reset_key, num_envs), params)
        (state, _, total), _ = jax.lax.scan(body, (state, key, jnp.zeros(())), None, steps)
        return total, jax.vmap(env.get_obs)(state)

    return run


def playground_rollout(num_envs: int, steps: int):
    playground = _import("mujoco_playground", "playground")
    registry, wrapper = playground.registry, playground.wrapper
    env = registry.load("CartpoleBalance", config_overrides={"impl": "jax"})
    if env.mjx_model.impl.value != "jax":
        raise PeerMissing(f"playground CartpoleBalance did not select impl='jax' (got {env.mjx_model.impl})")
    episode_length = int(registry.get_default_config("CartpoleBalance").episode_length)
    env = wrapper.wrap_for_brax_training(env, episode_length=episode_length)
    action_size = env.action_size

    def body(carry, _):
        state, key, total = carry
        key, action_key = jax.random.split(key)
        action = jax.random.uniform(action_key, (num_envs, action_size), minval=-1.0, maxval=1.0)
        state = env.step(state, action)
        return (state, key, total + state.reward.sum()), None

    @jax.jit
    def run(key):
        key, reset_key = jax.random.split(key)
        state = env.reset(jax.random.split(reset_key, num_envs))
        (state, _, total), _ = jax.lax.scan(body, (state, key, jnp.zeros(())), None, steps)
        return total, state.obs

    return run


ROLLOUTS = {"gymnax": gymnax_rollout, "playground": playground_rollout}
