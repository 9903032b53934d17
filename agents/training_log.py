"""Rerun logging of training: curves per seed and evaluation rollouts (docs/recording.md).

`TrainingLogger`, an `on_chunk` callback of `agents.run.train_run`, logs each seed's curves and, every
`rollout_every` chunks, its first evaluation episode (recorded inside the chunk: no extra rollout).
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np
import rerun as rr

import envs
from agents.dqn import DQNConfig
from agents.evaluation import EvalEpisode
from envs import recording

# Each agent's curves: {record key: curve name}; every agent's chunk also records its evaluation.
_RETURNS = {"eval_return": "eval_return", "train_return": "train_return"}
CURVES = {
    "dqn": {"loss": "loss", "q": "mean_q", "epsilon": "epsilon", **_RETURNS},
    "ppo": {**_RETURNS, "policy_loss": "policy_loss", "v_loss": "v_loss", "entropy_loss": "entropy_loss"},
    "sac": {**_RETURNS, "actor_loss": "actor_loss", "critic_loss": "critic_loss", "alpha": "alpha"},
    "td3": {**_RETURNS, "actor_loss": "actor_loss", "critic_loss": "critic_loss", "target_q": "target_q"},
}


class TrainingLogger:
    """Writes a training run to `path`: `train_run(..., on_chunk=logger)`, then `logger.close()` in a `finally`."""

    def __init__(self, path: str | os.PathLike, env_name: str, config: DQNConfig | Any, *, seeds: int = 1,
                 env_options: dict | None = None, overwrite: bool = False, rollout_every: int = 1,
                 agent_paths: tuple[list[str], list[str]] | None = None, curves: dict[str, str] = CURVES["dqn"]):
        """`agent_paths`: (entity paths, series labels) of the agents (`agents.sweep.agent_paths`);
        default `seed_<s>`, "seed <s>". `curves`: `CURVES[agent]` (default DQN's)."""
        if rollout_every < 0:
            raise ValueError(f"rollout_every must be >= 0 (0: no evaluation rollouts), got {rollout_every}")
        self.rec = recording.open_recording(path, overwrite)
        self.seeds = seeds
        self.paths, self.labels = agent_paths or ([f"seed_{s}" for s in range(seeds)], [f"seed {s}" for s in range(seeds)])
        self.rollout_every = rollout_every
        self.env = envs.make(env_name, **(env_options or {}))
        self.steps_logged = 0  # evaluation steps already on the eval/ `step` timeline
        self.rollouts_logged = 0
        self.scene = recording.env_scene(self.env)
        self.curves = curves
        for name in curves.values():
            for s in range(seeds):
                self.rec.log(f"train/{self.paths[s]}/{name}", rr.SeriesLines(names=f"{name} ({self.labels[s]})"),
                             static=True)

    def __call__(self, index: int, train_state: Any, record: dict) -> None:
        train_step = int(np.atleast_1d(record["env_steps"])[0])
        self._log_curves(train_step, record)
        if self.rollout_every and index % self.rollout_every == 0 and record.get("eval_episode") is not None:
            episode = jax.device_get(record["eval_episode"])
            self._log_episodes(train_step, [episode_rollout(jax.tree.map(lambda x: x[s], episode))
                                            for s in range(self.seeds)])

    def _send(self, path: str, step: int, value: float, timeline: str = "train_step") -> None:
        self.rec.send_columns(path, indexes=[rr.TimeColumn(timeline, sequence=[step])],
                              columns=rr.Scalars.columns(scalars=[float(value)]))

    def _log_curves(self, train_step: int, record: dict) -> None:
        for key, name in self.curves.items():
            if record.get(key) is None:
                continue
            for s, value in enumerate(np.atleast_1d(record[key])):
                self._send(f"train/{self.paths[s]}/{name}", train_step, value)
        self._send("train/env_steps_per_s", train_step, record["steps_per_s"])
        for s in range(self.seeds):
            self._send(f"train/{self.paths[s]}/env_steps_per_s", train_step, record["steps_per_s"] / self.seeds)

    def _log_episodes(self, train_step: int, rollouts: list[recording.Rollout]) -> None:
        """One greedy episode of each seed (one-env host rollouts)."""
        for s, rollout in enumerate(rollouts):
            root = f"eval/{self.paths[s]}"
            recording.log_rollout(self.rec, self.env, rollout, root=root, step_offset=self.steps_logged,
                                  static=self.rollouts_logged == 0, scene=self.scene)
            self._send(f"{root}/train_step", self.steps_logged, train_step, timeline="step")
        self.steps_logged += max((rollout.reward.shape[0] for rollout in rollouts), default=0)
        self.rollouts_logged += 1

    def close(self) -> None:
        """Flush and close the file (it gets its footer); safe to call twice."""
        if self.rec is not None:
            recording.close_recording(self.rec)
            self.rec = None


def episode_rollout(episode: EvalEpisode) -> recording.Rollout:
    """One recorded evaluation episode as a one-env `Rollout` (padding cut off)."""
    length = max(int(episode.length), 1)
    reward = np.asarray(episode.reward[:length])
    done = np.zeros(length, np.float32)
    done[-1] = float(episode.length > 0)
    return recording.Rollout(
        obs=np.asarray(episode.obs[:length])[:, None], action=np.asarray(episode.action[:length])[:, None],
        reward=reward[:, None], done=done[:, None],
        episode_return=(done * reward.sum())[:, None], episode_length=(done * length)[:, None],
        scene_qpos=None if episode.scene_qpos is None else np.asarray(episode.scene_qpos[:length])[:, None],
    )
