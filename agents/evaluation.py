"""What every agent's evaluation and chunk loop share: fresh episodes of its deterministic policy,
the judge that keeps the best parameters and the solve step, and a chunk's training steps."""

from __future__ import annotations

from functools import partial
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp

from envs import Env, VmapWrapper


class EvalEpisode(NamedTuple):
    """One evaluation episode, a row per step (the pose: `env.scene_qpos`); rows from `length` on are padding."""

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    scene_qpos: jax.Array | None
    length: jax.Array


def evaluate(env: Env, act: Callable[[jax.Array], jax.Array], key: jax.Array, num_episodes: int,
             action: jax.ShapeDtypeStruct, record: bool = False):
    """The return of each of `num_episodes` fresh episodes of `env` under `act(obs batch) -> action batch`;
    with `record`, also the first episode as an `EvalEpisode` (actions shaped like `action`), for loggers."""
    batch = VmapWrapper(env, num_episodes)
    horizon = getattr(env, "episode_length", 1000)
    scene_qpos = getattr(env, "scene_qpos", None)

    def step(carry):
        state, returns, finished, episode = carry
        actions = act(state.obs)
        next_state = batch.step(state, actions)
        if record:
            t = episode.length
            first = jax.tree.map(lambda x: x[0], state.pipeline_state)
            episode = EvalEpisode(
                obs=episode.obs.at[t].set(state.obs[0], mode="drop"),
                action=episode.action.at[t].set(actions[0], mode="drop"),
                reward=episode.reward.at[t].set(next_state.reward[0], mode="drop"),
                scene_qpos=None if scene_qpos is None else episode.scene_qpos.at[t].set(scene_qpos(first), mode="drop"),
                length=t + (~finished[0]).astype(jnp.int32))
        returns = returns + next_state.reward * ~finished
        return next_state, returns, finished | (next_state.done > 0), episode

    state = batch.reset(key)
    zeros = jnp.zeros(state.reward.shape, state.reward.dtype)
    episode = None
    if record:
        first = jax.tree.map(lambda x: x[0], state.pipeline_state)
        episode = EvalEpisode(
            obs=jnp.zeros((horizon, *state.obs.shape[1:]), state.obs.dtype),  # a vector or an image
            action=jnp.zeros((horizon, *action.shape), action.dtype),
            reward=jnp.zeros((horizon,), state.reward.dtype),
            scene_qpos=None if scene_qpos is None else jnp.zeros((horizon,) + scene_qpos(first).shape),
            length=jnp.zeros((), jnp.int32))
    _, returns, _, episode = jax.lax.while_loop(lambda carry: ~carry[2].all(), step, (state, zeros, zeros > 0, episode))
    return (returns, episode) if record else returns


def step_stats(info: dict) -> tuple[jax.Array, dict]:
    """MuJoCo Warp's overflow code of the steps in `info` (`envs.mjx_env`) and their episode statistics."""
    overflow = info.get("overflow", jnp.zeros_like(info["nan"]))
    return overflow, {
        "episodes": info["episode_done"].sum(), "return_sum": (info["last_return"] * info["episode_done"]).sum(),
        "nan_episodes": info["nan"].sum(),
        "overflow_contacts": (overflow % 2 == 1).sum(), "overflow_constraints": (overflow >= 2).sum()}


def episode_metrics(totals: dict) -> dict:
    """A chunk's training-episode metrics from the running totals of `step_stats`."""
    episodes = totals["episodes"]
    return {"episodes": episodes, "train_return": totals["return_sum"] / jnp.maximum(episodes, 1),
            "nan_episodes": totals["nan_episodes"], "overflow_contacts": totals["overflow_contacts"].astype(jnp.int32),
            "overflow_constraints": totals["overflow_constraints"].astype(jnp.int32)}


class ChunkLoop(NamedTuple):
    """A chunk's training steps as pure pieces, to run as one program (`whole_chunk`) or several (`chunk_part`):
    `start(ts) -> (ts, pending)` (with "eval_key"), `step(ts) -> (ts, stats)` `iterations` times, and
    `finish(ts, pending, totals) -> (ts, metrics)` (`totals`: each stat's name and dtype)."""

    iterations: int
    start: Callable
    step: Callable
    finish: Callable
    totals: dict


