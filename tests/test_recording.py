"""Rerun logging: files read back with Rerun's own reader, pose correctness, CLI behaviour."""

import json
import shutil
import subprocess
import warnings
from collections import defaultdict
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

import envs
from agents import DQN, DQNConfig, processes
from agents import training_log as agent_recording
from agents.cli import main as cli_main
from envs import recording

STEPS = 300
TINY = ["--steps", "200", "--eval_every", "100", "--learning_starts", "64", "--eval-episodes", "4", "--hidden", "16"]


# ---- reading files back ---------------------------------------------------------
class Contents:
    """What a .rrd holds, per entity: static columns (one list per static chunk) and temporal rows."""

    def __init__(self, path):
        self.static = defaultdict(list)
        self.rows = defaultdict(int)
        self.timelines = defaultdict(set)
        self.chunks = defaultdict(list)
        for chunk in RrdReader(path).store().stream():
            entity = chunk.entity_path.lstrip("/")
            if chunk.is_static:
                self.static[entity].append(set(chunk.to_record_batch().schema.names))
            else:
                self.rows[entity] += chunk.num_rows
                self.timelines[entity] |= set(chunk.timeline_names)
                self.chunks[entity].append(chunk.to_record_batch())

    @property
    def entities(self):
        return set(self.static) | set(self.rows)

    def column(self, entity, name, index="step"):
        """A temporal component column as an array (rows, ...), sorted by the `index` timeline."""
        batches = self.chunks[entity]
        step = np.concatenate([b.column(index).to_numpy() for b in batches])
        values = np.concatenate([np.stack(b.column(name).to_pylist())[:, 0] for b in batches])
        return values[np.argsort(step, kind="stable")]


