"""PPO from camera images (`envs.make(task, observation="pixels")`, `agents.ppo.make_vision_networks`)
and the cart-pole balance task it is sized for, on the CPU.

Tiny images (8x8), one small convolution, four envs. What costs time is compiling the cart-pole's
step with its ray-cast camera, so the default run traces the training chunk and compiles only
the networks; the slow test trains, saves and acts.
"""

import dataclasses
import math
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from agents import brax_defaults
from agents.commands import UsageError
from agents.device_options import default_seed_axis
from agents.commands import agent_config as _agent_config
from agents.commands import choose_agent as _choose_agent
from agents.ppo import PPO, PPOConfig, image_shape
from agents.run import load_policy, train_run

TASK = "cartpole-balance-mjx"
SIZE = 8
PIXELS = dict(observation="pixels", width=SIZE, height=SIZE)
# One 3x3 convolution of stride 2 (8x8 -> 3x3x4) and tiny MLPs: a chunk of 64 env steps.
TINY = PPOConfig(num_timesteps=64, num_envs=4, unroll_length=4, batch_size=4, num_minibatches=4,
                 num_updates_per_batch=1, num_evals=2, num_eval_envs=2, policy_hidden=(8,), value_hidden=(8,),
                 cnn_output_channels=(4,), cnn_kernel_size=(3,), cnn_stride=(2,))


def test_balance_starts_upright():
    """dm_control's balance start: cart within 0.1 m of the centre, pole within 0.034 rad of upright,
    slow; the reset observation (x, cos, sin, x_dot, theta_dot) says so."""
    env = envs.make(TASK)
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 256))
    qpos, obs = np.asarray(states.pipeline_state.qpos), np.asarray(states.obs)
    assert np.abs(qpos[:, 0]).max() <= 0.1 and np.abs(qpos[:, 1]).max() <= 0.034
    assert np.abs(qpos[:, 0]).max() > 0.05 and np.abs(qpos[:, 1]).max() > 0.02  # spread over the ranges
    assert obs[:, 1].min() >= math.cos(0.034) and np.abs(obs[:, 3:]).max() < 0.1
    np.testing.assert_allclose(obs[:, 2], np.sin(qpos[:, 1]), atol=1e-6)
    assert envs.options(TASK)["episode_length"] == 1000
    swing_up = jax.jit(envs.make("cartpole-swingup-mjx").reset)(jax.random.PRNGKey(0))
    assert swing_up.obs[1] < -0.99  # the swing-up's pole still starts hanging down


def test_vision_networks_act_on_uint8_frames():
    """Policy and value each get their own convolution in front of their MLP; frames go in as
    uint8 and come out as actions in [-1, 1]; no normalizer statistics for images."""
    env = envs.make(TASK, **PIXELS)
    assert image_shape(env) == (SIZE, SIZE, 3) and image_shape(envs.make(TASK)) is None
    ppo = PPO(TINY, env)
    normalizer, policy, value = ppo.init_params(*jax.random.split(jax.random.PRNGKey(0)))
    assert normalizer.mean.shape == (0,)
    for params, out in ((policy, 2 * env.action_size), (value, 1)):
        conv = params["params"]["CNN_0"]["Conv_0"]["kernel"]
        assert conv.shape == (3, 3, 3, 4)
        assert jax.tree.leaves(params["params"]["MLP_0"])[-1].shape[-1] == out  # last layer's kernel
    frames = jax.random.randint(jax.random.PRNGKey(1), (5, SIZE, SIZE, 3), 0, 256).astype(jnp.uint8)
    actions = jax.jit(ppo.policy)((normalizer, policy, value), frames)
    assert actions.shape == (5, 1) and np.all(np.abs(np.asarray(actions)) <= 1)
    # Scaled inside the network: the uint8 frames and their float [0, 1] copies act alike.
    scaled = ppo.networks.policy_network.apply(normalizer, policy, frames)
    assert np.isfinite(np.asarray(scaled)).all()


def test_on_the_cpu_the_vision_networks_gradients_in_a_loop_are_canonical_convolutions():
    """XLA:CPU canonicalizes only a program's top-level convolutions, and runs the others on its slow generic path:
    in a loop, JAX's own gradients of Brax's convolutions stay there. PPO on the CPU applies its networks through
    `agents.networks.canonical_convs` (`agents.device_options.canonical_conv_gradients`): the same gradients, every
    convolution canonical; for a GPU it keeps JAX's own."""
    config = dataclasses.replace(TINY, cnn_output_channels=(4, 4), cnn_kernel_size=(3, 3), cnn_stride=(2, 1))
    env = envs.make(TASK, observation="pixels", width=12, height=12)
    frames = jax.random.randint(jax.random.PRNGKey(0), (4, 12, 12, 3), 0, 256).astype(jnp.uint8)
    grads, forms = [], []
    for platform in ("cpu", "gpu"):
        value = PPO(config, env, platform=platform).networks.value_network
        params = value.init(jax.random.PRNGKey(1))
        grad = jax.grad(lambda p, value=value: jnp.square(value.apply(None, p, frames)).sum())
        grads.append(jax.tree.leaves(grad(params)))
        loop = jax.jit(lambda p, grad=grad: jax.lax.scan(lambda p, _: (grad(p), None), p, None, length=2)[0])
        forms.append(set(re.findall(r"convolution\(.*dim_labels=([\w>-]+)", loop.lower(params).compile().as_text())))
    for a, b in zip(*grads, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)
    assert forms[0] == {"b01f_01io->b01f"} and len(forms[1]) > 1, forms