def _add_up(loop: ChunkLoop, carry, _):
    ts, totals = carry
    ts, stats = loop.step(ts)
    return (ts, {name: (total + stats[name]).astype(total.dtype) for name, total in totals.items()}), None


def _zero_totals(loop: ChunkLoop) -> dict:
    return {name: jnp.zeros((), dtype) for name, dtype in loop.totals.items()}


def whole_chunk(loop: ChunkLoop, ts: Any) -> tuple[Any, dict, jax.Array]:
    """A chunk's training steps in one program: the train state, metrics and evaluation key (`train_steps`)."""
    ts, pending = loop.start(ts)
    (ts, totals), _ = jax.lax.scan(partial(_add_up, loop), (ts, _zero_totals(loop)), None, length=loop.iterations)
    ts, metrics = loop.finish(ts, pending, totals)
    return ts, metrics, pending["eval_key"]


def chunk_part(loop: ChunkLoop, parts: int, ts: Any, carry: tuple) -> tuple:
    """Part `carry[0]` of `parts` of a chunk, the parts in turn ending as `whole_chunk` does, to the bit: the
    train state, the next carry (`part_carry`), the metrics and evaluation key (zeros before the last part)."""
    index, pending, totals = carry
    ts, pending, totals = jax.lax.cond(index == 0, lambda: (*loop.start(ts), _zero_totals(loop)),
                                       lambda: (ts, pending, totals))
    (ts, totals), _ = jax.lax.scan(partial(_add_up, loop), (ts, totals), None, length=loop.iterations // parts)
    shapes = jax.eval_shape(loop.finish, ts, pending, totals)[1]
    ts, metrics = jax.lax.cond(index == parts - 1, lambda: loop.finish(ts, pending, totals),
                               lambda: (ts, jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), shapes)))
    return ts, (index + 1, pending, totals), metrics, pending["eval_key"]


def part_carry(loop_of: Callable[[Any], ChunkLoop], ts: Any) -> tuple:
    """The zero carry of a chunk's first part (`chunk_part`) for the train state `ts` (arrays or shapes)."""
    loop = loop_of(ts)
    pending = jax.eval_shape(lambda t: loop.start(t)[1], ts)
    return (jnp.zeros((), jnp.int32), jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), pending), _zero_totals(loop))


def keep_best(ts: Any, eval_returns: jax.Array, eval_episode: EvalEpisode | None,
              solve_return: float | None) -> tuple[Any, dict]:
    """Keep the best parameters and the first env step whose evaluation reached `solve_return`; and metrics."""
    eval_return = eval_returns.mean()
    better = eval_return > ts.best_return
    solved_now = (ts.solve_step < 0) & (False if solve_return is None else eval_return >= solve_return)
    ts = ts.replace(
        best_params=jax.tree.map(lambda new, old: jnp.where(better, new, old), ts.params, ts.best_params),
        best_return=jnp.maximum(eval_return, ts.best_return),
        solve_step=jnp.where(solved_now, ts.env_steps, ts.solve_step))
    return ts, {"env_steps": ts.env_steps, "eval_return": eval_return, "best_return": ts.best_return,
                "eval_episode": eval_episode}


def evaluate_and_keep_best(agent: Any, ts: Any, eval_key: jax.Array, record: bool) -> tuple[Any, dict]:
    """`keep_best` of `agent.evaluate(ts.params, eval_key)`: an agent's `evaluate_and_keep_best` method."""
    returns, episode = agent.evaluate(ts.params, eval_key, record=True) if record else (
        agent.evaluate(ts.params, eval_key), None)
    return keep_best(ts, returns, episode, agent.config.solve_return)


def whole_run(agent: Any, key: jax.Array):
    """A whole run of `agent` as one pure function (its `train`): `(best_params, metrics)`."""
    ts = agent.init(key)
    ts, metrics = jax.lax.scan(lambda ts, _: agent.chunk(ts, record=False), ts, None, agent.config.num_chunks)
    metrics.pop("eval_episode")
    return ts.best_params, {**metrics, "solve_step": ts.solve_step, "final_params": ts.params}
