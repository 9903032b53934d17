"""Every (task, agent) pair of the recipes table (`agents/brax_defaults.py`) starts under
impl="warp": the agent builds with its recipe on the Warp env, and the training env's reset and
step trace through `WarpWorlds.run`, which steps the task's own model and refuses any other. Issue 65: Humanoid and Ant set their contact-force option on the model after
the Warp worlds had taken theirs, so `--impl warp` refused them.

This checks the check, not Warp: the CPU suite runs without MuJoCo Warp, so MJX's Warp pieces are
replaced here by its JAX ones under a model whose options have Warp's fields."""

import dataclasses

import jax
import numpy as np
import pytest
from conftest import USERS_CODEGEN, random_rollout

import envs
from agents import brax_defaults, registry
from envs import mjx_env, mjx_warp, wrap_for_training
from envs.mjx_env import mjx

# Tasks whose every env steps its own model (dm_control's manipulator insert: a colliding receptacle
# moved each episode; point_mass hard: tendon coefficients drawn each episode; lqr: joint stiffness
# drawn each episode): impl="jax" only, and they say so (`test_jax_only_tasks_refuse_warp`).
JAX_ONLY = ("dmc-manipulator-insert-ball", "dmc-point-mass-hard", "dmc-lqr-lqr-2-1", "dmc-lqr-lqr-6-2")
PAIRS = [(task, agent) for task, rows in brax_defaults.SETTINGS.items() if task in envs.names()
         and task not in JAX_ONLY for agent in rows]


@pytest.fixture
def warp_faked(monkeypatch):
    """`impl="warp"` on a CPU without MuJoCo Warp: MJX's JAX model with an option of Warp's
    fields (the ones our code sets), JAX's data, no buffers shared by the worlds, the physics run
    by JAX. `WarpWorlds.run`, with its check, is the real one."""
    from mujoco.mjx._src.types import OptionJAX

    class WarpShapedOption(OptionJAX):
        warn_overflow: int = 1
        run_rne_postconstraint: bool = False

    put_model = mjx.put_model

    def put_model_faked(mj_model, impl=None, **kwargs):
        model = put_model(mj_model, impl="jax" if impl == "warp" else impl, **kwargs)
        if impl != "warp":
            return model
        fields = {field.name: getattr(model.opt._impl, field.name) for field in dataclasses.fields(OptionJAX)}
        return model.replace(opt=model.opt.replace(_impl=WarpShapedOption(**fields)))

    def put_model_and_data_faked(mj_model, mjx_model, buffers):
        return mjx_model.tree_replace({"opt._impl.warn_overflow": 0}), mjx.make_data(mj_model, impl="jax")

    monkeypatch.setattr(mjx_env, "require_warp", lambda: None)
    monkeypatch.setattr(mjx, "put_model", put_model_faked)
    monkeypatch.setattr(mjx_env, "put_model_and_data", put_model_and_data_faked)
    monkeypatch.setattr(mjx_warp, "shared_buffers", lambda data: {})
    in_worlds = []

    def step_worlds_faked(self, physics, data):  # the task's physics sees every world at once, as under Warp
        in_worlds.append(True)
        try:
            return physics(self.mjx_model, data)
        finally:
            in_worlds.pop()

    monkeypatch.setattr(mjx_warp.WarpWorlds, "_step_worlds", step_worlds_faked)
    monkeypatch.setattr(mjx_warp.WarpWorlds, "overflow", staticmethod(lambda data: jax.numpy.zeros(())))
    # MJX refuses a Warp model in every function but its step and forward, which run only inside the
    # worlds (`WarpWorlds.run`): here each of them refuses the Warp-shaped model outside the worlds.
    # Inside them, MJX's Warp step and forward take the worlds' leading axis: here JAX's, vmapped over it.
    for name in [name for name in MJX_PHYSICS if hasattr(mjx, name)]:
        def refusing(model, *args, _real=getattr(mjx, name), _name=name, **kwargs):
            if not isinstance(model.opt._impl, WarpShapedOption):
                return _real(model, *args, **kwargs)
            if not in_worlds or _name not in ("step", "forward"):
                raise ValueError(f"{_name} requires JAX backend implementation (the Warp model outside WarpWorlds.run)")
            out = jax.vmap(lambda world: _real(model, world, **kwargs))(*args)
            # Warp's contact and constraint buffers keep their sizes whatever the model's flags (a refresh
            # without the constraint stage); JAX's follow the flags, so a leaf that changed size keeps its old.
            return jax.tree.map(lambda new, old: new if new.shape == old.shape else old, out, args[0])
        monkeypatch.setattr(mjx, name, refusing)


# MJX's functions of a model and its data (the ones that raise "requires JAX backend implementation").
MJX_PHYSICS = ("step", "forward", "euler", "rk4", "implicit", "kinematics", "collision", "com_pos", "com_vel",
               "camlight", "crb", "factor_m", "solve_m", "rne", "tendon", "transmission", "fwd_position",
               "fwd_velocity", "fwd_actuation", "fwd_acceleration", "sensor_pos", "sensor_vel", "sensor_acc",
               "make_constraint", "solve")