def test_config_checks_name_the_fields():
    with pytest.raises(ValueError, match="cnn_output_channels, cnn_kernel_size, cnn_stride"):
        PPOConfig(cnn_kernel_size=(8, 4))
    with pytest.raises(ValueError, match="cnn_stride"):
        PPOConfig(cnn_stride=(4, 0, 1))
    with pytest.raises(ValueError, match=r"does not fit the 1x1 map that 8x8 images leave it .*--env-opt width=64"):
        PPO(PPOConfig(), envs.make(TASK, **PIXELS))  # the Nature CNN's 8x8 kernel then 4x4 on 8x8 images


def test_pixels_take_the_pixel_recipe_and_ppo():
    """Without --preset, camera images take the task's "pixels" recipe (the base one at 256 envs);
    DQN and SAC, which have no image networks, are refused with the fix."""
    for task in (TASK, "cartpole-swingup-mjx"):
        assert brax_defaults.default_preset(task, "ppo", "pixels") == "pixels"
        assert brax_defaults.default_preset(task, "ppo") == "default"
    config = _agent_config(TASK, "ppo", None, {}, None, None, observation="pixels")
    assert (config.num_envs, config.batch_size, config.cnn_kernel_size) == (256, 256, (8, 4, 3))
    assert _agent_config(TASK, "ppo", None, {}, None, None) == PPOConfig()  # state: the base recipe
    assert _choose_agent(TASK, None, PIXELS) == "ppo"
    with pytest.raises(UsageError, match="--agent sac has no network for camera images"):
        _choose_agent(TASK, "sac", PIXELS)


def test_dm_control_tasks_from_pixels_take_the_pixel_recipe_with_drqv2s_goal():
    """A dmc-* task on camera images trains PPO's pixel recipe, with DrQ-v2's score as its goal where
    issue 66 names one; from its state it keeps Playground's recipe and the state goal."""
    config = _agent_config("dmc-cartpole-swingup", "ppo", None, {}, None, None, observation="pixels")
    assert (config.num_envs, config.batch_size, config.solve_return) == (256, 256, 863.0)
    assert _agent_config("dmc-cartpole-swingup", "ppo", None, {}, None, None).num_envs == 2048
    assert _agent_config("dmc-finger-spin", "ppo", None, {}, None, None, observation="pixels").solve_return is None
    assert set(brax_defaults.DRQV2_SCORES) <= {name for name, *_ in envs.TASKS}
    # Without --agent, a dm_control task trains TD3's pixel recipe from camera images; other tasks PPO's.
    assert _choose_agent("dmc-cartpole-swingup", None, {}) == "td3"
    assert _choose_agent("dmc-cartpole-swingup", None, PIXELS) == "td3"
    assert _choose_agent(TASK, None, PIXELS) == "ppo"


def test_a_gpu_maps_the_seeds_of_image_networks_and_vmaps_the_others():
    """Vmapped over seeds' parameters, every convolution and its gradients become grouped ones, which a GPU
    runs slower than the seeds one after another (docs/bench-gpu.json, "pixel-ppo-speed")."""
    pixel_ppo, state_ppo = PPO(TINY, envs.make(TASK, **PIXELS)), PPO(TINY, envs.make(TASK))
    assert default_seed_axis("gpu", pixel_ppo) == "map"
    assert default_seed_axis("gpu", state_ppo) == default_seed_axis("gpu") == "vmap"
    assert default_seed_axis("cpu", state_ppo) == "map"


def test_pixels_on_a_discrete_task_get_one_truthful_message_from_every_agent_and_the_api():
    """Cases 68/69: DQN said "use ppo" and PPO "use dqn"; through the Python API DQN failed inside
    JAX. Every way in now says no agent trains that combination, and what does, before any compile."""
    from agents import DQNConfig, PPOConfig, train_run

    message = r"cartpole-mjx with observation=pixels: no agent trains camera images with discrete actions"
    for agent in (None, "dqn", "ppo", "sac"):
        with pytest.raises(UsageError, match=message):
            _choose_agent("cartpole-mjx", agent, PIXELS)
    for config in (DQNConfig(), PPOConfig()):
        with pytest.raises(ValueError, match=message + r".*--agent dqn \(drop observation=pixels\)"):
            train_run("cartpole-mjx", config, env_options=PIXELS, progress=False)


