"""CartPole-v1 of Gymnasium (gymnasium/envs/classic_control/cartpole.py), written as its equations in
JAX: `envs.make("cartpole")`. A pole hinged on a cart; push the cart left or right to keep it up.

## Action Space
Discrete(2), as v1: 0 pushes the cart left, 1 right, with force_mag (10 N).

## Observation Space
(x, x_dot, theta, theta_dot), 4 values, as v1; in JAX's default float type: float32 (v1: float32
observations from a float64 state), float64 with `jax_enable_x64`.

## Rewards
1 on every step, the terminating one included (v1's default, sutton_barto_reward=False).

## Starting State
Each of the four values U(-0.05, 0.05), as v1; JAX's random numbers: the same distribution, not
the same draws.

## Episode End
- Terminated: |x| > 2.4 or |theta| > 12 degrees (as v1), or a non-finite state (ours).
- Truncated: after 500 steps (`envs.make`'s TimeLimit, v1's max_episode_steps).

## Arguments
`envs.make("cartpole", ...)`: `integrator` ("euler", v1's default, or "semi_implicit", v1's
"semi-implicit euler"), `physics` (`CartPolePhysics`: gravity 9.8, masscart 1.0, masspole 0.1,
length 0.5, force_mag 10.0, tau 0.02: v1's constants) and `rules` (`CartPoleRules`: x_threshold
2.4, theta_threshold 12 degrees, reset_bound 0.05). v1 takes none of these as constructor arguments
(only render_mode and sutton_barto_reward); ours are overrides and vmappable pytrees.

## Version History
- v1 only (500 steps); v0 (200 steps) is not offered.

## Equality with Gymnasium
tests/test_cartpole_gymnasium.py, against v1's own `CartPoleEnv` (float64):
- test_step_matches_gymnasium: 10,000 states across the whole non-terminal region and beyond,
  random actions, one step each, both integrators: the next state within 1e-12 under float64
  and within 1e-5 under float32; reward 1; termination equal under float64, and under float32 on
  all but 0.1% of the steps (a state within rounding of a threshold may flip).
- test_episodes_terminate_on_the_same_step: 30 whole episodes from v1's own resets, random
  actions, float64, both integrators: every step's state within 1e-12, rewards equal, the episode
  ending on the same step.
- test_truncation_at_500_is_not_termination: a balancing controller runs 500 steps; step 500 is
  truncation, as v1's TimeLimit (also for cartpole-mjx).
- test_reset_distribution_matches_gymnasium_bounds: inside +-0.05, both ends reached, mean within
  4e-3 of 0 and spread within 5% of 0.1 / sqrt(12), for ours and v1's alike.
"""

from __future__ import annotations

import math
from typing import ClassVar

import jax
import jax.numpy as jnp
from flax import struct

from envs.core import Env, State
from envs.ranges import FINITE, NON_NEGATIVE, POSITIVE, Range

INTEGRATORS = ("euler", "semi_implicit")


@struct.dataclass
class CartPolePhysics:
    """Physical constants. A pytree of floats, so it can be vmapped for domain randomisation."""

    gravity: float = 9.8
    masscart: float = 1.0
    masspole: float = 0.1
    length: float = 0.5  # half the pole's length: the pole is a uniform rod 2 * length long
    force_mag: float = 10.0
    tau: float = 0.02  # seconds between state updates

    # What `envs.make` accepts as overrides (a vmapped pytree of values is not checked).
    RANGES: ClassVar[dict[str, Range]] = {"gravity": FINITE, "masscart": POSITIVE, "masspole": POSITIVE,
                                          "length": POSITIVE, "force_mag": NON_NEGATIVE, "tau": POSITIVE}


@struct.dataclass
class CartPoleRules:
    """Reset and termination rules, shared by the analytic and the MJX CartPole."""

    x_threshold: float = 2.4
    theta_threshold: float = 12 * 2 * math.pi / 360  # 12 degrees, Gymnasium's exact expression
    reset_bound: float = 0.05  # reset state ~ U(-reset_bound, reset_bound)^4

    # A zero threshold is allowed: every episode then ends on its first step (a test uses that).
    RANGES: ClassVar[dict[str, Range]] = {"x_threshold": NON_NEGATIVE, "theta_threshold": NON_NEGATIVE,
                                          "reset_bound": NON_NEGATIVE}

    def initial_state(self, key: jax.Array) -> jax.Array:
        """(x, x_dot, theta, theta_dot) as one array, drawn as Gymnasium draws them."""
        return jax.random.uniform(key, (4,), minval=-self.reset_bound, maxval=self.reset_bound)

    def is_terminated(self, x: jax.Array, theta: jax.Array) -> jax.Array:
        return (jnp.abs(x) > self.x_threshold) | (jnp.abs(theta) > self.theta_threshold)