TASKS = sorted({task for task, _ in PAIRS})


@pytest.mark.parametrize("task", TASKS)
def test_the_warp_worlds_step_the_model_the_task_steps(warp_faked, task):
    """What `WarpWorlds.run` checks, for every task of the table: the model its worlds hold is the
    task's own, the task's own options (Humanoid's and Ant's contact forces) set on both."""
    env = envs.make(task, impl="warp").unwrapped
    assert env.impl == "warp" and env._warp.mjx_model is env.mjx_model


# Tracing a task's physics takes seconds to a minute on 2 cores: CI's slow run traces one task per
# hook (Ant's contact options, reacher's per-episode target, cheetah's physics at reset); the heavy
# run traces the rest (Humanoid's contact options and ball_in_cup's rejection test among them).
TRACED_IN_SLOW = ("ant", "dmc-reacher-easy", "dmc-cheetah-run")


@pytest.mark.parametrize("task", [pytest.param(task, marks=pytest.mark.slow if task in TRACED_IN_SLOW else pytest.mark.heavy)
                                  for task in TASKS])
def test_every_recipe_starts_under_warp(warp_faked, task):
    """Each agent the table offers for `task` builds on the Warp env with its recipe, and the env
    its training steps (`wrap_for_training`, as every agent wraps it) resets and steps."""
    env = envs.make(task, impl="warp")
    for agent in brax_defaults.SETTINGS[task]:
        registry.make(registry.config_class(agent)(**brax_defaults.settings(task, agent)), env)
    batch = wrap_for_training(env, 2)
    state = jax.eval_shape(batch.reset, jax.random.PRNGKey(0))
    jax.eval_shape(batch.step, state, jax.ShapeDtypeStruct((2, env.action_size), jax.numpy.float32))


def test_the_check_refuses_another_model(warp_faked):
    """The check both tests above rely on: per-env model values (`envs.randomize`) are refused."""
    env = envs.make("inverted-pendulum", impl="warp").unwrapped
    other = env.mjx_model.tree_replace({"opt.timestep": env.mjx_model.opt.timestep * 2})
    state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    action = jax.ShapeDtypeStruct((env.action_size,), jax.numpy.float32)
    with pytest.raises(ValueError, match="steps the task's own model"):
        jax.eval_shape(lambda s, a: env.step_with_model(s, a, other), state, action)


def test_mjx_refuses_the_warp_model_outside_the_worlds(warp_faked):
    """The fake refuses what MJX refuses under Warp: a reset's own physics on the task's Warp model
    (dm_control cheetah's settling steps ran `mjx.euler` on it) rather than on `reset_model`."""
    env = envs.make("dmc-cheetah-run", impl="warp").unwrapped
    with pytest.raises(ValueError, match="euler requires JAX backend implementation"):
        jax.eval_shape(lambda d: mjx.euler(env.mjx_model, d), env.reset_data)
    jax.eval_shape(lambda d: mjx.euler(env.reset_model, d), env.reset_data)


@pytest.mark.parametrize("task", JAX_ONLY)
def test_jax_only_tasks_refuse_warp(warp_faked, task):
    """A task that steps a model per env refuses impl="warp" when built, naming impl='jax'."""
    with pytest.raises(ValueError, match="use impl='jax'"):
        envs.make(task, impl="warp")


