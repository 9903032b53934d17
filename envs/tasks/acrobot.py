"""Gymnasium's Acrobot-v1, written as its equations in JAX.

Two links hang from a fixed pivot; only the joint between them is driven, with a
torque of -1, 0 or +1. The dynamics are the "book" equations (Sutton & Barto;
Gymnasium's default `book_or_nips="book"`), advanced by one classic Runge-Kutta 4
step of dt = 0.2 s with the torque held constant. After the step the angles are
wrapped to [-pi, pi] and the velocities clipped, as `AcrobotEnv.step` does. The
constants, reset distribution, reward and termination rule are Gymnasium's; the
500-step truncation is added by the registry's time limit. Arithmetic runs in JAX's
default float type: float32, or float64 with `jax_enable_x64`.
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from envs.core import Env, State
from envs.ranges import FINITE, NON_NEGATIVE, POSITIVE, Range

# Action index -> torque in units of `torque_mag` (Gymnasium's AVAIL_TORQUE).
TORQUES = (-1.0, 0.0, 1.0)


@struct.dataclass
class AcrobotPhysics:
    """Physical constants. A pytree of floats, so it can be vmapped for domain randomisation."""

    gravity: float = 9.8
    link_length_1: float = 1.0  # pivot to elbow; the second link's length only enters the goal
    link_mass_1: float = 1.0
    link_mass_2: float = 1.0
    link_com_pos_1: float = 0.5  # distance from each link's joint to its centre of mass
    link_com_pos_2: float = 0.5
    link_moi: float = 1.0  # each link's moment of inertia about its centre of mass
    torque_mag: float = 1.0
    dt: float = 0.2  # seconds per step: one RK4 step

    # What `envs.make` accepts as overrides (a vmapped pytree of values is not checked).
    RANGES: ClassVar[dict[str, Range]] = {
        "gravity": FINITE, "link_length_1": POSITIVE, "link_mass_1": POSITIVE, "link_mass_2": POSITIVE,
        "link_com_pos_1": NON_NEGATIVE, "link_com_pos_2": NON_NEGATIVE, "link_moi": POSITIVE,
        "torque_mag": NON_NEGATIVE, "dt": POSITIVE}


@struct.dataclass
class AcrobotRules:
    """Reset, goal and velocity limits, shared by the analytic and the MJX Acrobot.

    The velocity clip is not physics (no MJCF can express it), so it lives here,
    where the MJX task can apply it after each `mjx.step` too.
    """

    reset_bound: float = 0.1  # reset state ~ U(-reset_bound, reset_bound)^4
    goal_height: float = 1.0  # the tip must rise this far above the pivot (links 1 m long)
    max_vel_1: float = 4 * math.pi
    max_vel_2: float = 9 * math.pi

    RANGES: ClassVar[dict[str, Range]] = {"reset_bound": NON_NEGATIVE, "goal_height": FINITE,
                                          "max_vel_1": POSITIVE, "max_vel_2": POSITIVE}

    def initial_state(self, key: jax.Array) -> jax.Array:
        """(theta1, theta2, dtheta1, dtheta2), drawn as Gymnasium draws them."""
        return jax.random.uniform(key, (4,), minval=-self.reset_bound, maxval=self.reset_bound)

    def clip_velocities(self, dtheta1: jax.Array, dtheta2: jax.Array) -> tuple[jax.Array, jax.Array]:
        return jnp.clip(dtheta1, -self.max_vel_1, self.max_vel_1), jnp.clip(dtheta2, -self.max_vel_2, self.max_vel_2)

    def is_terminated(self, theta1: jax.Array, theta2: jax.Array) -> jax.Array:
        """Gymnasium's `-cos(theta1) - cos(theta1 + theta2) > 1`: the tip is above the goal line."""
        return -jnp.cos(theta1) - jnp.cos(theta2 + theta1) > self.goal_height


def wrap_angle(x: jax.Array) -> jax.Array:
    """Gymnasium's `wrap(x, -pi, pi)`: add or subtract 2 pi as often as needed to land in [-pi, pi].

    Written as a count of whole turns rather than a modulo so that, like Gymnasium's
    loop, it leaves x = +-pi alone and subtracts exactly 2 pi once in the usual case.
    """
    two_pi = 2 * math.pi
    above = jnp.ceil((x - math.pi) / two_pi)  # turns to remove when x > pi
    below = jnp.ceil((-math.pi - x) / two_pi)  # turns to add when x < -pi
    return jnp.where(x > math.pi, x - above * two_pi, jnp.where(x < -math.pi, x + below * two_pi, x))


