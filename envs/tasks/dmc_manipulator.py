"""The DeepMind Control Suite's manipulator (dm_control/suite/manipulator.py), stepped by MJX:
`envs.make("dmc-manipulator-bring-ball")`, `"dmc-manipulator-bring-peg"` and `"dmc-manipulator-insert-ball"`.
A planar arm
(root, shoulder, elbow, wrist hinges) with a two-fingered hand (thumb and finger coupled by a tendon
equality, each with a fingertip) brings a prop to a ghost target of its shape (Euler, elliptic
friction cones, timestep 0.001, 10 physics steps per control step: dt 0.01). The MJCF is
dm_control's `manipulator.xml`, read from the installed package, less the props the task does not
use, as dm_control's `make_model(use_peg, insert)` removes them: bring_ball keeps the ball and its
target, bring_peg the peg (a blade, a guard and a pommel: three capsule and sphere geoms) and its
target; insert_ball adds the cup (four capsules), placed at the target every episode: bring_ball with
that receptacle (dm_control 1.0.50's `Bring` gives it bring's reward and observation; the cup is not
observed: it is at the target). insert_peg (its slot of three boxes) is not offered: MJX's
capsule-box collision misses contacts C MuJoCo finds (docs/tasks.md).

- Action: Box(-1, 1, (5,)): root, shoulder, elbow, wrist motors and the grasp tendon's motor.
- Observation (44), dm_control's order: arm_pos (16) = (sin, cos) of each of the 8 arm joints
  (arm_root, arm_shoulder, arm_elbow, arm_wrist, finger, fingertip, thumb, thumbtip), row by row;
  arm_vel (8) = their qvel; touch (5) = log1p of the palm, finger, thumb, fingertip and thumbtip
  touch sensors (acceleration stage: the last substep's value, as in dm_control's legacy step);
  hand_pos (4), object_pos (4), target_pos (4) = the hand's, the prop's and the target's bodies' 2-D
  poses (xpos x, z, then xquat w, y); object_vel (3) = the prop's qvel (x, z, y).
- Reward, with close(d) = tolerance(d, (0, 0.01), margin 0.02), gaussian: bring_ball
  close(|ball site - target site|); bring_peg max(bringing, grasping / 3), bringing the mean of
  close(peg site - target_peg site) and close(peg_tip - target_peg_tip), grasping the mean of
  close(peg_grasp - the hand's grasp site) and close(peg_pinch - the hand's pinch site).
- Reset: dm_control's rejection loop, until nothing touches (its `ncon > 0` after a forward pass;
  here a `lax.while_loop` on MJX's contact slots closer than their margin): the arm joints uniform
  in their ranges (the root U(-pi, pi)), the finger set to the thumb's angle; the target at x
  U(-0.4, 0.4), z U(0.1, 0.4), turned U(-pi, pi) about y (an insert's U(-pi/3, pi/3), its receptacle
  with it); the prop, with probability 0.1 in the hand
  (at the grasp site, turned as the grasp site is), 0.1 on the target (its position and angle),
  else at x U(-0.5, 0.5), z U(0, 0.7), angle U(0, 2 pi) and thrown at x velocity U(-5, 5). The
  velocity is the loop's one draw that a later try does not overwrite: a start in the hand or on the
  target keeps the last thrown velocity of a rejected try (0 if none), as dm_control's loop leaves it.
- Episode: 1,000 steps (10 s simulated), never terminated.

The target's pose is per episode (dm_control edits `model.body_pos`/`body_quat` of the target body
in every try of its loop): kept in `state.info["target"]` as the model holds it (x, z, qw, qy) and
written after each physics call into the body's, its sites' and its geoms' derived poses
(`with_episode`), where dm_control's edited model puts them. The target is a ghost (contype and
conaffinity 0, fixed to the world): its pose moves nothing else, so every env and every MuJoCo Warp
world steps the task's one model. insert_ball also moves the colliding cup, which the physics must
see: each env steps the task's model with that body's `body_pos`/`body_quat` rows
edited as dm_control edits them (`episode_model`), under impl="jax" only (MuJoCo Warp's worlds step
one model). The ball put on the target touches the cup at zero distance by design (its radius is the
cup's inner half-width): whether such a try of the reset's loop touches is decided by rounding, so
fewer of our starts are on the target than dm_control's (docs/tasks.md).
"""

from __future__ import annotations

import os
from typing import ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.mjx_env import mjx
from envs.tasks.dm_control_suite import DmControlEnv, tolerance

