"""Rerun logging of DQN training: curves per seed and greedy evaluation rollouts.

`TrainingLogger` is an `on_chunk(index, train_state, record)` callback for
`agents.run.train_run`. After every chunk it sends, on the `train_step` timeline,

  train/seed_<s>/loss, mean_q, epsilon, eval_return, train_return, env_steps_per_s
  train/env_steps_per_s                     all seeds together

and every `rollout_every` chunks one greedy rollout per seed of the current
parameters, drawn like `mjxsuite rollout` under `eval/seed_<s>/` (env/0/..., world/env_0/...).
Successive evaluations follow each other on that prefix's `step` timeline;
`eval/seed_<s>/train_step` marks where each one starts and the train step it shows.
"""

from __future__ import annotations

import os
import queue
import threading
import time
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import rerun as rr

import envs
from agents.dqn import DQN, DQNConfig
from envs import recording

MAX_PENDING_ROLLOUTS = 8  # evaluations queued for the worker; later ones are skipped until it catches up
SEED_CURVES = {"loss": "loss", "q": "mean_q", "epsilon": "epsilon", "eval_return": "eval_return",
               "train_return": "train_return"}


def greedy_policy(dqn: DQN) -> recording.PolicyFn:
    """`(params, obs, key) -> argmax_a Q(obs, a)`, jittable, for `recording.collect_rollout`."""
    return lambda params, obs, key: jnp.argmax(dqn.q_values(params, obs), axis=-1).astype(jnp.int32)


def load_greedy(out_dir: str | os.PathLike, seed_index: int | None = None):
    """The env and jittable greedy policy saved by `mjxsuite train --out DIR`: `(env_name, env, policy, params)`.

    With several trained seeds it takes the one with the best greedy evaluation unless `seed_index` picks one.
    """
    from agents.run import load_agent, pick_seed

    env_name, env, dqn, params = load_agent(out_dir)
    return env_name, env, greedy_policy(dqn), pick_seed(out_dir, params, seed_index)


