"""Rerun recordings of rollouts: a 3D scene drawn from any MJCF model, plots of
observations, actions and rewards, and episode boundaries.

A rollout is collected by one jitted `lax.scan`, copied to the host once, and sent
with `rr.send_columns` (per-step `rr.log` calls would be far slower). The scene
needs no task-specific code: every geom of the env's MjModel becomes a static
Rerun shape in the geom's own frame, and its world pose per step comes from C
MuJoCo's `mj_kinematics` on the rollout's `qpos`. An env opts into the scene by
providing `scene_model()` (the MjModel to draw) and `scene_qpos(pipeline_state)`
(that model's qpos for one state); the analytic CartPole maps its state to the MJX
CartPole's qpos, so both backends are drawn the same way.

Entity paths, for env `i` under an optional `root`:
  env/<i>/obs/<name>, env/<i>/action, env/<i>/reward       every step
  env/<i>/camera/rgb, env/<i>/camera/depth                  a pixel task's newest frame, every step
  env/<i>/episode_done, env/<i>/episode/return, .../length  at the steps where episodes end
  world/env_<i>/<geom name>                                 static shape + per-step pose
Timelines: `step` (sequence) and `sim_time` (seconds).
"""

from __future__ import annotations

import os
import re
import uuid
import warnings
from pathlib import Path
from typing import Any, Callable, NamedTuple

import jax
import mujoco
import numpy as np
import pyarrow as pa
import rerun as rr

from envs.core import Env
from envs.rollouts import (PolicyFn, Rollout, collect_rollout, has_scene, random_policy,  # noqa: F401
                          rollout_program, trim_to_episodes)

APPLICATION_ID = "mjxsuite"
VISIBLE_GROUPS = (0, 1, 2)  # geom groups MuJoCo's viewer shows by default


# ---- output files ---------------------------------------------------------------
def check_output_path(path: str | os.PathLike, overwrite: bool = False) -> Path:
    """Fail early, with a clear message, unless `path` can be written as an .rrd file."""
    out = Path(path)
    if out.is_dir():
        raise ValueError(f"Rerun output {out} is a directory; give a file name such as {out / 'run.rrd'}")
    if out.exists():
        if not overwrite:
            raise ValueError(f"Rerun output {out} already exists; pass --overwrite to replace it")
        if not os.access(out, os.W_OK):
            raise ValueError(f"cannot write Rerun output {out}: permission denied")
        return out
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.touch(exist_ok=False)
        out.unlink()
    except OSError as err:
        raise ValueError(f"cannot write Rerun output {out}: {err.strerror or err}") from err
    return out


def open_recording(path: str | os.PathLike, overwrite: bool = False, blueprint: Any = None) -> rr.RecordingStream:
    """A fresh recording stream (no global state) writing to `path`; pair with `close_recording`."""
    out = check_output_path(path, overwrite)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
    rec.save(out, default_blueprint=blueprint)
    return rec


def close_recording(rec: rr.RecordingStream) -> None:
    """Flush and close the file so it gets its footer (readable by `RrdReader(...).store()`)."""
    rec.flush()
    rec.disconnect()


# ---- the scene: MjModel -> static Rerun shapes ------------------------------------
class SceneGeom(NamedTuple):
    geom_id: int
    name: str  # entity name under world/env_<i>/
    shape: Any  # a Rerun archetype in the geom's own frame
    fixed: bool  # on a body welded to the world: its pose never changes


def geom_color(model: mujoco.MjModel, geom_id: int) -> np.ndarray:
    """RGBA as MuJoCo's renderer picks it: the geom's rgba unless it has a material and
    its rgba was left at the default, then the material's."""
    rgba = model.geom_rgba[geom_id]
    material = model.geom_matid[geom_id]
    if material >= 0 and np.allclose(rgba, (0.5, 0.5, 0.5, 1.0)):
        rgba = model.mat_rgba[material]
    return np.round(np.clip(rgba, 0.0, 1.0) * 255).astype(np.uint8)


def _box(model, g, color):
    return rr.Boxes3D(half_sizes=[model.geom_size[g]], colors=[color], fill_mode="solid")


def _plane(model, g, color):
    # A zero size means an infinite plane; draw a generous finite patch instead.
    extent = 2.0 * float(model.stat.extent)
    half_x, half_y = (s if s > 0 else extent for s in model.geom_size[g][:2])
    thickness = 1e-3
    return rr.Boxes3D(half_sizes=[[half_x, half_y, thickness]], centers=[[0, 0, -thickness]], colors=[color],
                      fill_mode="solid")


