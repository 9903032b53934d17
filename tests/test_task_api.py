"""The task API (envs.MjxEnv): a user's task built from an XML and a short class,
and the errors a wrong task gets, each naming the task and the problem."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs

SLIDER_XML = """
<mujoco model="slider">
  <option timestep="0.05"><flag contact="disable"/></option>
  <default><geom contype="0" conaffinity="0"/></default>
  <worldbody>
    <body name="block">
      <joint name="slide" type="slide" axis="1 0 0"/>
      <geom name="block" type="box" size="0.1 0.1 0.1" mass="1"/>
    </body>
  </worldbody>
  <actuator><motor name="push" joint="slide" gear="2" ctrlrange="-0.5 1"/></actuator>
</mujoco>
"""


@pytest.fixture
def slider_xml(tmp_path):
    path = tmp_path / "slider.xml"
    path.write_text(SLIDER_XML)
    return path


class Slider(envs.MjxEnv):
    observation_size = 2

    def initial_qpos_qvel(self, key):
        return jnp.zeros(1), jnp.zeros(1)

    def observation(self, data):
        return jnp.concatenate([data.qpos, data.qvel])

    def reward(self, data, action, prev):
        return data.qpos[0] - prev.qpos[0]  # distance covered by this step

    def terminated(self, data):
        return data.qpos[0] > 1.0


class DiscreteSlider(Slider):
    action_bins = {"back": (-0.5,), "stop": (0.0,), "forward": (1.0,)}


def test_discrete_bins_map_to_ctrl_in_order(slider_xml):
    env = DiscreteSlider(slider_xml)
    assert env.num_actions == 3 and env.action_size is None
    state = env.reset(jax.random.PRNGKey(0))
    for action, ctrl in enumerate((-0.5, 0.0, 1.0)):
        assert float(jax.jit(env.step)(state, jnp.int32(action)).pipeline_state.ctrl[0]) == ctrl


def test_continuous_actions_scale_to_ctrlrange(slider_xml):
    env = Slider(slider_xml)
    assert env.num_actions is None and env.action_size == 1
    state = env.reset(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    ctrls = [float(step(state, jnp.array([a], jnp.float32)).pipeline_state.ctrl[0]) for a in (-1.0, 0.0, 1.0, 3.0)]
    np.testing.assert_allclose(ctrls, [-0.5, 0.25, 1.0, 1.0])  # [-1, 1] -> ctrlrange, clipped


def test_reward_sees_the_transition(slider_xml):
    env = DiscreteSlider(slider_xml)
    state = env.reset(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    for _ in range(3):
        before = float(state.pipeline_state.qpos[0])
        state = step(state, jnp.int32(2))
        assert float(state.reward) == pytest.approx(float(state.pipeline_state.qpos[0]) - before)


def test_int_action_bins_are_evenly_spaced_over_ctrlrange(slider_xml):
    env = Slider(slider_xml, action_bins=4)
    assert env.num_actions == 4
    np.testing.assert_allclose(np.asarray(env._bin_table[:, 0]), [-0.5, 0.0, 0.5, 1.0])


def test_bin_outside_ctrlrange_names_task_bin_and_actuator(slider_xml):
    with pytest.raises(ValueError, match=r"task Slider: action bin 'fast' sets actuator 'push' to 2.0, outside its ctrlrange"):
        Slider(slider_xml, action_bins={"stop": (0.0,), "fast": (2.0,)})
    with pytest.raises(ValueError, match=r"task Slider: action bin 'stop' has 2 ctrl values.*1 actuator"):
        Slider(slider_xml, action_bins={"stop": (0.0, 0.0)})


def test_xml_that_does_not_parse_names_the_task_and_file(tmp_path):
    bad = tmp_path / "broken.xml"
    bad.write_text("<mujoco><worldbody><body></worldbody></mujoco>")
    with pytest.raises(ValueError, match=r"task Slider: MuJoCo could not load .*broken\.xml"):
        Slider(bad)


def test_colliding_geoms_mjx_cannot_handle_get_a_hint(tmp_path):
    xml = tmp_path / "collide.xml"
    xml.write_text(SLIDER_XML.replace('<default><geom contype="0" conaffinity="0"/></default>', "").replace(
        '<worldbody>', '<worldbody><geom type="box" size="1 1 0.1"/>'
    ).replace('type="box" size="0.1 0.1 0.1"', 'type="cylinder" size="0.1 0.1"'))
    with pytest.raises(NotImplementedError, match=r"task Slider: MJX .*cannot run this model.*contype"):
        Slider(xml)


def test_observation_shape_changing_between_reset_and_step_is_caught(slider_xml):
    class Growing(Slider):
        def observation(self, data):  # 2 values at reset (time 0), 3 after
            return jnp.concatenate([data.qpos, data.qvel, data.qpos]) if self.stepping else super().observation(data)

        def step(self, state, action):
            self.stepping = True
            return super().step(state, action)

        stepping = False

    env = Growing(slider_xml)
    state = env.reset(jax.random.PRNGKey(0))
    with pytest.raises(ValueError, match=r"task Growing: observation\(\) returned shape \(3,\) after a step but \(2,\) at reset"):
        jax.jit(env.step)(state, jnp.zeros(1))


def test_observation_size_must_match_the_observation(slider_xml):
    class Misdeclared(Slider):
        observation_size = 3

    with pytest.raises(ValueError, match=r"task Misdeclared: observation\(\) returned shape \(2,\) at reset, but observation_size is 3"):
        Misdeclared(slider_xml).reset(jax.random.PRNGKey(0))


def test_non_scalar_reward_is_caught(slider_xml):
    class VectorReward(Slider):
        def reward(self, data, action, prev):
            return data.qpos

    env = VectorReward(slider_xml)
    with pytest.raises(ValueError, match=r"task VectorReward: reward\(\) must return a scalar"):
        jax.jit(env.step)(env.reset(jax.random.PRNGKey(0)), jnp.zeros(1))


def test_a_hook_under_its_former_name_is_refused_by_name():
    """`forward_on_reset` and `forward_at_reset` were renamed: a task setting them would skip its
    reset's derived quantities without a word, so defining the class fails and names the new hook."""
    with pytest.raises(TypeError, match="task Old: `forward_on_reset` is now `reset_computes_derived`"):
        class Old(envs.MjxEnv):
            forward_on_reset = True


def test_duplicate_registration_names_the_env(slider_xml):
    envs.register("test-slider", lambda: Slider(slider_xml), episode_length=10)
    with pytest.raises(ValueError, match=r"an env named 'test-slider' is already registered"):
        envs.register("test-slider", lambda: Slider(slider_xml))
    env = envs.make("test-slider")
    states = jax.vmap(env.reset)(jax.random.split(jax.random.PRNGKey(0), 4))
    states = jax.jit(jax.vmap(env.step))(states, jnp.ones((4, 1)))
    assert states.obs.shape == (4, 2)
