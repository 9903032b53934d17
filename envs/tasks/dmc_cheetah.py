"""The DeepMind Control Suite's cheetah run (dm_control/suite/cheetah.py), stepped by MJX:
`envs.make("dmc-cheetah-run")`. A planar cheetah (9 joints, 6 motors; Euler at 0.01 s, one physics
step per control step) runs forward. The MJCF is dm_control's `cheetah.xml`, read from the
installed package.

- Action: Box(-1, 1, (6,)): bthigh, bshin, bfoot, fthigh, fshin, ffoot.
- Observation (17), dm_control's order: position = qpos[1:] (rootx left out), velocity = qvel.
- Reward: tolerance(torso subtree linear velocity x, (10, inf), margin 10, value_at_margin 0,
  linear): the speed over 10 m/s, capped at 1.
- Reset: the limited joints (the six legs' hinges) uniform in their ranges, then 200 physics steps
  at zero control to let it settle, the clock back at 0 (dm_control's `initialize_episode`). As in
  dm_control, the first of those steps integrates the accelerations of `mj_resetData`'s state
  (qpos0 at rest, whose `mj_forward` ran before the joints were drawn) from the drawn joints.
  The settling steps' line search stops after 8 iterations (`SETTLE_LS_ITERATIONS`; MuJoCo's 50);
  under impl="warp", the settling steps after the first are MuJoCo Warp's, with MuJoCo's settings.
- Episode: 1,000 steps (10 s simulated), never terminated.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from envs.mjx_env import mjx, physics_steps
from envs.tasks.dm_control_suite import DmControlEnv, tolerance

RUN_SPEED = 10.0  # dm_control's _RUN_SPEED (m/s)
SETTLE_STEPS = 200  # physics steps at reset before the episode starts
# The settling steps' line search stops after this many iterations (MuJoCo's default: 50). MJX's JAX
# line search is a scan of `ls_iterations` bodies that, batched, all run even once it has converged,
# so the cap sets the reset's cost; the settled states stay as dm_control's (tests/test_dm_control.py).
SETTLE_LS_ITERATIONS = 8


class DmcCheetahRun(DmControlEnv):
    costly_reset = True
    domain, task = "cheetah", "run"
    observation_shapes = (("position", 8), ("velocity", 9))

    def initial_qpos_qvel(self, key):
        settled = self._settled(key)
        return settled.qpos, settled.qvel

    def draw_start(self, key):
        key, episode = self.draw_episode(key)
        settled = self._settled(key)
        return settled.qpos, settled.qvel, {**episode, "overflow": self._overflow(settled)}

    def _settled(self, key):
        """The settled state of drawn joints: dm_control's `initialize_episode`."""
        model, limited = self.mj_model, np.flatnonzero(self.mj_model.jnt_limited)
        low, high = model.jnt_range[limited].T
        drawn = jnp.asarray(model.qpos0).at[limited].set(jax.random.uniform(key, (len(limited),), minval=low,
                                                                                maxval=high))
        # dm_control's first settling step is mj_step2 on the forward pass of qpos0 at rest.
        model = self.settle_model  # MJX's JAX implementation under either impl (mjx.euler is JAX's alone)
        rest = mjx.forward(model, self.reset_data)
        first = mjx.euler(model, rest.replace(qpos=drawn.astype(rest.qpos.dtype)))
        return self._settle(first)

    def _settle(self, first):
        """The settling steps after the first, by the implementation that steps the env. Under
        impl="warp" they run on MuJoCo Warp's worlds, whose solver and line search stop where each
        world converged; MJX-JAX's batched line search runs every iteration (`SETTLE_LS_ITERATIONS`)."""
        settle = functools.partial(physics_steps, substeps=SETTLE_STEPS - 1)
        if self._warp is None:
            return settle(self.settle_model, first)
        worlds = self._warp.without_shared(self._initial_data)
        start = worlds.replace(qpos=first.qpos, qvel=first.qvel, qacc_warmstart=first.qacc_warmstart)
        return self._warp.run(settle, self.mjx_model, start)

    @property
    def settle_model(self):
        """The reset's model (`reset_model`) with its line search capped at `SETTLE_LS_ITERATIONS`."""
        ls_iterations = min(self.reset_model.opt.ls_iterations, SETTLE_LS_ITERATIONS)
        return self.reset_model.tree_replace({"opt.ls_iterations": ls_iterations})

    def observations(self, data):
        return {"position": data.qpos[1:], "velocity": data.qvel}

    def reward(self, data, action, prev):
        speed = self.sensor(data, "torso_subtreelinvel")[0]
        return tolerance(speed, (RUN_SPEED, float("inf")), margin=RUN_SPEED, value_at_margin=0, sigmoid="linear")