def verify_with_rerun_cli(path):
    binary = shutil.which("rerun") or str(Path(__import__("sys").executable).with_name("rerun"))
    try:
        done = subprocess.run([binary, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60)
    except OSError as err:
        pytest.skip(f"the rerun binary cannot run here ({err}); skipping `rerun rrd verify`")
    assert done.returncode == 0, done.stdout + done.stderr


def write_rollout(path, env, num_envs=3, scene_envs=2, steps=STEPS, seed=0):
    rollout = recording.collect_rollout(env, recording.random_policy(env), jax.random.PRNGKey(seed),
                                        num_envs=num_envs, steps=steps, scene_envs=scene_envs)
    rec = recording.open_recording(path)
    try:
        recording.log_rollout(rec, env, rollout)
    finally:
        recording.close_recording(rec)
    return jax.device_get(rollout)


@pytest.fixture(scope="module")
def analytic_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("rrd") / "cartpole.rrd"
    rollout = write_rollout(path, envs.make("cartpole"))
    return path, rollout, Contents(path)


# ---- the scene builder ------------------------------------------------------------
ALL_GEOMS = """
<mujoco>
  <asset>
    <material name="red" rgba="1 0 0 1"/>
    <mesh name="tetra" vertex="0 0 0  1 0 0  0 1 0  0 0 1"/>
    <hfield name="terrain" nrow="3" ncol="3" size="1 1 0.2 0.1"/>
  </asset>
  <worldbody>
    <geom name="ground" type="plane" size="0 0 1"/>
    <geom name="terrain" type="hfield" hfield="terrain" pos="5 0 0"/>
    <geom name="hidden" type="box" size=".1 .1 .1" group="3"/>
    <body name="thing" pos="0 0 1">
      <freejoint/>
      <geom name="box" type="box" size=".1 .2 .3" material="red"/>
      <geom name="ball" type="sphere" size=".1" pos="1 0 0" rgba="0 1 0 1"/>
      <geom name="pill" type="capsule" size=".1 .2" pos="2 0 0"/>
      <geom name="can" type="cylinder" size=".1 .2" pos="3 0 0"/>
      <geom name="egg" type="ellipsoid" size=".1 .2 .3" pos="4 0 0"/>
      <geom type="mesh" mesh="tetra" pos="5 0 0"/>
    </body>
  </worldbody>
</mujoco>
"""


def test_scene_from_any_mjcf_one_entity_per_geom():
    model = mujoco.MjModel.from_xml_string(ALL_GEOMS)
    with pytest.warns(UserWarning, match="terrain.*HFIELD"):
        geoms = recording.scene_from_model(model)
    kinds = {g.name: type(g.shape) for g in geoms}
    assert kinds == {"ground": rr.Boxes3D, "box": rr.Boxes3D, "ball": rr.Ellipsoids3D, "pill": rr.Capsules3D,
                     "can": rr.Cylinders3D, "egg": rr.Ellipsoids3D, "geom_8": rr.Mesh3D}
    fixed = {g.name for g in geoms if g.fixed}
    assert fixed == {"ground"}
    box = model.geom("box").id
    np.testing.assert_array_equal(recording.geom_color(model, box), [255, 0, 0, 255])  # the material's
    np.testing.assert_array_equal(recording.geom_color(model, model.geom("ball").id), [0, 255, 0, 255])


def test_every_geom_type_makes_a_valid_file(tmp_path):
    model = mujoco.MjModel.from_xml_string(ALL_GEOMS)
    with pytest.warns(UserWarning):
        geoms = recording.scene_from_model(model)
    path = tmp_path / "geoms.rrd"
    rec = recording.open_recording(path)
    steps = np.arange(3)
    qpos = np.tile(model.qpos0, (3, 1))
    qpos[:, 2] += [0.0, 0.5, 1.0]  # the free body rises
    recording.log_scene(rec, model, "world", qpos, [rr.TimeColumn("step", sequence=steps)], geoms)
    recording.close_recording(rec)
    contents = Contents(path)
    assert {f"world/{g.name}" for g in geoms} <= contents.entities
    assert contents.rows["world/egg"] == 3 and contents.rows["world/ground"] == 0
    np.testing.assert_allclose(contents.column("world/egg", "Transform3D:translation")[:, 2], [1.0, 1.5, 2.0])
    verify_with_rerun_cli(path)


def test_geom_poses_match_mujoco():
    model = mujoco.MjModel.from_xml_string(ALL_GEOMS)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    qpos = np.tile(model.qpos0, (5, 1))
    qpos[:, :3] += rng.normal(size=(5, 3))
    quat = rng.normal(size=(5, 4))
    qpos[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    ids = [model.geom("pill").id, model.geom("egg").id]
    positions, rotations = recording.geom_poses(model, qpos, ids)
    for t in range(5):
        data.qpos[:] = qpos[t]
        mujoco.mj_forward(model, data)
        np.testing.assert_allclose(positions[t], data.geom_xpos[ids])
        np.testing.assert_allclose(rotations[t], data.geom_xmat[ids])


# ---- rollout files --------------------------------------------------------------------
def test_rollout_file_has_plots_scene_and_timelines(analytic_file):
    path, rollout, contents = analytic_file
    verify_with_rerun_cli(path)
    geoms = {"floor", "rail", "cart", "pole"}
    for i in range(3):
        for name in ("obs/x", "obs/x_dot", "obs/theta", "obs/theta_dot", "action", "reward"):
            assert contents.rows[f"env/{i}/{name}"] == STEPS, name
            assert contents.timelines[f"env/{i}/{name}"] == {"step", "sim_time"}
        ends = int((rollout.done[:, i] > 0).sum())
        assert ends > 0  # random actions end CartPole episodes within ~20 steps
        for name in ("episode_done", "episode/return", "episode/length"):
            assert contents.rows[f"env/{i}/{name}"] == ends
    # The 3D scene only for the first two envs: static shapes exactly once, moving geoms every step.
    for i in range(2):
        for geom in geoms:
            entity = f"world/env_{i}/{geom}"
            shapes = [cols for cols in contents.static[entity] if not any("Transform3D" in c for c in cols)]
            assert len(shapes) == 1, (entity, contents.static[entity])
        assert contents.rows[f"world/env_{i}/cart"] == contents.rows[f"world/env_{i}/pole"] == STEPS
        assert contents.rows[f"world/env_{i}/floor"] == contents.rows[f"world/env_{i}/rail"] == 0  # fixed: static pose
    assert not any(e.startswith("world/env_2") for e in contents.entities)


def test_episode_returns_are_logged_where_episodes_end(analytic_file):
    _, rollout, contents = analytic_file
    ends = rollout.done[:, 0] > 0
    batches = contents.chunks["env/0/episode/return"]
    logged_steps = np.concatenate([b.column("step").to_numpy() for b in batches])
    np.testing.assert_array_equal(np.sort(logged_steps), np.flatnonzero(ends))
    returns = contents.column("env/0/episode/return", "Scalars:scalars")
    np.testing.assert_allclose(returns, rollout.episode_return[ends, 0])
    np.testing.assert_allclose(contents.column("env/0/episode/length", "Scalars:scalars"), returns)  # reward 1/step


def pole_pose_from_theta(model, x, theta):
    """The pole geom's pose by hand: a rotation about +y by theta at the cart, centre R (0, 0, 0.5) above it."""
    c, s = np.cos(theta), np.sin(theta)
    zero, one = np.zeros_like(theta), np.ones_like(theta)
    rotation = np.stack([np.stack([c, zero, s], -1), np.stack([zero, one, zero], -1), np.stack([-s, zero, c], -1)], -2)
    cart = np.stack([x, zero, zero], -1)
    centre = cart + rotation @ np.array([0.0, 0.0, 0.5])
    geom_frame = np.zeros(9)
    mujoco.mju_quat2Mat(geom_frame, model.geom_quat[model.geom("pole").id])  # the capsule's frame in its body
    return centre, rotation @ geom_frame.reshape(3, 3)


def test_logged_pole_pose_follows_theta(analytic_file):
    _, _, contents = analytic_file
    x = contents.column("env/0/obs/x", "Scalars:scalars")
    theta = contents.column("env/0/obs/theta", "Scalars:scalars")
    translation = contents.column("world/env_0/pole", "Transform3D:translation")
    flat_columns = contents.column("world/env_0/pole", "Transform3D:mat3x3")  # Rerun stores column-major
    rotation = flat_columns.reshape(-1, 3, 3).transpose(0, 2, 1)
    centre, expected_rotation = pole_pose_from_theta(envs.CartPole().scene_model(), x, theta)
    assert np.abs(theta).max() > 0.1  # the pole actually swings in this rollout
    np.testing.assert_allclose(translation, centre, atol=1e-5)
    np.testing.assert_allclose(rotation, expected_rotation, atol=1e-5)


@pytest.mark.slow
def test_both_backends_draw_the_same_scene(tmp_path, analytic_file):
    _, _, analytic = analytic_file
    write_rollout(tmp_path / "mjx.rrd", envs.make("cartpole-mjx"), num_envs=2, steps=50)
    mjx = Contents(tmp_path / "mjx.rrd")
    scene = lambda c: {e: sorted(map(sorted, c.static[e])) for e in c.entities if e.startswith("world/")}  # noqa: E731
    assert scene(mjx) == scene(analytic)
    assert mjx.rows["world/env_0/pole"] == 50


# ---- training and the command line ---------------------------------------------------
@pytest.mark.slow
def test_cli_train_and_rollout_write_readable_files(tmp_path, capsys):
    out, train_file, rollout_file = tmp_path / "run", tmp_path / "train.rrd", tmp_path / "rollout.rrd"
    assert cli_main(["train", "--env", "cartpole", "--out", str(out), "--rerun", str(train_file), "--rerun-every", "1",
                     "--judge-every", "1", *TINY]) == 0
    contents = Contents(train_file)
    for name in ("loss", "mean_q", "epsilon", "eval_return", "env_steps_per_s"):
        assert contents.rows[f"train/seed_0/{name}"] == 2  # one row per chunk
        assert contents.timelines[f"train/seed_0/{name}"] == {"train_step"}
    assert contents.rows["eval/seed_0/train_step"] == 2  # an evaluation rollout after every chunk
    assert contents.rows["eval/seed_0/world/env_0/pole"] == contents.rows["eval/seed_0/env/0/reward"] > 0
    assert len(contents.static["eval/seed_0/world/env_0/pole"]) == 1  # shapes once, not per evaluation
    verify_with_rerun_cli(train_file)

    assert cli_main(["rollout", "--checkpoint", str(out), "--env", "cartpole-mjx", "--num-envs", "2",
                     "--episodes", "1", "--rerun", str(rollout_file)]) == 0
    assert f"to {rollout_file}" in capsys.readouterr().out
    contents = Contents(rollout_file)
    assert {"env/0/reward", "env/1/reward", "world/env_0/pole"} <= contents.entities
    assert not any(e.startswith("world/env_1") for e in contents.entities)  # --scene-envs 1
    assert contents.rows["env/0/episode/return"] >= 1 and contents.rows["env/1/episode/return"] >= 1


@pytest.mark.slow
def test_the_console_scripts_fast_exit_leaves_a_whole_rerun_file(tmp_path):
    """Training as the `mjxsuite` script runs it, in a process of its own: the file its fast exit
    (`agents.console.exit_now`) leaves holds every chunk's rows and passes `rerun rrd verify`."""
    out, train_file = tmp_path / "run", tmp_path / "train.rrd"
    done = subprocess.run([*processes.MJXSUITE, "train", "--env", "cartpole", "--out", str(out),
                           "--rerun", str(train_file), "--rerun-every", "1", "--judge-every", "1", *TINY],
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    contents = Contents(train_file)
    assert contents.rows["train/seed_0/loss"] == 2 and contents.rows["eval/seed_0/train_step"] == 2
    assert json.loads((out / "eval.json").read_text())["mean_return"]
    verify_with_rerun_cli(train_file)


def test_training_logger_curves_per_seed_and_eval_episodes_every_n_chunks(tmp_path):
    config = DQNConfig(hidden=(16,))
    dqn = DQN(config, envs.make("cartpole"))
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    params = jax.vmap(lambda k: dqn.network.init(k, jnp.zeros((1, 4))))(keys)
    _, episode = jax.vmap(lambda p, k: dqn.evaluate(p, k, 4, record=True))(params, keys)
    lengths = np.asarray(episode.length)
    assert (lengths > 0).all()
    path = tmp_path / "train.rrd"
    logger = agent_recording.TrainingLogger(path, "cartpole", config, seeds=2, rollout_every=2)
    try:
        for index in range(3):
            record = {"env_steps": [1000 * (index + 1)] * 2, "loss": [1.0, 2.0], "q": [3.0, 4.0], "epsilon": [0.5, 0.5],
                      "eval_return": [10.0, 20.0], "train_return": [9.0, 19.0], "steps_per_s": 5000.0,
                      "eval_episode": episode}
            logger(index, None, record)
    finally:
        logger.close()
    contents = Contents(path)
    for seed in (0, 1):
        assert contents.rows[f"train/seed_{seed}/loss"] == 3
        returns = contents.column(f"train/seed_{seed}/eval_return", "Scalars:scalars", index="train_step")
        np.testing.assert_allclose(returns, [10.0 * (seed + 1)] * 3)
        assert contents.rows[f"eval/seed_{seed}/train_step"] == 2  # chunks 0 and 2
        root = f"eval/seed_{seed}"
        # The recorded episode, padding cut off, logged twice; its return at its last step.
        assert contents.rows[f"{root}/env/0/reward"] == contents.rows[f"{root}/world/env_0/pole"] == 2 * lengths[seed]
        np.testing.assert_allclose(contents.column(f"{root}/env/0/episode/return", "Scalars:scalars"),
                                   [float(lengths[seed])] * 2)  # CartPole: reward 1 per step
    assert contents.rows["train/env_steps_per_s"] == 3


@pytest.mark.slow  # issue #29: out of the default run (make test <= 8 min); a training run of its own (~17 s); the CLI's train + rollout recordings stay
def test_recorded_eval_episode_replays_the_greedy_policy():
    """The episode `evaluate(record=True)` returns is the first env's trajectory, step for step."""
    env = envs.make("cartpole-mjx")
    dqn = DQN(DQNConfig(hidden=(16,)), env)
    params = dqn.network.init(jax.random.PRNGKey(1), jnp.zeros((1, 4)))
    evaluate = jax.jit(lambda p, key: dqn.evaluate(p, key, 3, record=True))  # jitted: MJX op by op is slow
    returns, episode = evaluate(params, jax.random.PRNGKey(2))
    length = int(episode.length)
    assert length == int(returns[0])  # reward 1 per step
    state = jax.jit(envs.VmapWrapper(env, 3).reset)(jax.random.PRNGKey(2))
    state = jax.tree.map(lambda x: x[0], state)
    step = jax.jit(env.step)
    for t in range(length):
        np.testing.assert_allclose(np.asarray(episode.obs[t]), np.asarray(state.obs), atol=1e-6)
        np.testing.assert_allclose(np.asarray(episode.scene_qpos[t]), np.asarray(state.pipeline_state.qpos), atol=1e-6)
        action = int(jnp.argmax(dqn.q_values(params, state.obs)))
        assert int(episode.action[t]) == action
        state = step(state, jnp.int32(action))
    assert float(state.done) == 1.0


def test_cli_rollout_with_random_policy_and_fixed_steps(tmp_path):
    path = tmp_path / "random.rrd"
    assert cli_main(["rollout", "--env", "cartpole", "--steps", "40", "--scene-envs", "2", "--num-envs", "2",
                     "--rerun", str(path)]) == 0
    contents = Contents(path)
    assert contents.rows["env/1/obs/theta"] == contents.rows["world/env_1/pole"] == 40


@pytest.fixture
def no_training(monkeypatch):
    """Fail the test if training or a rollout starts."""
    import agents.run

    def boom(*args, **kwargs):
        raise AssertionError("training started before the output path was checked")

    monkeypatch.setattr(agents.run, "train_run", boom)
    monkeypatch.setattr(recording, "collect_rollout", boom)
    monkeypatch.setattr(recording, "rollout_program", boom)


def test_bad_rerun_paths_fail_before_training(tmp_path, capsys, no_training):
    blocker = tmp_path / "file"
    blocker.write_text("")
    existing = tmp_path / "old.rrd"
    existing.write_bytes(b"keep me")
    cases = {
        str(tmp_path): "is a directory",
        str(blocker / "run.rrd"): "cannot write",  # parent is a file
        "/proc/mjxsuite-test.rrd": "cannot write",  # /proc refuses new entries even to root
        str(existing): "already exists; pass --overwrite",
    }
    for path, message in cases.items():
        for command in (["train", "--env", "cartpole", *TINY], ["rollout", "--env", "cartpole"]):
            assert cli_main([*command, "--rerun", path]) == 2, (command, path)
            assert message in capsys.readouterr().err, (command, path)
    assert existing.read_bytes() == b"keep me"


def test_overwrite_replaces_an_existing_file(tmp_path):
    path = tmp_path / "old.rrd"
    path.write_bytes(b"old")
    assert cli_main(["rollout", "--env", "cartpole", "--steps", "20", "--rerun", str(path), "--overwrite"]) == 0
    assert Contents(path).rows["env/0/reward"] == 20


def test_interrupted_training_leaves_a_readable_file(tmp_path, monkeypatch):
    path = tmp_path / "interrupted.rrd"
    log_chunk = agent_recording.TrainingLogger.__call__

    def interrupt_after_first_chunk(self, index, train_state, record):
        log_chunk(self, index, train_state, record)
        raise KeyboardInterrupt

    monkeypatch.setattr(agent_recording.TrainingLogger, "__call__", interrupt_after_first_chunk)
    out = tmp_path / "run"
    assert cli_main(["train", "--env", "cartpole", "--out", str(out), "--rerun", str(path), "--judge-every", "1", *TINY]) == 130
    # Ctrl-C keeps the checkpoint too: one chunk done, resumable.
    assert json.loads((out / "progress.json").read_text())["chunks_done"] == 1
    assert (out / "train_state.ckpt").is_file()
    contents = Contents(path)
    assert contents.rows["train/seed_0/loss"] == 1
    assert contents.rows["eval/seed_0/env/0/reward"] > 0
    verify_with_rerun_cli(path)


@pytest.mark.slow  # one env of each of the suite's 16 domains built (MJX's model put on the device)
def test_every_dm_control_domain_draws_its_scene_where_c_mujoco_puts_its_geoms(tmp_path):
    """Each DeepMind Control Suite domain's model (the task's own, after its edits) makes a Rerun
    scene with every geom type drawn, and the file holds each moving geom where C MuJoCo's
    kinematics puts it along a random-action run."""
    pytest.importorskip("dm_control")
    first_of_each = {}  # domain -> its first task's model
    for name, *_ in envs.TASKS:
        if name.startswith("dmc-"):
            task = envs.make(name).unwrapped
            first_of_each.setdefault(task.domain, task.mj_model)
    assert len(first_of_each) == 16
    rng = np.random.default_rng(0)
    for domain, model in first_of_each.items():
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a geom type the scene cannot draw warns
            geoms = recording.scene_from_model(model)
        data, qpos, xpos = mujoco.MjData(model), [], []
        for _ in range(4):
            data.ctrl[:] = rng.uniform(-1.0, 1.0, model.nu)
            mujoco.mj_step(model, data, 5)
            mujoco.mj_kinematics(model, data)  # a step leaves geom_xpos of the state before its integration
            qpos.append(data.qpos.copy()), xpos.append(data.geom_xpos.copy())
        path = tmp_path / f"{domain}.rrd"
        rec = recording.open_recording(path)
        recording.log_scene(rec, model, "world", np.array(qpos), [rr.TimeColumn("step", sequence=np.arange(4))], geoms)
        recording.close_recording(rec)
        contents = Contents(path)
        assert {f"world/{g.name}" for g in geoms} <= contents.entities, domain
        moving = [g for g in geoms if not g.fixed]
        assert moving, domain
        for g in moving:
            np.testing.assert_allclose(contents.column(f"world/{g.name}", "Transform3D:translation"),
                                       np.array(xpos)[:, g.geom_id], atol=1e-5, err_msg=f"{domain} {g.name}")
