"""A contact task for the MuJoCo Warp checks: Gymnasium's `half_cheetah.xml` (7 bodies, 6 motors,
ground contacts), read from the installed `gymnasium` package, with HalfCheetah-v5's frame skip,
reset noise, observation and reward. `contact_task_name()` is the registered name to pass to
`envs.make` / `envs.to_brax`: the suite's own `half-cheetah` where it exists, else this class,
registered as `half-cheetah-contact` the first time it is asked for."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp

import envs
from envs.mjx_env import MjxEnv

NAME = "half-cheetah-contact"


def half_cheetah_xml() -> Path:
    try:
        import gymnasium
    except ImportError as err:
        raise RuntimeError("the contact task reads half_cheetah.xml from Gymnasium: pip install gymnasium") from err
    return Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets" / "half_cheetah.xml"


class HalfCheetahContact(MjxEnv):
    """Gymnasium HalfCheetah-v5's defaults: frame_skip 5, forward_reward_weight 1, ctrl_cost_weight
    0.1, reset noise U(-0.1, 0.1) on qpos and 0.1 N(0, 1) on qvel, observation qpos[1:] + qvel."""

    observation_size = 17
    n_substeps = 5
    forward_reward_weight = 1.0
    ctrl_cost_weight = 0.1
    reset_noise_scale = 0.1

    def __init__(self):
        super().__init__(xml=half_cheetah_xml())

    def initial_qpos_qvel(self, key):
        qpos_key, qvel_key = jax.random.split(key)
        scale = self.reset_noise_scale
        qpos = self._initial_data.qpos + jax.random.uniform(qpos_key, (self.mj_model.nq,), minval=-scale, maxval=scale)
        qvel = scale * jax.random.normal(qvel_key, (self.mj_model.nv,))
        return qpos, qvel

    def observation(self, data):
        return jnp.concatenate([data.qpos[1:], data.qvel])

    def reward(self, data, action, prev):
        x_velocity = (data.qpos[0] - prev.qpos[0]) / self.dt
        return self.forward_reward_weight * x_velocity - self.ctrl_cost_weight * jnp.sum(jnp.square(data.ctrl))

    def terminated(self, data):
        return jnp.zeros((), bool)


def contact_task_name() -> str:
    """`half-cheetah` where the suite has it, else this module's task (registered on first use)."""
    if "half-cheetah" in envs.names():
        return "half-cheetah"
    if NAME not in envs.names():
        envs.register(NAME, HalfCheetahContact, episode_length=1000)
    return NAME
