"""A Gymnasium-style task of a user's own, written with the public API only, proven against Gymnasium.

Gymnasium's HumanoidStandup-v5 (gymnasium/envs/mujoco/humanoidstandup_v5.py), which the suite does
not ship, written as a user would: a params dataclass of v5's constructor arguments and a subclass of
`envs.GymnasiumMujocoEnv` (docs/tasks.md, "A Gymnasium-style task"). `compare_with_gymnasium` then
gives the error of every step against Gymnasium's own env from the same states and actions.
"""

import dataclasses
import math

import gymnasium
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs.interop.gymnasium_equality import compare_with_gymnasium


# ---- the user's task ---------------------------------------------------------------------------
@dataclasses.dataclass(frozen=True)
class StandupParams:  # HumanoidStandup-v5's constructor arguments and defaults
    uph_cost_weight: float = 1.0  # taken by v5, unused by its reward (as there)
    ctrl_cost_weight: float = 0.1
    impact_cost_weight: float = 0.5e-6
    impact_cost_range: tuple[float, float] = (-math.inf, 10.0)
    reset_noise_scale: float = 1e-2
    exclude_current_positions_from_observation: bool = True
    include_cinert_in_observation: bool = True
    include_cvel_in_observation: bool = True
    include_qfrc_actuator_in_observation: bool = True
    include_cfrc_ext_in_observation: bool = True


class HumanoidStandup(envs.GymnasiumMujocoEnv):
    gymnasium_id = "HumanoidStandup-v5"
    xml_file = "humanoidstandup.xml"
    frame_skip = 5
    skipped_qpos = 2  # the torso's x and y
    reset_computes_derived = True  # the reset observation reads cinert and cvel
    reads_contact_forces = True  # the impact cost and the observation read cfrc_ext

    def __init__(self, params: StandupParams = StandupParams()):
        super().__init__(params)

    @property
    def needs_cfrc_ext(self) -> bool:  # the impact cost reads the forces even when not observed
        return self.params.include_cfrc_ext_in_observation or self.params.impact_cost_weight != 0

    @property
    def observation_size(self) -> int:
        p, bodies, nv = self.params, self.mj_model.nbody - 1, self.mj_model.nv
        return (super().observation_size + 10 * bodies * p.include_cinert_in_observation
                + 6 * bodies * p.include_cvel_in_observation + (nv - 6) * p.include_qfrc_actuator_in_observation
                + 6 * bodies * p.include_cfrc_ext_in_observation)

    def observation(self, data):
        p, parts = self.params, [super().observation(data)]
        if p.include_cinert_in_observation:
            parts.append(self.cinert(data)[1:].ravel())
        if p.include_cvel_in_observation:
            parts.append(data.cvel[1:].ravel())
        if p.include_qfrc_actuator_in_observation:
            parts.append(data.qfrc_actuator[6:])
        if p.include_cfrc_ext_in_observation:
            parts.append(self.cfrc_ext(data)[1:].ravel())
        return jnp.concatenate(parts)

    def terminated(self, data):
        return jnp.zeros((), bool)  # HumanoidStandup never terminates

    def reward(self, data, action, prev):
        p = self.params
        uph = data.qpos[2] / self.mj_model.opt.timestep
        ctrl_cost = self.control_cost(data)
        impact_cost = jnp.clip(p.impact_cost_weight * jnp.sum(jnp.square(self.cfrc_ext(data))), *p.impact_cost_range)
        terms = {"x_position": data.qpos[0], "y_position": data.qpos[1],
                 "z_distance_from_origin": data.qpos[2] - self.init_qpos[2],
                 "reward_linup": uph, "reward_quadctrl": -ctrl_cost, "reward_impact": -impact_cost}
        return uph - ctrl_cost - impact_cost + 1.0, terms


# ---- the proof -------------------------------------------------------------------------------------
def test_a_users_task_has_gymnasiums_spaces_and_hooks():
    task = HumanoidStandup()
    theirs = gymnasium.make("HumanoidStandup-v5")
    assert (task.observation_size,) == theirs.observation_space.shape
    assert task.action_size == theirs.action_space.shape[0]
    np.testing.assert_array_equal(task.action_low, theirs.action_space.low)
    # Its params have no contact_cost_weight: the base class's hooks ask only for the fields a task has.
    assert envs.GymnasiumMujocoEnv.needs_cfrc_ext.fget(task) is True
    bare = HumanoidStandup(StandupParams(include_cfrc_ext_in_observation=False))
    assert envs.GymnasiumMujocoEnv.needs_cfrc_ext.fget(bare) is False
    assert task.mj_model.opt.solver == mujoco.mjtSolver.mjSOL_NEWTON  # the MJCF's PGS, as for humanoid


@pytest.mark.heavy  # three compiles of inverted-pendulum's step; gymnasium_mujoco's tests use the same proof by default
def test_the_public_proof_reports_each_steps_error():
    """The helper on a cheap built-in task: an error per step, within test_inverted_pendulums'
    tolerances; a task that differs from Gymnasium's is caught."""
    same = compare_with_gymnasium("inverted-pendulum", "InvertedPendulum-v5", num_envs=16, num_steps=8, keep=64)
    errors = same.errors()
    assert set(errors) >= {"obs", "reward", "terminated"} and all(e.shape == (64,) for e in errors.values())
    same.assert_within({"obs": 1e-4, "reward": 1e-4})
    assert same.worst()["terminated"] == 0.0
    # A shorter frame skip than Gymnasium's: the proof sees it.
    skipped = envs.make("inverted-pendulum").unwrapped
    skipped.n_substeps = 1
    wrong = compare_with_gymnasium(skipped, "InvertedPendulum-v5", num_envs=16, num_steps=8, keep=64)
    assert wrong.worst()["obs"] > 1e-3
    with pytest.raises(AssertionError):
        wrong.assert_within({"obs": 1e-4, "reward": 1e-4})


# Float32 against float64 from the same state, Newton on both sides (humanoid's tolerances,
# tests/test_humanoid.py): everything but the contact forces within 1e-2, those within 1 N + 1%.
@pytest.mark.heavy  # compiles a humanoid's contact/RK4 step (minutes on 2 cores), as tests/test_humanoid.py's
def test_a_users_humanoid_standup_steps_as_gymnasiums():
    task = HumanoidStandup()
    report = compare_with_gymnasium(task, "HumanoidStandup-v5", num_envs=8, num_steps=20, keep=80,
                                    forward_first=True, opt={"solver": mujoco.mjtSolver.mjSOL_NEWTON})
    cfrc = slice(task.observation_size - 6 * (task.mj_model.nbody - 1), task.observation_size)
    ours, theirs = report.ours, report.theirs
    np.testing.assert_allclose(ours.obs[:, :cfrc.start], theirs.obs[:, :cfrc.start], atol=1e-2, rtol=1e-4)
    np.testing.assert_allclose(ours.obs[:, cfrc], theirs.obs[:, cfrc], atol=1.0, rtol=1e-2, err_msg="cfrc_ext")
    np.testing.assert_allclose(ours.reward, theirs.reward, atol=1e-2, rtol=1e-4, err_msg="reward")
    assert report.worst()["terminated"] == 0.0