@struct.dataclass
class CartPoleState:
    """The analytic CartPole's `pipeline_state`: four scalars (four `[N]` arrays for a batch).

    Separate scalars rather than one `[4]` array, so that a batch's state is four `[N]`
    arrays: on a GPU, XLA then fuses a whole auto-resetting step into one kernel with one
    thread per env, where an `[N, 4]` array had every one of its four columns recompute the
    env's physics and reset draw (docs/results.md measures it).
    """

    x: jax.Array
    x_dot: jax.Array
    theta: jax.Array
    theta_dot: jax.Array

    @classmethod
    def from_array(cls, values: jax.Array) -> CartPoleState:
        """From (x, x_dot, theta, theta_dot) along the last axis."""
        values = jnp.asarray(values)
        return cls(values[..., 0], values[..., 1], values[..., 2], values[..., 3])

    def as_array(self) -> jax.Array:
        """(x, x_dot, theta, theta_dot) along a new last axis: the observation."""
        return jnp.stack([self.x, self.x_dot, self.theta, self.theta_dot], axis=-1)


def dynamics(physics: CartPolePhysics, state: CartPoleState, force: jax.Array):
    """Cart and pole accelerations (Florian 2005, eqs. 23-24, as Gymnasium writes them)."""
    theta, theta_dot = state.theta, state.theta_dot
    total_mass = physics.masspole + physics.masscart
    polemass_length = physics.masspole * physics.length
    costheta, sintheta = jnp.cos(theta), jnp.sin(theta)
    temp = (force + polemass_length * theta_dot**2 * sintheta) / total_mass
    thetaacc = (physics.gravity * sintheta - costheta * temp) / (
        physics.length * (4.0 / 3.0 - physics.masspole * costheta**2 / total_mass)
    )
    xacc = temp - polemass_length * thetaacc * costheta / total_mass
    return xacc, thetaacc


def integrate(physics: CartPolePhysics, state: CartPoleState, force: jax.Array, integrator: str) -> CartPoleState:
    """One step of length tau. "euler" (Gymnasium's default) advances positions with the
    old velocities; "semi_implicit" updates velocities first, as MuJoCo's Euler does."""
    x, x_dot, theta, theta_dot = state.x, state.x_dot, state.theta, state.theta_dot
    xacc, thetaacc = dynamics(physics, state, force)
    tau = physics.tau
    if integrator == "euler":
        x, theta = x + tau * x_dot, theta + tau * theta_dot
        x_dot, theta_dot = x_dot + tau * xacc, theta_dot + tau * thetaacc
    else:
        x_dot, theta_dot = x_dot + tau * xacc, theta_dot + tau * thetaacc
        x, theta = x + tau * x_dot, theta + tau * theta_dot
    return CartPoleState(x, x_dot, theta, theta_dot)


class CartPole(Env):
    """Observation (x, x_dot, theta, theta_dot); actions 0 (push left) and 1 (push right).

    Reward is 1 on every step, the terminating one included. `pipeline_state` is a
    `CartPoleState`; `obs` is the same four values as one array.
    """

    observation_size = 4
    num_actions = 2
    observation_names = ("x", "x_dot", "theta", "theta_dot")

    def __init__(
        self,
        integrator: str = "euler",
        physics: CartPolePhysics = CartPolePhysics(),
        rules: CartPoleRules = CartPoleRules(),
    ):
        if integrator not in INTEGRATORS:
            raise ValueError(f"unknown integrator {integrator!r}; choose one of {INTEGRATORS}")
        self.integrator = integrator
        self.physics = physics
        self.rules = rules

    def replace(self, **changes) -> CartPole:
        """A copy with other settings, e.g. `env.replace(physics=p)` inside a vmap over physics."""
        fields = {"integrator": self.integrator, "physics": self.physics, "rules": self.rules}
        return CartPole(**{**fields, **changes})

    def reset(self, key: jax.Array) -> State:
        start = self.rules.initial_state(key)
        zero = jnp.zeros((), start.dtype)
        return State(CartPoleState.from_array(start), start, zero, zero, info={"truncation": zero, "nan": zero})

    def step(self, state: State, action: jax.Array) -> State:
        action = self.check_action(action)
        force = jnp.where(action == 1, self.physics.force_mag, -self.physics.force_mag)
        new = integrate(self.physics, state.pipeline_state, force, self.integrator)
        obs = self.observation(new)
        # e.g. absurd overridden constants. Field by field, not over `obs`: a reduction over
        # an env's four values would end the one-kernel-per-step fusion on a GPU.
        nan = ~(jnp.isfinite(new.x) & jnp.isfinite(new.x_dot) & jnp.isfinite(new.theta) & jnp.isfinite(new.theta_dot))
        done = self.rules.is_terminated(new.x, new.theta) | nan
        one = jnp.ones((), obs.dtype)
        info = {**state.info, "nan": nan.astype(obs.dtype)}
        return state.replace(pipeline_state=new, obs=obs, reward=one, done=done.astype(obs.dtype), info=info)

    def observation(self, pipeline_state: CartPoleState) -> jax.Array:
        """The observation of a physics state (as `MjxEnv.observation(data)`)."""
        return pipeline_state.as_array()

    def scene_model(self):
        """The MJX CartPole's model, so `envs.recording` draws both backends alike."""
        from envs.assets import load_model

        return load_model("cartpole.xml")

    def scene_qpos(self, pipeline_state: CartPoleState) -> jax.Array:
        """qpos (x, theta) of `scene_model()` for the state."""
        return jnp.stack([pipeline_state.x, pipeline_state.theta], axis=-1)

    def __repr__(self) -> str:
        return f"CartPole(integrator={self.integrator!r}, physics={self.physics}, rules={self.rules})"