def test_pixel_runs_stack_frames_as_playground():
    """A pixel run of the cart-pole sees the last 3 frames, 4 task steps apart, by default: one
    frame has no velocities, and frames one 10 ms step apart barely differ (no run balanced from
    them). The episode keeps its 10 s; --env-opt frame_stack=N still wins; state runs get no
    pixel options."""
    import argparse

    from agents.commands import train_env_options as _train_env_options

    def options(*pairs):
        return _train_env_options(argparse.Namespace(env=TASK, env_opts=list(pairs), impl=None, randomize=[],
                                                     randomize_per=None))

    given = options("observation=pixels", f"width={SIZE}", f"height={SIZE}")
    assert given == dict(PIXELS, frame_stack=3, action_repeat=4)
    env = envs.make(TASK, **given)
    assert image_shape(env) == (SIZE, SIZE, 9) and env.episode_length == 1000 // 4
    assert options("observation=pixels", "frame_stack=1")["frame_stack"] == 1
    assert options() == {} and options("episode_length=200") == {"episode_length": 200}
    for task in brax_defaults.PIXEL_ENV_OPTIONS:
        assert brax_defaults.default_preset(task, "ppo", "pixels") == "pixels"


@pytest.mark.slow
def test_pixel_training_keeps_uint8_frames():
    """PPO's whole training chunk on 8x8 frames, traced (not compiled: the ray-cast camera's step
    takes most of a minute to compile on a CPU; the slow test below runs it): the rollouts hold
    uint8 frames, and the parameters and metrics come out as for state observations."""
    env = envs.make(TASK, **PIXELS, episode_length=20)
    ppo = PPO(TINY, env)
    ts = jax.eval_shape(ppo.init, jax.random.PRNGKey(0))
    assert ts.env_state.obs.dtype == jnp.uint8 and ts.env_state.obs.shape == (TINY.num_envs, SIZE, SIZE, 3)
    _, data = jax.eval_shape(ppo.collect, ts, jax.random.PRNGKey(1))
    assert data.observation.dtype == jnp.uint8 and data.next_observation.dtype == jnp.uint8
    assert data.observation.shape == (TINY.batch_size * TINY.num_minibatches, TINY.unroll_length, SIZE, SIZE, 3)
    trained, judged = jax.eval_shape(ppo.chunk, ts)
    assert jax.tree.map(lambda x: (x.shape, x.dtype), trained.params) == jax.tree.map(
        lambda x: (x.shape, x.dtype), ts.params)
    assert trained.env_state.obs.dtype == jnp.uint8 and judged["loss"].shape == ()
    assert judged["eval_episode"].obs.shape == (20, SIZE, SIZE, 3)  # the recorded episode's frames


@pytest.mark.heavy
def test_ppo_trains_from_pixels_and_the_saved_policy_acts(tmp_path):
    """A chunk from 8x8 frames on the CPU, saved, and `load_policy` acting on a uint8 frame as the
    env gives it (a float one is refused). The run stops after its first of two chunks: its
    checkpoint holds the policy, and the final evaluation (a program of its own to compile) is
    left out. Euler instead of the task's RK4 halves the compile of the cart-pole's step."""
    options = dict(PIXELS, opt={"integrator": "Euler"}, episode_length=20)
    config = dataclasses.replace(TINY, num_evals=3)
    result = train_run(TASK, config, out_dir=tmp_path, env_options=options, progress=False, checkpoint_seconds=0,
                       stop_after_chunks=1)
    [record] = result.history
    assert record["env_steps"] == [config.eval_every] and np.isfinite(record["loss"]).all()
    policy = load_policy(tmp_path)
    frame = np.asarray(jax.jit(envs.make(TASK, **options).reset)(jax.random.PRNGKey(2)).obs)
    assert frame.dtype == np.uint8 and frame.shape == (SIZE, SIZE, 3)
    action = policy(frame)
    assert action.shape == (1,) and action.dtype == np.float32 and abs(float(action[0])) <= 1.0
    assert policy(np.stack([frame, frame])).shape == (2, 1)
    with pytest.raises(ValueError, match="uint8 camera images of shape"):
        policy(frame.astype(np.float32) / 255)


def test_state_observations_keep_the_mlp_networks():
    """The state path builds Brax's `make_ppo_networks` as before: no convolution, a normalizer over the vector."""
    env = envs.make(TASK)
    normalizer, policy, _ = PPO(dataclasses.replace(TINY), env).init_params(*jax.random.split(jax.random.PRNGKey(0)))
    assert normalizer.mean.shape == (env.observation_size,) and "CNN_0" not in policy["params"]
