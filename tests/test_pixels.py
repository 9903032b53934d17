"""Pixel observations (`envs.make(task, observation="pixels", ...)`, envs/pixels.py) on the CPU.

impl="jax" renders with MJX's JAX ray caster: tiny images and two envs keep the compiles short.
One batched rollout (compiled once for the module) feeds the checks of shapes, the frame stack
across steps and auto-reset, and `info["state_obs"]`; the depth image is checked against C
MuJoCo's `mj_ray` cast through the same pixels.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

import envs
from envs.pixels import DEFAULT_CAMERA, camera_rays

TASK = "cartpole-swingup-mjx"  # the depth test's and the option tests' task
ROLLOUT_TASK = "pendulum-mjx"  # the rollout's: a cheaper step to compile, and cylinders (cast by envs.pixels)
HEIGHT, WIDTH, STACK, CHANNELS = 6, 8, 3, 4  # rgb + depth
N_ENVS, N_STEPS, EPISODE = 2, 5, 3  # every env ends an episode (truncation) at step 3


@pytest.fixture(scope="module")
def env():
    return envs.make(ROLLOUT_TASK, observation="pixels", width=WIDTH, height=HEIGHT, depth=True, frame_stack=STACK,
                     episode_length=EPISODE)


@pytest.fixture(scope="module")
def rollout(env):
    # Every env reset by a select (no lax.switch of three branches, each rendering: a third of the compile).
    batch = envs.BatchedAutoReset(env, N_ENVS, reset_by_index=False)
    state = jax.jit(batch.reset)(jax.random.PRNGKey(0))
    actions = jax.random.uniform(jax.random.PRNGKey(1), (N_STEPS, N_ENVS, env.action_size), minval=-1, maxval=1)

    def body(state, action):
        state = batch.step(state, action)
        return state, state

    _, states = jax.jit(lambda s: jax.lax.scan(body, s, actions))(state)
    return state, states


def test_shapes_and_dtype(env, rollout):
    first, states = rollout
    assert env.observation_shape == (HEIGHT, WIDTH, CHANNELS * STACK)
    assert env.observation_size == HEIGHT * WIDTH * CHANNELS * STACK
    assert first.obs.shape == (N_ENVS, HEIGHT, WIDTH, CHANNELS * STACK) and first.obs.dtype == jnp.uint8
    assert states.obs.shape == (N_STEPS, N_ENVS, HEIGHT, WIDTH, CHANNELS * STACK)
    assert states.obs.dtype == jnp.uint8 and states.info["final_obs"].dtype == jnp.uint8
    assert states.info["state_obs"].shape == (N_STEPS, N_ENVS, env.state_observation_size)
    assert int(first.obs.max()) > 0  # the camera sees something


def test_frame_stack_order_and_auto_reset(rollout):
    first, states = rollout
    obs, final, done = np.asarray(states.obs), np.asarray(states.info["final_obs"]), np.asarray(states.done)
    assert done[EPISODE - 1].all() and not done[: EPISODE - 1].any()
    # A reset fills the stack with its first frame.
    start = np.asarray(first.obs)
    for k in range(STACK):
        np.testing.assert_array_equal(start[..., k * CHANNELS:(k + 1) * CHANNELS], start[..., -CHANNELS:])
    previous = start
    for t in range(N_STEPS):
        # The frame the step produced is the newest of the final stack; the older ones moved one place back.
        np.testing.assert_array_equal(final[t][..., :-CHANNELS], previous[..., CHANNELS:])
        for e in range(N_ENVS):
            if done[t, e]:  # the fresh episode's stack: its first frame everywhere
                for k in range(STACK):
                    np.testing.assert_array_equal(obs[t, e][..., k * CHANNELS:(k + 1) * CHANNELS],
                                                  obs[t, e][..., -CHANNELS:])
            else:
                np.testing.assert_array_equal(obs[t, e], final[t, e])
        previous = obs[t]


def test_state_observation_in_info(env, rollout):
    first, states = rollout
    task = env.unwrapped
    for t in (0, EPISODE - 1, N_STEPS - 1):
        data = jax.tree.map(lambda x: x[t], states.pipeline_state)
        expected = jax.vmap(task.observation)(data)
        np.testing.assert_allclose(states.info["state_obs"][t], expected, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(first.info["state_obs"], jax.vmap(task.observation)(first.pipeline_state),
                               rtol=1e-6, atol=1e-6)
    # The finished episode's state observation survives the auto-reset: the pendulum's (cos, sin, speed)
    # one semi-implicit Euler step on from the step before (angle += dt * new speed).
    final, done = np.asarray(states.info["final_state_obs"]), np.asarray(states.done)
    t = EPISODE - 1
    assert done[t].all() and task.n_substeps == 1
    np.testing.assert_array_equal(final[:t], np.asarray(states.info["state_obs"])[:t])
    before, after = np.asarray(states.info["state_obs"][t - 1]), final[t]
    turned = np.arctan2(after[:, 1], after[:, 0]) - np.arctan2(before[:, 1], before[:, 0])
    np.testing.assert_allclose(np.angle(np.exp(1j * (turned - env.dt * after[:, 2]))), 0, atol=1e-4)
    assert not np.allclose(final[t], np.asarray(states.info["state_obs"][t]))  # a fresh episode's


def test_newest_frame_is_the_render_of_the_state(env, rollout):
    _, states = rollout
    data = jax.tree.map(lambda x: x[1], states.pipeline_state)
    rgb, depth = jax.jit(jax.vmap(env.render))(data)
    expected = np.concatenate([np.asarray(rgb), np.clip(np.asarray(depth) / env.depth_range, 0, 1)[..., None]], -1)
    expected = np.round(expected * 255).astype(np.uint8)
    np.testing.assert_array_equal(np.asarray(states.obs[1])[..., -CHANNELS:], expected)


def warp_or_skip(impl: str) -> None:
    if impl == "warp":
        from envs.mjx_warp import WarpUnavailable, require_warp

        try:
            require_warp()
        except WarpUnavailable as err:
            pytest.skip(str(err))


# Poses to render per task: qpos vectors, or None for qpos0 and two poses near it
DEPTH_CASES = {
    "cartpole-swingup-mjx": [[0.0, 0.0], [0.8, 0.6], [-1.2, 2.5]],  # cart position, pole angle (0: down)
    "half-cheetah": None,
}


@pytest.mark.slow
@pytest.mark.parametrize("impl", ["jax", "warp"])
@pytest.mark.parametrize("task_name", ["cartpole-swingup-mjx", "half-cheetah"])  # a fixed camera, a tracking one
def test_depth_equals_c_mujoco_mj_ray(task_name, impl):
    """Planar depth (MuJoCo Warp's convention) against C MuJoCo's mj_ray through the same pixels,
    float64, wherever both hit; the two agree on which pixels hit anything (impl="warp": on a GPU)."""
    warp_or_skip(impl)
    height, width = 12, 16
    env = envs.make(task_name, observation="pixels", width=width, height=height, impl=impl)
    task = env.unwrapped
    model = task.mj_model
    poses = DEPTH_CASES[task_name]
    if poses is None:
        noise = np.random.default_rng(0).uniform(-0.3, 0.3, (2, model.nq))
        poses = np.concatenate([model.qpos0[None], model.qpos0 + noise])
    poses = np.asarray(poses, np.float32)

    def render(qpos):  # the renderer computes the positions of qpos itself
        data = task.reset(jax.random.PRNGKey(0)).pipeline_state
        return env.render(data.replace(qpos=qpos.astype(data.qpos.dtype)))[1]

    depth = np.asarray(jax.jit(jax.vmap(render))(jnp.asarray(poses)), np.float64)

    both = 0
    for pose, image in zip(poses, depth):
        expected, _ = c_mujoco_depth(model, pose, env.cam, width, height)
        hit, c_hit = image > 0, expected > 0
        np.testing.assert_array_equal(hit, c_hit)
        np.testing.assert_allclose(image[hit], expected[hit], atol=1e-4, rtol=0)
        both += hit.sum()
    assert both > 20  # the pictures are not empty


def c_mujoco_depth(model: mujoco.MjModel, qpos: np.ndarray, cam: int, width: int, height: int):
    """C MuJoCo's picture of `qpos` from camera `cam`: each pixel's planar depth by `mj_ray` (geom
    groups 0-2, 0 where nothing is hit) and the geom it hits (-1: none), both (height, width)."""
    data = mujoco.MjData(model)
    data.qpos[:] = qpos
    mujoco.mj_forward(model, data)
    rays = camera_rays(model, cam, width, height)
    origin, frame = data.cam_xpos[cam], data.cam_xmat[cam].reshape(3, 3)
    groups, geom = np.array([1, 1, 1, 0, 0, 0], np.uint8), np.zeros(1, np.int32)
    depth, hits = np.zeros((height, width)), np.full((height, width), -1)
    for row in range(height):
        for col in range(width):
            dist = mujoco.mj_ray(model, data, origin, frame @ rays[row, col], groups, 1, -1, geom)
            if dist >= 0:
                depth[row, col], hits[row, col] = dist * -rays[row, col, 2], geom[0]
    return depth, hits


@pytest.mark.parametrize("overrides, words", [
    ({"observation": "rgb"}, ["observation='rgb'", "'state', 'pixels'"]),
    ({"observation": "pixels", "width": 0}, ["width=0", "positive integer"]),
    ({"observation": "pixels", "frame_stack": 1.5}, ["frame_stack=1.5", "positive integer"]),
    ({"observation": "pixels", "height": 5000}, ["height=5000", "at most 4096"]),
    ({"observation": "pixels", "depth": "yes"}, ["depth='yes'", "true or false"]),
    ({"observation": "pixels", "shadows": 1}, ["shadows=1", "true or false"]),
    ({"shadows": True}, ["'shadows': True", "observation='state'"]),
    ({"width": 32}, ["'width': 32", "observation='state'", "observation=pixels"]),
    ({"observation": "pixels", "action_repeat": 0}, ["action_repeat=0", "positive integer"]),
    ({"action_repeat": 2}, ["'action_repeat': 2", "observation='state'"]),
    ({"observation": "pixels", "camera": "side"}, ["camera='side'", "'fixed'"]),
    ({"observation": "pixels", "camera": 3}, ["camera=3", "1 camera(s)"]),
])
def test_bad_options_say_which_and_how_to_fix(overrides, words):
    with pytest.raises(ValueError) as err:
        envs.make(TASK, **overrides)
    for word in words:
        assert word in str(err.value)


def test_action_repeat_keeps_the_tasks_seconds_unless_episode_length_is_given():
    """With `action_repeat=k` an episode defaults to the task's own length over k env steps (the
    same seconds of the task); a given `episode_length` counts env steps."""
    def length(**options):
        return envs.make("cartpole-balance-mjx", observation="pixels", width=4, height=3, **options).episode_length

    assert length() == 1000 and length(action_repeat=4) == 250 and length(action_repeat=3) == 333
    assert length(action_repeat=2, episode_length=100) == 100
    assert envs.make("cartpole-balance-mjx").episode_length == 1000


@pytest.mark.slow
def test_action_repeat_steps_the_task_k_times_and_sums_their_rewards():
    """An env step of `action_repeat=k` is k steps of the task with the same action: the state
    after the k-th (whose frame `Pixels.step` then renders, as without a repeat), the k rewards
    summed; the step that ends the episode (the pole falls) ends the repeat there. Checked on
    `Pixels.repeated_step`, without rendering (compiling the renderer is most of a pixel test),
    on the MJX CartPole, whose step compiles fastest of the tasks that end episodes."""
    def pixels(k):  # the Pixels wrapper, inside the time limit
        return envs.make("cartpole-mjx", observation="pixels", width=4, height=3, action_repeat=k).env

    task = pixels(1).env
    action = jnp.asarray(1)  # pushed right every step, the pole falls within a few steps
    start = jax.jit(task.reset)(jax.random.PRNGKey(0))
    state, trajectory, step = start, [], jax.jit(task.step)
    for _ in range(60):
        state = step(state, action)
        trajectory.append(state)
        if state.done:
            break
    assert trajectory[-1].done
    k = next(k for k in (2, 3, 4, 5) if len(trajectory) % k)  # so that it ends inside a repeat
    repeated, repeat = start, jax.jit(pixels(k).repeated_step)
    for j in range(-(-len(trajectory) // k)):
        repeated = repeat(repeated, action)
        window = trajectory[k * j:k * j + k]
        for a, b in zip(jax.tree.leaves(repeated.pipeline_state), jax.tree.leaves(window[-1].pipeline_state), strict=True):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(repeated.reward, sum(float(s.reward) for s in window), rtol=1e-6)
        assert bool(repeated.done) == bool(window[-1].done)
    assert repeated.done


def test_analytic_task_has_no_pixels():
    with pytest.raises(ValueError, match="unknown option"):
        envs.make("cartpole", observation="pixels")


def test_command_line_options():
    from agents.env_options import parse_option

    assert parse_option(TASK, "observation", "pixels") == "pixels"
    assert parse_option(TASK, "width", "32") == 32 and parse_option(TASK, "depth", "true") is True
    assert parse_option(TASK, "camera", "1") == 1 and parse_option(TASK, "camera", "track") == "track"
    assert parse_option(TASK, "frame_stack", "4") == 4


def test_every_mjx_task_has_a_camera():
    """The task's own default camera, else the MJCF's first, or the default camera added to a model without one."""
    for name in envs.names():
        if "randomize" not in envs.options(name):
            continue
        env = envs.make(name, observation="pixels", width=2, height=2)
        model = env.unwrapped.mj_model
        assert model.ncam >= 1 and 0 <= env.cam < model.ncam, name
        named = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, env.cam)
        default = envs.options(name)["camera"]  # a task's own default (the quadruped's DrQ-v2 camera 2), else the first
        assert named == DEFAULT_CAMERA or env.cam == (0 if default is None else default), name


def test_default_camera_keeps_the_model_options():
    """A model rebuilt with the default camera keeps what the task and `opt` set after loading
    (Gymnasium's tasks turn PGS into MJX's solver)."""
    state_model = envs.make("inverted-pendulum", opt={"iterations": 7}).unwrapped.mj_model
    model = envs.make("inverted-pendulum", opt={"iterations": 7}, observation="pixels").unwrapped.mj_model
    assert state_model.ncam == 0 and model.ncam == 1
    assert model.opt.solver == state_model.opt.solver and model.opt.iterations == 7
    assert model.opt.timestep == state_model.opt.timestep


def test_rerun_recording_logs_the_camera_frames(env, rollout, tmp_path):
    """A pixel task's rollout in Rerun: each step's newest frame as images (rgb, depth) beside the scene."""
    from rerun.chunk import RrdReader

    from envs import recording

    _, states = rollout
    data = recording.Rollout(obs=states.obs, action=jnp.zeros((N_STEPS, N_ENVS, env.action_size)),
                             reward=states.reward, done=states.done, episode_return=states.reward,
                             episode_length=jnp.ones((N_STEPS, N_ENVS), jnp.int32),
                             scene_qpos=states.pipeline_state.qpos[:, :1])
    path = tmp_path / "pixels.rrd"
    rec = recording.open_recording(path, blueprint=recording.rollout_blueprint(camera=True))
    try:
        recording.log_rollout(rec, env, data)
    finally:
        recording.close_recording(rec)
    images, entities = {}, set()
    for chunk in RrdReader(path).store().stream():
        entity = chunk.entity_path.lstrip("/")
        entities.add(entity)
        batch = chunk.to_record_batch()
        if not chunk.is_static and entity.startswith("env/0/camera/"):
            buffers = [column for column in batch.schema.names if column.endswith("buffer")]
            images[entity] = np.stack([np.asarray(row[0], np.uint8) for row in batch.column(buffers[0]).to_pylist()])
    newest = np.asarray(states.obs[:, 0, ..., -CHANNELS:])
    np.testing.assert_array_equal(images["env/0/camera/rgb"], newest[..., :3].reshape(N_STEPS, -1))
    np.testing.assert_array_equal(images["env/0/camera/depth"], newest[..., 3].reshape(N_STEPS, -1))
    assert any(entity.startswith("world/env_0/") for entity in entities)  # the 3D scene beside them
    assert not any("/obs/" in entity for entity in entities)  # no plot per pixel


def test_a_batch_of_pixel_envs_resets_only_the_envs_that_ended(env, monkeypatch):
    """A reset renders, so on an accelerator too the batch resets the ended envs by index (not a
    fresh frame for every env on every step); a batch vmapped over seeds decides over every seed at once."""
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert envs.BatchedAutoReset(env, 4).reset_by_index
    assert envs.BatchedAutoReset(env, 4, under_vmap=True).reset_across_vmap
    assert not envs.BatchedAutoReset(envs.make(ROLLOUT_TASK), 4).reset_by_index


def test_shadows_reach_warps_render_context_and_the_cpus_ray_caster_draws_none(monkeypatch):
    """`shadows=True` asks MuJoCo Warp's ray tracer for shadow rays (dm_control's OpenGL draws shadows); off by
    default. The render context is built by a stand-in here (MuJoCo Warp needs a GPU)."""
    from envs.pixels import WarpRenderer

    built = []
    task = envs.make("dmc-cheetah-run").unwrapped
    for shadows in (False, True):
        renderer = WarpRenderer(task, 0, 8, 8, False, **({"shadows": True} if shadows else {}))
        monkeypatch.setattr(renderer.mjx, "create_render_context", lambda *args, **kw: built.append(kw), raising=False)
        renderer.context(4)
    assert [kw["use_shadows"] for kw in built] == [False, True] and all(kw["use_textures"] for kw in built)
    shaded = envs.make("dmc-cheetah-run", observation="pixels", width=8, height=8, shadows=True)
    assert not shaded.warp_renders  # on the CPU: the JAX ray caster, which draws no lights


def test_programs_that_render_with_warp_keep_xlas_default_cuda_graphs():
    """Warp's renderer fails inside the WHILE/CONDITIONAL CUDA graphs the training programs use on a GPU."""
    from agents.device_options import training_compiler_options

    class RendersWithWarp:
        warp_renders = True

    assert training_compiler_options("gpu", env=RendersWithWarp()) == {}
    assert "xla_gpu_enable_command_buffer" in training_compiler_options("gpu", env=envs.make(ROLLOUT_TASK))
    assert not envs.make(ROLLOUT_TASK, observation="pixels", width=2, height=2).warp_renders