def _sphere(model, g, color):
    radius = model.geom_size[g][0]
    return rr.Ellipsoids3D(half_sizes=[[radius] * 3], colors=[color], fill_mode="solid")


def _ellipsoid(model, g, color):
    return rr.Ellipsoids3D(half_sizes=[model.geom_size[g]], colors=[color], fill_mode="solid")


def _capsule(model, g, color):
    # MuJoCo's capsule is centred on its frame along z; Rerun's runs from 0 to `length`.
    radius, half_length = model.geom_size[g][:2]
    return rr.Capsules3D(lengths=[2 * half_length], radii=[radius], translations=[[0, 0, -half_length]],
                         colors=[color], fill_mode="solid")


def _cylinder(model, g, color):
    radius, half_length = model.geom_size[g][:2]
    return rr.Cylinders3D(lengths=[2 * half_length], radii=[radius], colors=[color], fill_mode="solid")


def _mesh(model, g, color):
    mesh = model.geom_dataid[g]
    start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    vertices = model.mesh_vert[start : start + count]
    face_start, face_count = model.mesh_faceadr[mesh], model.mesh_facenum[mesh]
    faces = model.mesh_face[face_start : face_start + face_count]
    return rr.Mesh3D(vertex_positions=vertices, triangle_indices=faces,
                     vertex_normals=_vertex_normals(vertices, faces), albedo_factor=color)


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted smooth normals, so the viewer can shade the mesh."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    face_normals = np.cross(b - a, c - a)
    normals = np.zeros_like(vertices)
    for k in range(3):
        np.add.at(normals, faces[:, k], face_normals)
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)


SHAPES: dict[int, Callable] = {
    mujoco.mjtGeom.mjGEOM_PLANE: _plane,
    mujoco.mjtGeom.mjGEOM_SPHERE: _sphere,
    mujoco.mjtGeom.mjGEOM_CAPSULE: _capsule,
    mujoco.mjtGeom.mjGEOM_ELLIPSOID: _ellipsoid,
    mujoco.mjtGeom.mjGEOM_CYLINDER: _cylinder,
    mujoco.mjtGeom.mjGEOM_BOX: _box,
    mujoco.mjtGeom.mjGEOM_MESH: _mesh,
}


def _entity_name(model: mujoco.MjModel, geom_id: int) -> str:
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom_id)
    return re.sub(r"[^A-Za-z0-9_.-]", "_", name) if name else f"geom_{geom_id}"


def _is_fixed(model: mujoco.MjModel, body_id: int) -> bool:
    return model.body_weldid[body_id] == 0 and model.body_mocapid[body_id] < 0


def scene_from_model(model: mujoco.MjModel, groups: tuple[int, ...] = VISIBLE_GROUPS) -> list[SceneGeom]:
    """One static Rerun shape per visible geom; unsupported geom types are skipped with a warning."""
    geoms = []
    for g in range(model.ngeom):
        if model.geom_group[g] not in groups or model.geom_rgba[g][3] == 0:
            continue
        kind = int(model.geom_type[g])
        name = _entity_name(model, g)
        if kind not in SHAPES:
            warnings.warn(f"Rerun scene: geom {name!r} has type {mujoco.mjtGeom(kind).name}, "
                          "which is not drawn; skipping it", stacklevel=2)
            continue
        shape = SHAPES[kind](model, g, geom_color(model, g))
        geoms.append(SceneGeom(g, name, shape, _is_fixed(model, model.geom_bodyid[g])))
    return geoms


