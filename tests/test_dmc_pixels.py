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
from tests.test_gym_interop import run_python
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


def test_a_judge_that_cannot_render_says_how_to_fix_it():
    """Where a process imported dm_control without rendering (`load`'s MUJOCO_GL=disable), a pixel
    judge's `load(..., renders=True)` is refused with the fix, not left to fail in OpenGL (in a fresh
    process: another test's import may have picked a renderer)."""
    result = run_python("""
        from envs.interop.dm_control import load
        load("cartpole", "swingup")
        try:
            load("cartpole", "swingup", renders=True)
        except RuntimeError as error:
            print(error)
    """, MUJOCO_GL=None)
    assert "cannot render: set MUJOCO_GL=egl before the process first imports dm_control" in result.stdout, \
        result.stderr


@pytest.mark.slow  # ~15 s in a fresh process: dm_control renders only where it was first imported with MUJOCO_GL=egl
def test_the_judge_shows_a_pixel_policy_dm_controls_own_pictures():
    """`returns_on_dm_control` of a pixel env hands the policy dm_control's own rendered frames of the
    env's camera and size, the last three oldest first (a reset's frame repeated), holds each action
    for the env's action repeat, and sums dm_control's rewards: checked against dm_control's env of
    the same seed stepped and rendered here by hand."""
    result = run_python("""
        import numpy as np
        import envs
        from envs.interop.dm_control import JUDGE_FIRST_SEED, load, returns_on_dm_control

        env = envs.make("dmc-cartpole-swingup", observation="pixels", width=32, height=24)
        actions = [np.array([a]) for a in (0.9, -0.6, 1.0, -1.0)]
        seen = []
        def policy(observation):
            seen.append(observation.copy())
            return actions[len(seen) - 1]
        [judged] = returns_on_dm_control(policy, env, episodes=1, max_steps=8)

        theirs = load("cartpole", "swingup", JUDGE_FIRST_SEED, renders=True)
        theirs.reset()
        frames, total = [theirs.physics.render(24, 32, camera_id=0)], 0.0
        for action in actions:
            for _ in range(env.action_repeat):
                total += theirs.step(action).reward
            frames.append(theirs.physics.render(24, 32, camera_id=0))
        assert len(seen) == 4 and seen[0].dtype == np.uint8 and seen[0].shape == (24, 32, 9)
        stacks = [np.concatenate(f, -1) for f in ([frames[0]] * 3, [frames[0], frames[0], frames[1]],
                                                   frames[0:3], frames[1:4])]
        for i, (got, want) in enumerate(zip(seen, stacks)):
            assert (got == want).all(), i
        assert (frames[3] != frames[0]).any()  # the cart moved: the frames tell the steps apart
        assert judged == total, (judged, total)
        print("judged")
    """, MUJOCO_GL="egl")
    if "EGL" in result.stderr and "judged" not in result.stdout:
        pytest.skip("no EGL on this machine: " + result.stderr.strip().splitlines()[-1])
    assert result.returncode == 0, result.stderr
    assert "judged" in result.stdout


@pytest.mark.slow
@pytest.mark.parametrize("task_name", ["dmc-cheetah-run", "half-cheetah"])
def test_the_renderer_reads_the_positions_that_a_full_forward_derives(task_name):
    """MuJoCo Warp's renderer reads `compute_positions`: a dm_control task's state as its step leaves
    it (the legacy step's refresh), another task's through `mjx.forward` without the constraint stage.
    After steps that move the model (cheetah's tracking camera), both equal the frames of bodies,
    geoms and cameras that a full `mjx.forward` derives (MJX-JAX keeps no lights' frames; MuJoCo Warp
    derives them in the same stage as the cameras'); Gymnasium's step leaves them stale."""
    task = envs.make(task_name).unwrapped

    @jax.jit
    def steps(key):
        def body(state, key):
            return task.step(state, jax.random.uniform(key, (task.action_size,), minval=-1, maxval=1)), None
        return jax.lax.scan(body, task.reset(key), jax.random.split(key, 20))[0].pipeline_state

    data = steps(jax.random.PRNGKey(4))
    positions, derived = task.compute_positions(data), task.compute_derived(data)
    assert task.positions_fresh_after_step == task_name.startswith("dmc-")
    for field in ("xpos", "xmat", "geom_xpos", "geom_xmat", "cam_xpos", "cam_xmat"):
        np.testing.assert_allclose(getattr(positions, field), getattr(derived, field), atol=1e-5, err_msg=field)
    assert task.positions_fresh_after_step or not np.allclose(data.geom_xpos, derived.geom_xpos, atol=1e-5)


@pytest.mark.slow  # a fresh process: dm_control renders only where it was first imported with MUJOCO_GL=egl
def test_the_picture_gap_shows_a_policy_both_renderers_pictures_of_dm_controls_state():
    """`benchmarks.pixel_gap` drives dm_control's env as the judge does (the same returns where the policy sees
    dm_control's pictures), and renders ours of dm_control's physics state each step: the pixels our picture
    hits are those C MuJoCo's `mj_ray` hits at that state; the policy's actions on the two stacks differ."""
    result = run_python("""
        import numpy as np
        import envs
        from benchmarks.pixel_gap import gap, our_pictures
        from envs.interop.dm_control import JUDGE_FIRST_SEED, load, returns_on_dm_control
        from tests.test_pixels import c_mujoco_depth

        env = envs.make("dmc-cartpole-swingup", observation="pixels", width=32, height=24)
        policy = lambda obs: np.asarray(obs, np.float32).mean(axis=(-3, -2, -1))[..., None] / 127.5 - 1.0
        ours = our_pictures(env)
        record = gap(policy, env, ours, episodes=1, max_steps=6)
        assert record["returns_seeing_theirs"] == returns_on_dm_control(policy, env, 1, max_steps=6)
        assert record["pictures"] == 2 * (1 + 6 // env.action_repeat)
        assert record["picture_abs_diff"] > 10 and record["action_abs_diff"] > 0
        alone = gap(policy, env, ours, episodes=1, max_steps=6, ours_only=True)
        assert alone["returns_seeing_ours"] == record["returns_seeing_ours"] and "picture_abs_diff" not in alone

        theirs = load("cartpole", "swingup", JUDGE_FIRST_SEED)
        theirs.reset()
        model, start = theirs.physics.model._model, theirs.physics.data.qpos.copy()
        for _ in range(40):
            theirs.step(np.array([1.0]))
        seen = ours(theirs.physics) > 0
        _, hits = c_mujoco_depth(model, theirs.physics.data.qpos, env.cam, 32, 24)
        _, hits_at_start = c_mujoco_depth(model, start, env.cam, 32, 24)
        assert seen.shape == (24, 32, 3) and (seen.max(-1) == (hits >= 0)).mean() > 0.99
        assert (seen.max(-1) != (hits_at_start >= 0)).sum() > 5  # the picture tells the two states apart
        print("gap", record)
    """, MUJOCO_GL="egl")
    if "EGL" in result.stderr and "gap" not in result.stdout:
        pytest.skip("no EGL on this machine: " + result.stderr.strip().splitlines()[-1])
    assert result.returncode == 0, result.stderr
    assert "gap" in result.stdout
