"""dm_control's legacy-step refresh (`DmControlEnv.refresh`): a task that declares it reads only qpos,
qvel, ctrl and the kinematics (`reads_kinematics_only`) gets the kinematics alone after its step. Every
task's declaration is checked against what its observation, reward and termination read, and the
observations and rewards of the short refresh against those of the whole one."""

from __future__ import annotations

import importlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import random_rollout

import envs

pytest.importorskip("dm_control", reason="the dmc-* tasks read dm_control's MJCF (pip install 'mjxsuite[dmc]')")

from envs.tasks.dm_control_suite import KINEMATICS, DmControlEnv  # noqa: E402

STATE = ("qpos", "qvel", "act", "ctrl", "time", "mocap_pos", "mocap_quat")  # a step leaves these new
DM_CONTROL_TASKS = [name for name, *_ in envs.TASKS if name.startswith("dmc-")]

def task_class(name: str) -> type[DmControlEnv]:
    module, _, cls = next(factory for task, factory, *_ in envs.TASKS if task == name).partition(":")
    return getattr(importlib.import_module(module), cls)


DECLARED = [name for name in DM_CONTROL_TASKS if task_class(name).reads_kinematics_only]


def fields_read(task: DmControlEnv) -> set[str]:
    """The fields of a state (`mjx.Data`, e.g. "qpos", "_impl.cinert") that the task's observation,
    reward and termination read after its episode's edits: the inputs its traced program uses."""
    info = jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(task.reset, jax.random.PRNGKey(0)).info)
    leaves, tree = jax.tree_util.tree_flatten_with_path(task._initial_data)
    action = jnp.zeros(task.action_size)

    def readings(*values):
        data = task.with_episode(jax.tree_util.tree_unflatten(tree, values), info)
        return task.observation(data), task._reward_and_terms(data, action, data)[0], task.terminated(data)

    jaxpr = jax.make_jaxpr(readings)(*(value for _, value in leaves)).jaxpr
    used = {id(var) for eqn in jaxpr.eqns for var in eqn.invars} | {id(var) for var in jaxpr.outvars}
    return {jax.tree_util.keystr(path)[1:] for (path, _), var in zip(leaves, jaxpr.invars) if id(var) in used}


@pytest.mark.parametrize("name", [name if name in DECLARED else pytest.param(name, marks=pytest.mark.slow)
                                  for name in DM_CONTROL_TASKS])
def test_a_task_reads_only_the_kinematics_where_it_says_so(name):
    """Declared: nothing but the state and the kinematics is read (else the short refresh would hand it
    the step's stale sensors). Not declared: something else is (else it pays for a refresh it never reads)."""
    task = envs.make(name).unwrapped
    beyond = sorted(field for field in fields_read(task) if field not in STATE + KINEMATICS)
    assert not beyond if task.reads_kinematics_only else beyond, f"{name} reads {beyond}"


def test_the_check_sees_a_velocity_read():
    """The check above can fail: the pendulum's observation with a body's velocity (mj_fwdVelocity's) added reads `cvel`."""
    from envs.tasks.dmc_pendulum import DmcPendulumSwingUp

    class WithVelocity(DmcPendulumSwingUp):
        def observations(self, data):
            return {**super().observations(data), "velocity": data.qvel + data.cvel[1, 0]}

    assert "cvel" in fields_read(WithVelocity())
    assert "cvel" not in fields_read(DmcPendulumSwingUp())


@pytest.mark.parametrize("name", ["dmc-pendulum-swingup", pytest.param("dmc-reacher-easy", marks=pytest.mark.slow),
                                  pytest.param("dmc-walker-stand", marks=pytest.mark.slow)])
def test_the_kinematics_refresh_gives_the_whole_refreshs_observations(name, monkeypatch):
    """30 steps of 4 envs: the observations and rewards after the kinematics alone are those after
    MJX's whole position and velocity stages (reacher: the episode's target; walker: 10 substeps)."""
    short = random_rollout(name)
    monkeypatch.setattr(task_class(name), "reads_kinematics_only", False)
    whole = random_rollout(name)
    assert np.ptp(short[0], axis=(0, 1)).min() > 0  # every observation element moved
    np.testing.assert_allclose(short[0], whole[0], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(short[1], whole[1], rtol=1e-6, atol=1e-6)