def geom_poses(model: mujoco.MjModel, qpos: np.ndarray, geom_ids: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """World positions (T, G, 3) and row-major rotations (T, G, 9) of `geom_ids` for each qpos row.

    C MuJoCo's `mj_kinematics` on the host: no compile, so faster overall than a vmapped
    `mjx.kinematics` unless one compiled shape is reused many times.
    """
    data = mujoco.MjData(model)
    qpos = np.asarray(qpos, np.float64).reshape(-1, model.nq)
    # Views into `data`, fetched once: attribute lookups and fancy indexing inside
    # the loop would cost more than the kinematics itself.
    data_qpos, data_xpos, data_xmat = data.qpos, data.geom_xpos, data.geom_xmat
    positions = np.empty((len(qpos), model.ngeom, 3))
    rotations = np.empty((len(qpos), model.ngeom, 9))
    for t, q in enumerate(qpos):
        data_qpos[:] = q
        mujoco.mj_kinematics(model, data)
        positions[t] = data_xpos
        rotations[t] = data_xmat
    return positions[:, geom_ids], rotations[:, geom_ids]


def _mat3x3_column(rotations: np.ndarray) -> pa.Array:
    """Row-major (T, 9) rotations as Rerun's column-major Mat3x3 arrow array, built in
    one numpy operation (a plain (T, 3, 3) array is converted by a per-row Python loop)."""
    flat = np.ascontiguousarray(rotations.reshape(-1, 3, 3).transpose(0, 2, 1), np.float32).ravel()
    return pa.FixedSizeListArray.from_arrays(flat, type=rr.components.TransformMat3x3Batch._ARROW_DATATYPE)


def log_scene(rec: rr.RecordingStream, model: mujoco.MjModel, root: str, qpos: np.ndarray, times: list,
              geoms: list[SceneGeom] | None = None, static: bool = True, origin=(0.0, 0.0, 0.0)) -> None:
    """Draw `model` under `root`: static shapes (and fixed poses) once, then one pose row per qpos row."""
    geoms = scene_from_model(model) if geoms is None else geoms
    moving = [g for g in geoms if not g.fixed]
    if static:
        rec.log(root, rr.Transform3D(translation=origin), static=True)
        fixed = [g for g in geoms if g.fixed]
        positions, rotations = geom_poses(model, model.qpos0, [g.geom_id for g in fixed])
        for k, g in enumerate(fixed):
            pose = rr.Transform3D(translation=positions[0, k], mat3x3=rotations[0, k])
            rec.log(f"{root}/{g.name}", pose, static=True)
        for g in geoms:
            rec.log(f"{root}/{g.name}", g.shape, static=True)
    if not moving:
        return
    positions, rotations = geom_poses(model, qpos, [g.geom_id for g in moving])
    for k, g in enumerate(moving):
        columns = rr.Transform3D.columns(translation=positions[:, k], mat3x3=_mat3x3_column(rotations[:, k]))
        rec.send_columns(f"{root}/{g.name}", indexes=times, columns=columns)


def env_spacing(model: mujoco.MjModel, geoms: list[SceneGeom]) -> float:
    """Distance along y between envs drawn side by side: the scene's width at qpos0, plus a margin."""
    positions, _ = geom_poses(model, model.qpos0, [g.geom_id for g in geoms])
    half_width = 0.0
    for g, position in zip(geoms, positions[0]):
        if model.geom_type[g.geom_id] == mujoco.mjtGeom.mjGEOM_PLANE:
            reach = model.geom_size[g.geom_id][1] or model.stat.extent
        else:
            reach = model.geom_rbound[g.geom_id]
        half_width = max(half_width, abs(position[1]) + reach)
    return 2.2 * float(half_width or model.stat.extent)


class Scene(NamedTuple):
    """What drawing an env needs, built once: its model, the shapes, and the spacing between envs."""

    model: mujoco.MjModel
    geoms: list[SceneGeom]
    spacing: float


def env_scene(env: Env) -> Scene | None:
    """The env's scene, or None when it does not provide `scene_model`/`scene_qpos`."""
    if not has_scene(env):
        return None
    model = env.scene_model()
    geoms = scene_from_model(model)
    return Scene(model, geoms, env_spacing(model, geoms))


# ---- logging a rollout ---------------------------------------------------------------
def observation_names(env: Env) -> list[str]:
    names = getattr(env, "observation_names", None)
    return list(names) if names is not None else [f"obs_{k}" for k in range(env.observation_size)]


def env_dt(env: Env) -> float:
    """Seconds per env step: `env.dt` (MJX envs) or `env.physics.tau` (analytic), else 1."""
    dt = getattr(env, "dt", None)
    if dt is None:
        dt = getattr(getattr(env, "physics", None), "tau", 1.0)
    return float(dt)


def _path(root: str, *parts) -> str:
    return "/".join([root.strip("/")] * bool(root.strip("/")) + [str(p) for p in parts])


def _times(steps: np.ndarray, dt: float) -> list:
    return [rr.TimeColumn("step", sequence=steps), rr.TimeColumn("sim_time", duration=steps * dt)]


def _send_scalars(rec, path: str, times: list, values: np.ndarray) -> None:
    rec.send_columns(path, indexes=times, columns=rr.Scalars.columns(scalars=np.asarray(values, np.float64)))


def _log_env_plots(rec, root: str, data: Rollout, i: int, names: list[str], times: list, steps: np.ndarray,
                   dt: float, static: bool) -> None:
    for k, name in enumerate(names):
        if static:
            rec.log(_path(root, "obs", name), rr.SeriesLines(names=name), static=True)
        _send_scalars(rec, _path(root, "obs", name), times, data.obs[:, i, k])
    action = data.action[:, i]
    if action.ndim == 1:
        _send_scalars(rec, _path(root, "action"), times, action)
    else:
        for k in range(action.shape[1]):
            _send_scalars(rec, _path(root, "action", k), times, action[:, k])
    _send_scalars(rec, _path(root, "reward"), times, data.reward[:, i])

    ends = np.flatnonzero(data.done[:, i] > 0)
    if static:
        rec.log(_path(root, "episode_done"), rr.SeriesPoints(markers="down", marker_sizes=6.0), static=True)
        for name in ("return", "length"):
            rec.log(_path(root, "episode", name), rr.SeriesPoints(marker_sizes=4.0), static=True)
    if len(ends):
        end_times = _times(steps[ends], dt)
        _send_scalars(rec, _path(root, "episode_done"), end_times, np.ones(len(ends)))
        _send_scalars(rec, _path(root, "episode", "return"), end_times, data.episode_return[ends, i])
        _send_scalars(rec, _path(root, "episode", "length"), end_times, data.episode_length[ends, i])


def _log_camera(rec, path: str, frames: np.ndarray, channels: int, times: list, static: bool) -> None:
    """The newest frame of each step's stack as images: `<path>/rgb`, and `<path>/depth` (the
    uint8 depth channel, grey) where the frames carry one."""
    newest = np.asarray(frames[..., -channels:], np.uint8)
    steps, height, width = newest.shape[:3]
    for name, pixels, model in (("rgb", newest[..., :3], "RGB"), ("depth", newest[..., 3:4], "L")):
        if pixels.shape[-1] == 0:
            continue
        if static:
            image_format = rr.components.ImageFormat(width=width, height=height, color_model=model,
                                                     channel_datatype="U8")
            rec.log(f"{path}/{name}", rr.Image.from_fields(format=image_format), static=True)
        rec.send_columns(f"{path}/{name}", indexes=times,
                         columns=rr.Image.columns(buffer=np.ascontiguousarray(pixels).reshape(steps, -1)))


def log_rollout(rec: rr.RecordingStream, env: Env, rollout: Rollout, *, root: str = "",
                plot_envs: int | None = None, step_offset: int = 0, static: bool = True,
                scene: Scene | None = None) -> None:
    """Send a whole rollout as columns: plots for the first `plot_envs` envs (all by default)
    and the 3D scene for the envs `collect_rollout` kept poses for.

    `step_offset` starts the `step` timeline there (back-to-back rollouts under one root);
    `static=False` skips the shapes and series styles already logged under `root`;
    pass `scene=env_scene(env)` to reuse it across calls.
    """
    data = jax.device_get(rollout)  # the one host copy
    num_steps, num_envs = data.reward.shape
    dt = env_dt(env)
    steps = np.arange(step_offset, step_offset + num_steps, dtype=np.int64)
    times = _times(steps, dt)
    images = np.ndim(data.obs) == 5  # camera frames (steps, envs, H, W, C*k): envs.pixels
    names = [] if images else observation_names(env)
    for i in range(min(num_envs, plot_envs or num_envs)):
        _log_env_plots(rec, _path(root, "env", i), data, i, names, times, steps, dt, static)
        if images:
            _log_camera(rec, _path(root, "env", i, "camera"), data.obs[:, i], getattr(env, "channels", 3),
                        times, static)
    if data.scene_qpos is None:
        return
    scene = env_scene(env) if scene is None else scene
    if static:
        rec.log(_path(root, "world"), rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)  # MuJoCo's convention
    for i in range(data.scene_qpos.shape[1]):
        log_scene(rec, scene.model, _path(root, "world", f"env_{i}"), data.scene_qpos[:, i], times, scene.geoms,
                  static=static, origin=(0.0, i * scene.spacing, 0.0))


def rollout_blueprint(root: str = "", camera: bool = False):
    """A default layout: the 3D scene beside env 0's plots (and, with `camera`, env 0's camera
    images between them: a pixel task's)."""
    import rerun.blueprint as rrb

    env0 = "/" + _path(root, "env", 0)
    cameras = [rrb.Spatial2DView(name="camera", origin=env0 + "/camera")] if camera else []
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="scene", origin="/" + _path(root, "world")),
            *cameras,
            rrb.Vertical(
                rrb.TimeSeriesView(name="observation", origin=env0 + "/obs"),
                rrb.TimeSeriesView(name="action, reward, episodes", origin=env0,
                                   contents=["$origin/action/**", "$origin/reward", "$origin/episode_done"]),
                rrb.TimeSeriesView(name="episode return", origin=env0 + "/episode/return"),
            ),
            column_shares=[3, 2, 2] if camera else [3, 2],
        ),
        rrb.TimePanel(state="collapsed", timeline="step", play_state="paused"),
        collapse_panels=True,
    )
