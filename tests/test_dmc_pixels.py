"""The DeepMind Control Suite's tasks observed through a camera (`envs.make("dmc-...",
observation="pixels")`): DrQ-v2's protocol by default, and each episode's model edits drawn.

impl="jax" renders with MJX's JAX ray caster on the CPU; depth is checked against C MuJoCo's
`mj_ray` through the same pixels, with dm_control's per-episode edit made in C MuJoCo's model.
"""

import jax
import numpy as np
import pytest

import envs
from agents.env_options import parse_option
from tests.test_pixels import c_mujoco_depth

pytest.importorskip("dm_control")


def test_pixels_default_to_drqv2s_protocol():
    """84x84 RGB from camera 0, three frames stacked, action repeat 2 (500 env steps an episode);
    each option given wins, and the state observation keeps dm_control's 1,000 steps."""
    env = envs.make("dmc-cheetah-run", observation="pixels")
    assert env.observation_shape == (84, 84, 9) and env.cam == 0
    assert env.action_repeat == 2 and env.episode_length == 500
    assert envs.options("dmc-cheetah-run")["width"] == 84
    assert parse_option("dmc-cheetah-run", "camera", "back") == "back" and parse_option("dmc-cheetah-run", "camera", "1") == 1

    given = envs.make("dmc-cheetah-run", observation="pixels", width=32, height=24, frame_stack=1,
                      action_repeat=1, camera="back")
    assert given.observation_shape == (24, 32, 3) and given.episode_length == 1000
    assert given.cam == given.unwrapped.mj_model.camera("back").id
    assert envs.make("dmc-cheetah-run").episode_length == 1000  # the state observation
    assert envs.make("dmc-quadruped-walk", observation="pixels", width=8, height=8).cam == 2  # DrQ-v2's camera
    with pytest.raises(ValueError, match="observation='state'"):
        envs.make("dmc-cheetah-run", width=32)


@pytest.mark.slow
def test_reachers_target_is_drawn_where_its_episode_puts_it():
    """Reacher's target moves every episode (a `geom_pos` edit, as dm_control's): the camera draws
    it there. Depth from camera 0 equals C MuJoCo's mj_ray with the same edit, for three episodes,
    and the image differs from one drawn with the task's unedited model."""
    height, width = 12, 12
    env = envs.make("dmc-reacher-easy", observation="pixels", width=width, height=height)
    task = env.unwrapped
    model = task.mj_model
    target = model.geom("target").id

    @jax.jit
    def draw(key):
        state = task.reset(key)
        return state.info["target"], state.pipeline_state.qpos, env.render(state.pipeline_state, state.info)[1], \
            env.render(state.pipeline_state)[1]

    targets, poses, depths, unedited = jax.vmap(draw)(jax.random.split(jax.random.PRNGKey(3), 3))
    target_pixels = 0
    for goal, qpos, depth, plain in zip(np.asarray(targets), np.asarray(poses), np.asarray(depths, np.float64),
                                        np.asarray(unedited)):
        c_model = model.__copy__()
        c_model.geom_pos[target, :2] = goal
        expected, hits = c_mujoco_depth(c_model, qpos, env.cam, width, height)
        target_pixels += int((hits == target).sum())
        np.testing.assert_array_equal(depth > 0, expected > 0)
        np.testing.assert_allclose(depth[depth > 0], expected[depth > 0], atol=1e-4, rtol=0)
        assert not np.allclose(plain, depth)  # the unedited model draws the target elsewhere
    assert target_pixels > 0