def derivatives(physics: AcrobotPhysics, state: jax.Array, torque: jax.Array) -> jax.Array:
    """d/dt (theta1, theta2, dtheta1, dtheta2): the book equations, as Gymnasium's `_dsdt`.

    theta1 is the first link's angle from hanging straight down, theta2 the second
    link's angle relative to the first; `torque` acts on the second joint only.
    """
    theta1, theta2, dtheta1, dtheta2 = state
    m1, m2 = physics.link_mass_1, physics.link_mass_2
    l1, lc1, lc2 = physics.link_length_1, physics.link_com_pos_1, physics.link_com_pos_2
    I1 = I2 = physics.link_moi
    g = physics.gravity
    d1 = m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * jnp.cos(theta2)) + I1 + I2
    d2 = m2 * (lc2**2 + l1 * lc2 * jnp.cos(theta2)) + I2
    phi2 = m2 * lc2 * g * jnp.cos(theta1 + theta2 - math.pi / 2.0)
    phi1 = (
        -m2 * l1 * lc2 * dtheta2**2 * jnp.sin(theta2)
        - 2 * m2 * l1 * lc2 * dtheta2 * dtheta1 * jnp.sin(theta2)
        + (m1 * lc1 + m2 * l1) * g * jnp.cos(theta1 - math.pi / 2)
        + phi2
    )
    ddtheta2 = (torque + d2 / d1 * phi1 - m2 * l1 * lc2 * dtheta1**2 * jnp.sin(theta2) - phi2) / (
        m2 * lc2**2 + I2 - d2**2 / d1
    )
    ddtheta1 = -(d2 * ddtheta2 + phi1) / d1
    return jnp.stack([dtheta1, dtheta2, ddtheta1, ddtheta2])


def rk4_step(physics: AcrobotPhysics, state: jax.Array, torque: jax.Array) -> jax.Array:
    """One classic RK4 step of length dt with the torque held constant (Gymnasium's `rk4`)."""
    dt = physics.dt
    k1 = derivatives(physics, state, torque)
    k2 = derivatives(physics, state + dt / 2.0 * k1, torque)
    k3 = derivatives(physics, state + dt / 2.0 * k2, torque)
    k4 = derivatives(physics, state + dt * k3, torque)
    return state + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


def observation(state: jax.Array) -> jax.Array:
    """(cos theta1, sin theta1, cos theta2, sin theta2, dtheta1, dtheta2), as Gymnasium's `_get_ob`."""
    theta1, theta2, dtheta1, dtheta2 = state
    return jnp.stack([jnp.cos(theta1), jnp.sin(theta1), jnp.cos(theta2), jnp.sin(theta2), dtheta1, dtheta2])


class Acrobot(Env):
    """Actions 0, 1, 2 apply torque -1, 0, +1 to the elbow joint.

    `pipeline_state` is (theta1, theta2, dtheta1, dtheta2). Reward is -1 on every
    step except the terminating one, which earns 0.
    """

    observation_size = 6
    num_actions = 3
    observation_names = ("cos_theta1", "sin_theta1", "cos_theta2", "sin_theta2", "dtheta1", "dtheta2")

    def __init__(self, physics: AcrobotPhysics = AcrobotPhysics(), rules: AcrobotRules = AcrobotRules()):
        self.physics = physics
        self.rules = rules

    def replace(self, **changes) -> Acrobot:
        """A copy with other settings, e.g. `env.replace(physics=p)` inside a vmap over physics."""
        return Acrobot(**{"physics": self.physics, "rules": self.rules, **changes})

    def reset(self, key: jax.Array) -> State:
        state = self.rules.initial_state(key)
        zero = jnp.zeros((), state.dtype)
        return State(state, observation(state), zero, zero, info={"truncation": zero, "nan": zero})

    def step(self, state: State, action: jax.Array) -> State:
        action = self.check_action(action)
        torque = self.physics.torque_mag * jnp.asarray(TORQUES)[action]
        theta1, theta2, dtheta1, dtheta2 = rk4_step(self.physics, state.pipeline_state, torque)
        dtheta1, dtheta2 = self.rules.clip_velocities(dtheta1, dtheta2)
        s = jnp.stack([wrap_angle(theta1), wrap_angle(theta2), dtheta1, dtheta2])
        nan = ~jnp.isfinite(s).all()  # e.g. absurd overridden constants
        terminated = self.rules.is_terminated(s[0], s[1])
        reward = jnp.where(terminated, 0.0, -1.0).astype(s.dtype)
        done = (terminated | nan).astype(s.dtype)
        info = {**state.info, "nan": nan.astype(s.dtype)}
        return state.replace(pipeline_state=s, obs=observation(s), reward=reward, done=done, info=info)

    def scene_model(self):
        """The MJX Acrobot's model, so `envs.recording` draws both backends alike."""
        from envs.assets import load_model

        return load_model("acrobot.xml")

    def scene_qpos(self, pipeline_state: jax.Array) -> jax.Array:
        """qpos (theta1, theta2) of `scene_model()`."""
        return pipeline_state[..., :2]

    def __repr__(self) -> str:
        return f"Acrobot(physics={self.physics}, rules={self.rules})"