ARM_JOINTS = ("arm_root", "arm_shoulder", "arm_elbow", "arm_wrist", "finger", "fingertip", "thumb", "thumbtip")
TOUCH_SENSORS = ("palm_touch", "finger_touch", "thumb_touch", "fingertip_touch", "thumbtip_touch")
ALL_PROPS = ("ball", "target_ball", "cup", "peg", "target_peg", "slot")  # dm_control's _ALL_PROPS
CLOSE = 0.01  # dm_control's _CLOSE (m)
P_IN_HAND, P_IN_TARGET = 0.1, 0.1  # _P_IN_HAND, _P_IN_TARGET
TARGET_LOW, TARGET_HIGH = (-0.4, 0.1), (0.4, 0.4)  # the target's x, z box (m)
OBJECT_LOW, OBJECT_HIGH = (-0.5, 0.0, 0.0), (0.5, 0.7, 2 * np.pi)  # a free start's x, z, angle
OBJECT_SPEED = 5.0  # a free start's x velocity U(-5, 5) (m/s)


class DmcManipulator(DmControlEnv):
    """dm_control's `manipulator.Bring` for a prop (`prop`: "ball" or "peg"; each task class sets it
    and its reward): the model as `make_model` trims it, the rejection-sampled reset, the target's pose."""

    costly_reset = True
    domain = "manipulator"
    control_timestep = 0.01  # dm_control's _CONTROL_TIMESTEP
    prop: ClassVar[str] = "ball"
    # An insert task's receptacle (insert_ball's "cup"; None: a bring task), moved with the target each
    # episode, and the target's turn: U(-turn, turn) (dm_control's: pi, an insert's pi / 3).
    receptacle: ClassVar[str | None] = None
    turn: ClassVar[float] = np.pi
    episode_info = ("target",)  # the target body's (x, z, qw, qy), for envs.interop.dm_control
    observation_shapes = (("arm_pos", 16), ("arm_vel", 8), ("touch", 5), ("hand_pos", 4), ("object_pos", 4),
                          ("object_vel", 3), ("target_pos", 4))

    @property
    def target(self) -> str:
        return f"target_{self.prop}"

    def load_mj_model(self, path: os.PathLike) -> mujoco.MjModel:
        """dm_control's `make_model(use_peg, insert)`: the unused props' bodies removed."""
        spec = mujoco.MjSpec.from_file(str(path))
        for prop in ALL_PROPS:
            if prop not in (self.prop, self.target, self.receptacle):
                spec.delete(spec.body(prop))
        return spec.compile()

    def __init__(self, xml: str | None = None):
        super().__init__(xml)
        model = self.mj_model
        self._arm = np.array([model.joint(name).qposadr[0] for name in ARM_JOINTS])
        self._arm_vel = np.array([model.joint(name).dofadr[0] for name in ARM_JOINTS])
        limited = model.jnt_limited[[model.joint(name).id for name in ARM_JOINTS]].astype(bool)
        ranges = model.jnt_range[[model.joint(name).id for name in ARM_JOINTS]]
        self._arm_low = np.where(limited, ranges[:, 0], -np.pi)
        self._arm_high = np.where(limited, ranges[:, 1], np.pi)
        joints = [model.joint(f"{self.prop}_{axis}") for axis in "xzy"]  # dm_control's _object_joints
        self._object, self._object_vel = (np.array([j.qposadr[0] for j in joints]),
                                          np.array([j.dofadr[0] for j in joints]))
        # The target's sites and geoms in its body's frame (the ball's at its origin, the peg's along
        # it), for `with_episode` to place them where MuJoCo's kinematics would.
        body = self._target_body = model.body(self.target).id
        self._target_sites = self._local_frames(np.flatnonzero(model.site_bodyid == body), model.site_pos,
                                                model.site_quat)
        self._target_geoms = self._local_frames(np.flatnonzero(model.geom_bodyid == body), model.geom_pos,
                                                model.geom_quat)

    @staticmethod
    def _local_frames(ids: np.ndarray, pos: np.ndarray, quat: np.ndarray) -> tuple[np.ndarray, ...]:
        """(ids, their positions, their rotation matrices) in the body's frame."""
        mats = np.zeros((len(ids), 9))
        for mat, q in zip(mats, quat[ids]):
            mujoco.mju_quat2Mat(mat, q)
        return ids, pos[ids].copy(), mats.reshape(-1, 3, 3)

    # ---- reset ---------------------------------------------------------------------
    def _try(self, key: jax.Array, qvel: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """One try of dm_control's loop: (qpos, qvel, the target's x, z, qw, qy)."""
        arm_key, target_key, angle_key, branch_key, object_key, speed_key = jax.random.split(key, 6)
        model, dtype = self.mj_model, self._initial_data.qpos.dtype
        qpos = jnp.asarray(model.qpos0, dtype)
        arm = jax.random.uniform(arm_key, (len(ARM_JOINTS),), dtype, self._arm_low, self._arm_high)
        qpos = qpos.at[self._arm].set(arm)
        qpos = qpos.at[self._arm[4]].set(arm[6])  # dm_control's "symmetrize hand": finger = thumb
        target_xz = jax.random.uniform(target_key, (2,), dtype, jnp.array(TARGET_LOW), jnp.array(TARGET_HIGH))
        target_angle = jax.random.uniform(angle_key, (), dtype, -self.turn, self.turn)
        # The grasp site's pose for the in-hand start (dm_control's forward pass inside the loop).
        grasp = model.site("grasp").id
        hand = mjx.kinematics(self.reset_model, self.reset_data.replace(qpos=qpos))
        direction = hand.site_xmat[grasp]
        hand_angle = jnp.pi - jnp.arctan2(direction[2, 0], direction[0, 0])
        free = jax.random.uniform(object_key, (3,), dtype, jnp.array(OBJECT_LOW), jnp.array(OBJECT_HIGH))
        branch = jax.random.uniform(branch_key, (), dtype)
        in_hand, in_target = branch < P_IN_HAND, (branch >= P_IN_HAND) & (branch < P_IN_HAND + P_IN_TARGET)
        placed = jnp.where(in_hand, jnp.concatenate([hand.site_xpos[grasp, jnp.array([0, 2])], hand_angle[None]]),
                           jnp.concatenate([target_xz, target_angle[None]]))
        qpos = qpos.at[self._object].set(jnp.where(in_hand | in_target, placed, free))
        speed = jax.random.uniform(speed_key, (), qvel.dtype, -OBJECT_SPEED, OBJECT_SPEED)
        qvel = jnp.where(in_hand | in_target, qvel, qvel.at[self._object_vel[0]].set(speed))
        target = jnp.concatenate([target_xz, jnp.stack([jnp.cos(target_angle / 2), jnp.sin(target_angle / 2)])])
        return qpos, qvel, target

    def _start(self, key: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
        """dm_control's `initialize_episode`: tries until nothing touches (no cap, as dm_control's)."""
        def another(carry):
            key, _, qvel, _, _ = carry
            key, try_key = jax.random.split(key)
            qpos, qvel, target = self._try(try_key, qvel)
            # An insert's receptacle collides: each try is tested with it where that try put it.
            return key, qpos, qvel, target, self.touching(qpos, self.episode_model(self.reset_model,
                                                                                   {"target": target}))

        dtype = self._initial_data.qpos.dtype
        start = (key, jnp.asarray(self.mj_model.qpos0, dtype), jnp.zeros(self.mj_model.nv, dtype),
                 jnp.zeros(4, dtype), jnp.ones((), bool))
        _, qpos, qvel, target, _ = jax.lax.while_loop(lambda carry: carry[-1], another, start)
        return qpos, qvel, target

    def draw_start(self, key: jax.Array) -> tuple[jax.Array, jax.Array, dict]:
        # dm_control draws the target inside its rejection loop (a start on the target puts the ball
        # there): one loop draws the target and the state.
        qpos, qvel, target = self._start(key)
        return qpos, qvel, {"target": target.astype(self.mjx_model.body_pos.dtype)}

    def initial_qpos_qvel(self, key):
        return self._start(key)[:2]

    # ---- the target's per-episode pose -----------------------------------------------
    @property
    def per_env_model(self) -> str | None:  # DmControlEnv's refusal of impl="warp": an insert's receptacle
        return None if self.receptacle is None else f"the {self.receptacle} collides and moves (body_pos, body_quat)"

    def episode_model(self, model: mjx.Model, info) -> mjx.Model:
        """An insert task's model with the receptacle at the episode's target pose (dm_control's edit of
        its `body_pos` x, z and `body_quat` w, y: the rest stays the MJCF's); a bring task's as it is."""
        if self.receptacle is None:
            return model
        body, (x, z, w, y) = self.mj_model.body(self.receptacle).id, info["target"]
        return model.replace(body_pos=model.body_pos.at[body, jnp.array([0, 2])].set(jnp.stack([x, z])),
                             body_quat=model.body_quat.at[body, jnp.array([0, 2])].set(jnp.stack([w, y])))

    def with_episode(self, data: mjx.Data, info) -> mjx.Data:
        # A body fixed to the world: its pose is its model pose; its sites and geoms keep their places
        # in its frame (MuJoCo's kinematics: the body's pose composed with theirs).
        x, z, w, y = info["target"]
        body = self._target_body
        position = data.xpos[body].at[jnp.array([0, 2])].set(jnp.stack([x, z])).astype(data.xpos.dtype)
        zero, one = jnp.zeros_like(w), jnp.ones_like(w)
        quat = jnp.stack([w, zero, y, zero]).astype(data.xquat.dtype)
        # MuJoCo's mju_quat2Mat of (w, 0, y, 0): a turn about y.
        xmat = jnp.stack([jnp.stack([w * w - y * y, zero, 2 * w * y]), jnp.stack([zero, one, zero]),
                          jnp.stack([-2 * w * y, zero, w * w - y * y])]).astype(data.xmat.dtype)

        def placed(frames):
            ids, pos, mats = frames
            return ids, position + jnp.asarray(pos, xmat.dtype) @ xmat.T, xmat @ jnp.asarray(mats, xmat.dtype)

        sites, site_xpos, site_xmat = placed(self._target_sites)
        geoms, geom_xpos, geom_xmat = placed(self._target_geoms)
        return data.replace(xpos=data.xpos.at[body].set(position), xquat=data.xquat.at[body].set(quat),
                            xmat=data.xmat.at[body].set(xmat), site_xpos=data.site_xpos.at[sites].set(site_xpos),
                            site_xmat=data.site_xmat.at[sites].set(site_xmat),
                            geom_xpos=data.geom_xpos.at[geoms].set(geom_xpos),
                            geom_xmat=data.geom_xmat.at[geoms].set(geom_xmat))

    def put_episode(self, physics, info) -> None:
        """dm_control's physics given this episode's edits (`info`: our `state.info` entries)."""
        for body in (self.target, self.receptacle) if self.receptacle else (self.target,):
            physics.named.model.body_pos[body, ["x", "z"]] = info["target"][:2]
            physics.named.model.body_quat[body, ["qw", "qy"]] = info["target"][2:]

    def get_episode(self, physics) -> dict:
        return {"target": np.concatenate([physics.named.model.body_pos[self.target, ["x", "z"]],
                                          physics.named.model.body_quat[self.target, ["qw", "qy"]]])}

    # ---- readings --------------------------------------------------------------------
    def body_2d_pose(self, data: mjx.Data, body: str) -> jax.Array:
        """dm_control's `body_2d_pose`: xpos x, z and xquat w, y."""
        index = self.mj_model.body(body).id
        return jnp.concatenate([data.xpos[index, jnp.array([0, 2])], data.xquat[index, jnp.array([0, 2])]])

    def observations(self, data):
        angles = data.qpos[self._arm]
        return {"arm_pos": jnp.stack([jnp.sin(angles), jnp.cos(angles)], axis=1),
                "arm_vel": data.qvel[self._arm_vel],
                "touch": jnp.log1p(jnp.concatenate([self.sensor(data, name) for name in TOUCH_SENSORS])),
                "hand_pos": self.body_2d_pose(data, "hand"), "object_pos": self.body_2d_pose(data, self.prop),
                "object_vel": data.qvel[self._object_vel], "target_pos": self.body_2d_pose(data, self.target)}

    def site_distance(self, data: mjx.Data, first: str, second: str) -> jax.Array:
        first, second = self.mj_model.site(first).id, self.mj_model.site(second).id
        return jnp.linalg.norm(data.site_xpos[first] - data.site_xpos[second])

    def close(self, data: mjx.Data, first: str, second: str) -> jax.Array:
        """dm_control's `_is_close` of two sites' distance."""
        return tolerance(self.site_distance(data, first, second), (0.0, CLOSE), margin=2 * CLOSE)


class DmcManipulatorBringBall(DmcManipulator):
    task = "bring_ball"

    def reward(self, data, action, prev):
        return self.close(data, "ball", "target_ball")


class DmcManipulatorBringPeg(DmcManipulator):
    task = "bring_peg"
    prop = "peg"

    def reward(self, data, action, prev):
        # dm_control's `_peg_reward`: the peg at the target, both its middle and its tip (its
        # orientation), else a third of holding it at the hand's grasp and pinch sites.
        grasping = (self.close(data, "peg_grasp", "grasp") + self.close(data, "peg_pinch", "pinch")) / 2
        bringing = (self.close(data, "peg", "target_peg") + self.close(data, "target_peg_tip", "peg_tip")) / 2
        return jnp.maximum(bringing, grasping / 3)


class DmcManipulatorInsertBall(DmcManipulatorBringBall):
    """dm_control's insert_ball: bring_ball's task and reward with the cup kept, placed at the target."""

    task = "insert_ball"
    receptacle = "cup"
    turn = np.pi / 3