class TrainingLogger:
    """Writes a training run to `path` (checked before any training starts; see module docstring).

    Use as `train_run(..., on_chunk=logger)` and call `logger.close()` in a `finally`,
    so an interrupted run still leaves a readable file. The curves are sent from the
    callback; evaluation rollouts are compiled, collected and logged on a worker thread
    (`background=False`: in the callback), and skipped, with a warning at `close()`,
    when more than MAX_PENDING_ROLLOUTS are waiting.
    """

    def __init__(self, path: str | os.PathLike, env_name: str, config: DQNConfig, *, seeds: int = 1,
                 env_options: dict | None = None, overwrite: bool = False, rollout_every: int = 1,
                 rollout_steps: int | None = None, seed: int = 0, background: bool = True):
        if rollout_every < 0:
            raise ValueError(f"rollout_every must be >= 0 (0: no evaluation rollouts), got {rollout_every}")
        self.rec = recording.open_recording(path, overwrite)
        self.path = path
        self.seeds = seeds
        self.rollout_every = rollout_every
        self.env = envs.make(env_name, **(env_options or {}))
        dqn = DQN(config, self.env)
        self.policy = greedy_policy(dqn)
        self.rollout_steps = rollout_steps or getattr(self.env, "episode_length", 500)
        self.key = jax.random.fold_in(jax.random.PRNGKey(seed), 2)
        self.rollouts_logged = 0
        self.scene = recording.env_scene(self.env)
        for name in SEED_CURVES.values():
            for s in range(seeds):
                self.rec.log(f"train/seed_{s}/{name}", rr.SeriesLines(names=f"{name} (seed {s})"), static=True)
        # Evaluation rollouts (compile, collect, log) run on a worker thread, so training
        # only waits for the host copy of the parameters. The worker compiles the rollout
        # right away, while train_run compiles its own chunk.
        self._jobs: queue.Queue = queue.Queue(maxsize=MAX_PENDING_ROLLOUTS)
        self._error: BaseException | None = None
        self.rollouts_skipped = 0
        self.worker_busy_s = 0.0  # time the worker spent compiling and logging rollouts
        self._worker = None
        if rollout_every and background:
            self._worker = threading.Thread(target=self._work, args=(dqn,), name="rerun-eval-rollouts", daemon=True)
            self._worker.start()

    def __call__(self, index: int, train_state: Any, record: dict) -> None:
        train_step = int(np.atleast_1d(record["env_steps"])[0])
        self._log_curves(train_step, record)
        if self.rollout_every and index % self.rollout_every == 0:
            # Copied now: the train state's buffers are donated to the next chunk.
            job = (index, train_step, jax.device_get(train_state.params))
            if self._worker is None:
                self._log_rollouts(*job)
                return
            try:
                self._jobs.put_nowait(job)
            except queue.Full:  # logging fell behind: skip this evaluation rather than stall training
                self.rollouts_skipped += 1

    def _work(self, dqn: DQN) -> None:
        start = time.perf_counter()
        try:
            # Zeros shaped like the parameters: an eager `network.init` would compile op by op.
            shapes = jax.eval_shape(dqn.network.init, jax.random.PRNGKey(0), jnp.zeros((1, self.env.observation_size)))
            params = jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), shapes)
            jax.block_until_ready(recording.collect_rollout(self.env, self.policy, self.key, steps=self.rollout_steps,
                                                            params=params, fast_compile=True))
        except Exception:  # noqa: BLE001 - the first real evaluation fails the same way, and reports it
            pass
        self.worker_busy_s += time.perf_counter() - start
        while (job := self._jobs.get()) is not None:
            start = time.perf_counter()
            if self._error is None:
                try:
                    self._log_rollouts(*job)
                except BaseException as err:  # noqa: BLE001 - reported by close()
                    self._error = err
            self.worker_busy_s += time.perf_counter() - start

    def _send(self, path: str, train_step: int, value: float) -> None:
        self.rec.send_columns(path, indexes=[rr.TimeColumn("train_step", sequence=[train_step])],
                              columns=rr.Scalars.columns(scalars=[float(value)]))

    def _log_curves(self, train_step: int, record: dict) -> None:
        for key, name in SEED_CURVES.items():
            for s, value in enumerate(np.atleast_1d(record[key])):
                self._send(f"train/seed_{s}/{name}", train_step, value)
        self._send("train/env_steps_per_s", train_step, record["steps_per_s"])
        for s in range(self.seeds):
            self._send(f"train/seed_{s}/env_steps_per_s", train_step, record["steps_per_s"] / self.seeds)

    def _log_rollouts(self, index: int, train_step: int, params: Any) -> None:
        """One greedy rollout per seed of `params` (host arrays with a leading seed axis)."""
        step_offset = self.rollouts_logged * self.rollout_steps
        for s in range(self.seeds):
            root = f"eval/seed_{s}"
            rollout = recording.collect_rollout(
                self.env, self.policy, jax.random.fold_in(self.key, index), num_envs=1,
                steps=self.rollout_steps, params=jax.tree.map(lambda x: x[s], params), fast_compile=True)
            recording.log_rollout(self.rec, self.env, rollout, root=root, step_offset=step_offset,
                                  static=self.rollouts_logged == 0, scene=self.scene)
            self.rec.send_columns(f"{root}/train_step", indexes=[rr.TimeColumn("step", sequence=[step_offset])],
                                  columns=rr.Scalars.columns(scalars=[float(train_step)]))
        self.rollouts_logged += 1

    def close(self) -> None:
        """Finish pending rollouts, then flush and close the file (it gets its footer); safe to call twice."""
        if self._worker is not None:
            self._jobs.put(None)
            self._worker.join()
            self._worker = None
        if self.rollouts_skipped:
            warnings.warn(f"Rerun log: skipped {self.rollouts_skipped} evaluation rollouts that fell behind "
                          "training; log them less often with a larger --rerun-every", stacklevel=2)
            self.rollouts_skipped = 0
        if self.rec is not None:
            recording.close_recording(self.rec)
            self.rec = None
        if self._error is not None:
            error, self._error = self._error, None
            raise RuntimeError(f"an evaluation rollout for the Rerun log failed: {error!r}") from error
