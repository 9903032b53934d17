"""dm_control's legacy-step refresh (`DmControlEnv.refresh`): a task whose observation, reward and
termination read nothing of a state but what a step leaves new and the kinematics
(`reads_kinematics_only`, found by tracing them) gets the kinematics alone after its step. Which tasks
those are, that the tracing sees a read, and the observations and rewards of the short refresh
against those of the whole one."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import random_rollout

import envs

pytest.importorskip("dm_control", reason="the dmc-* tasks read dm_control's MJCF (pip install 'mjxsuite[dmc]')")

DM_CONTROL_TASKS = [name for name, *_ in envs.TASKS if name.startswith("dmc-")]
# The others read sensors (walker walk and run, the speed sensor; cheetah, finger, hopper, humanoid,
# manipulator, quadruped, swimmer) and get MJX's whole position and velocity stages.
KINEMATIC_TASKS = {"dmc-acrobot-swingup", "dmc-acrobot-swingup-sparse", "dmc-ball-in-cup-catch", "dmc-cartpole-balance",
                   "dmc-cartpole-balance-sparse", "dmc-cartpole-swingup", "dmc-cartpole-swingup-sparse",
                   "dmc-cartpole-three-poles", "dmc-cartpole-two-poles", "dmc-fish-swim", "dmc-fish-upright",
                   "dmc-lqr-lqr-2-1", "dmc-lqr-lqr-6-2", "dmc-pendulum-swingup", "dmc-point-mass-easy",
                   "dmc-point-mass-hard", "dmc-reacher-easy", "dmc-reacher-hard", "dmc-walker-stand"}


def test_the_tasks_that_read_only_the_kinematics():
    assert {name for name in DM_CONTROL_TASKS if envs.make(name).unwrapped.reads_kinematics_only} == KINEMATIC_TASKS


def test_the_check_sees_a_velocity_read():
    """The tracing sees a read: the pendulum's observation with a body's velocity (mj_fwdVelocity's)
    added reads `cvel`, and that task gets the whole refresh."""
    from envs.tasks.dmc_pendulum import DmcPendulumSwingUp

    class WithVelocity(DmcPendulumSwingUp):
        def observations(self, data):
            return {**super().observations(data), "velocity": data.qvel + data.cvel[1, 0]}

    with_velocity, pendulum = WithVelocity(), DmcPendulumSwingUp()
    assert "cvel" in with_velocity.fields_read() and not with_velocity.reads_kinematics_only
    assert "cvel" not in pendulum.fields_read() and pendulum.reads_kinematics_only


@pytest.mark.parametrize("name", ["dmc-pendulum-swingup", pytest.param("dmc-reacher-easy", marks=pytest.mark.slow),
                                  pytest.param("dmc-walker-stand", marks=pytest.mark.slow)])
def test_the_kinematics_refresh_gives_the_whole_refreshs_observations(name, monkeypatch):
    """30 steps of 4 envs: the observations and rewards after the kinematics alone are those after
    MJX's whole position and velocity stages (reacher: the episode's target; walker: 10 substeps)."""
    short = random_rollout(name)
    monkeypatch.setattr(type(envs.make(name).unwrapped), "reads_kinematics_only", False)
    whole = random_rollout(name)
    assert np.ptp(short[0], axis=(0, 1)).min() > 0  # every observation element moved
    np.testing.assert_allclose(short[0], whole[0], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(short[1], whole[1], rtol=1e-6, atol=1e-6)