@pytest.mark.slow
def test_the_warp_renderer_draws_the_states_positions_and_its_episodes_target(warp_faked):
    """`WarpRenderer`'s own code on the CPU, MuJoCo Warp's tracer faked: each world it traces holds
    the positions of its state's qpos with the episode's target placed over them (reacher easy;
    derived after the target, the target would sit at the model's position), unbatched and under
    vmap; its contexts draw dm_control's skybox. The fake "renders" the target's and the fingertip's
    positions as the first two pixels."""
    env = envs.make("dmc-reacher-easy", impl="warp", observation="pixels", width=2, height=2, frame_stack=1,
                    action_repeat=1)
    task = env.unwrapped
    target, finger = task.mj_model.geom("target").id, task.mj_model.geom("finger").id

    contexts = []  # the options of each render context built

    class Context:
        def pytree(self):
            return None

    def render(model, data, handle):  # one world: (pixels, 3) colours, (pixels,) depths; 2x2 pixels
        rgb = jax.numpy.stack([data.geom_xpos[target], data.geom_xpos[finger], *data.geom_xpos[:2]])
        return rgb, rgb[:, 0], None

    env.renderer.mjx = type("FakeMjx", (), dict(
        create_render_context=staticmethod(lambda *args, **kwargs: contexts.append(kwargs) or Context()),
        refit_bvh=staticmethod(lambda model, data, handle: data), render=staticmethod(render),
        get_rgb=staticmethod(lambda handle, cam, rgb: rgb.reshape(rgb.shape[0], 2, 2, 3)),
        get_depth=staticmethod(lambda handle, cam, depth, scale: depth.reshape(depth.shape[0], 2, 2, 1) / scale)))
    states = jax.jit(jax.vmap(env.reset))(jax.random.split(jax.random.PRNGKey(0), 2))
    states = jax.jit(jax.vmap(env.step))(states, jax.numpy.array([[1.0, -1.0], [-0.5, 0.5]]))
    batched, _ = jax.jit(jax.vmap(env.render))(states.pipeline_state, states.info)
    one = jax.tree.map(lambda x: x[1], states)
    alone, _ = jax.jit(env.render)(one.pipeline_state, one.info)
    np.testing.assert_allclose(alone, batched[1], atol=1e-6)
    for i in range(2):
        data = jax.tree.map(lambda x: x[i], states.pipeline_state)
        moved = mjx.kinematics(task.reset_model, task.reset_data.replace(qpos=data.qpos))
        np.testing.assert_allclose(batched[i, 0, 0, :2], states.info["target"][i], atol=1e-6)
        np.testing.assert_allclose(batched[i, 0, 1], moved.geom_xpos[finger], atol=1e-5)
    # dm_control's pictures show its skybox; a task of our own keeps Warp's black background.
    assert contexts and all(options["render_skybox"] for options in contexts)
    assert not envs.make("cartpole-swingup-mjx").unwrapped.render_skybox


@pytest.mark.slow
def test_dm_controls_touch_readings_under_warp_are_the_last_substeps_as_under_jax(warp_faked):
    """dm_control's legacy step keeps the last substep's acceleration-stage readings (touch, force,
    accelerometer) while it refreshes the rest (`DmControlEnv.refresh`). Under impl="warp" that code
    sees every world at once; indexing the worlds' axis in place of the sensors' kept nothing, so the
    observation read the refreshed state's touch, and policies of finger, hopper, quadruped and
    manipulator trained under Warp saw other readings than dm_control's."""
    under_jax, under_warp = envs.make("dmc-finger-spin"), envs.make("dmc-finger-spin", impl="warp")
    # Sixty steps through contacts: the two programs agree to 1e-5 where both are compiled as users' are.
    steps = [jax.jit(env.step, compiler_options=USERS_CODEGEN) for env in (under_jax, under_warp)]
    resets = [jax.jit(env.reset, compiler_options=USERS_CODEGEN) for env in (under_jax, under_warp)]
    states = [reset(jax.random.PRNGKey(0)) for reset in resets]
    actions = np.random.default_rng(0).uniform(-1, 1, (60, under_jax.action_size)).astype(np.float32)
    touched = 0
    for action in actions:
        states = [step(state, action) for step, state in zip(steps, states)]
        np.testing.assert_allclose(states[1].obs, states[0].obs, rtol=1e-5, atol=1e-5)
        touched += bool(np.any(np.asarray(states[0].obs[-2:]) > 0))  # the last two: log1p of the touches
    assert touched  # the readings compared were not all zero


def test_the_kinematics_refresh_runs_on_every_world_and_a_filmed_task_refreshes_whole(warp_faked):
    """A task that reads only the kinematics (`reads_kinematics_only`: the pendulum, Euler) refreshes
    them under Warp with MJX-JAX's kinematics of every world on `reset_model` (the fake refuses the
    Warp model there, as MJX does): 2 envs, 20 steps, the observations and rewards of impl="jax"
    refreshing MJX's whole position and velocity stages. Filmed (observation="pixels"), the task
    refreshes the whole stages, as MuJoCo Warp's renderer reads the cameras and lights; `Pixels`
    refuses the unfilmed task."""
    from envs.pixels import Pixels

    warp_obs, warp_reward = random_rollout("dmc-pendulum-swingup", "warp", 20, 2)
    with pytest.MonkeyPatch.context() as patch:  # impl="jax" with MJX's whole position and velocity stages
        patch.setattr(envs.make("dmc-pendulum-swingup").unwrapped.__class__, "reads_kinematics_only", False)
        jax_obs, jax_reward = random_rollout("dmc-pendulum-swingup", "jax", 20, 2)
    np.testing.assert_allclose(warp_obs, jax_obs, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(warp_reward, jax_reward, rtol=1e-6, atol=1e-6)
    task = envs.make("dmc-pendulum-swingup", impl="warp").unwrapped
    filmed = envs.make("dmc-pendulum-swingup", impl="warp", observation="pixels", width=2, height=2).unwrapped
    assert task.reads_kinematics_only and not filmed.reads_kinematics_only
    assert envs.make("dmc-pendulum-swingup").unwrapped.filmed().reads_kinematics_only  # MJX's ray caster
    with pytest.raises(ValueError, match="task.filmed()"):
        Pixels(task)
