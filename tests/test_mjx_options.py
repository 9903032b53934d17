"""`opt` (MuJoCo's solver options) and MuJoCo Warp's buffer sizes as envs.make overrides: they reach
the MjModel and the mjx.Model of every MJX task, the physics follows C MuJoCo with the same options,
no `opt` steps exactly as plain MJX, bad values are refused before anything compiles, and the
command line's `--env-opt opt.FIELD=VALUE` is saved with a run and reused."""

import json

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

import envs
from agents import checkpoint
from agents.run import load_agent
from benchmarks.cli import main as cli_main

# Slow run: every task recompiled with other solver options (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

OPT = {"iterations": 3, "ls_iterations": 5, "solver": "cg", "tolerance": 1e-6, "impratio": 2}


def mjx_task_names():
    return [name for name in envs.names() if "opt" in envs.options(name)]


def test_every_mjx_task_takes_opt():
    assert {"cartpole-mjx", "acrobot-mjx", "pendulum-mjx"} <= set(mjx_task_names())
    for name in mjx_task_names():
        task = envs.make(name, opt=OPT).unwrapped
        for model in (task.mj_model, task.mjx_model):
            assert (int(model.opt.iterations), int(model.opt.ls_iterations)) == (3, 5), name
            assert int(model.opt.solver) == mujoco.mjtSolver.mjSOL_CG, name
            assert float(model.opt.tolerance) == pytest.approx(1e-6) and float(model.opt.impratio) == 2.0, name
        plain = envs.make(name).unwrapped  # the options went into a copy: a fresh env has the MJCF's
        assert plain.mj_model.opt.iterations != 3 and plain.mjx_model.opt.iterations != 3, name
        assert task.opt == {**OPT, "solver": int(mujoco.mjtSolver.mjSOL_CG)}


def rollout(env, steps=40, num_envs=3):
    """qpos and qvel after each of `steps` steps of fixed actions from `num_envs` starts."""
    actions = jnp.arange(steps * num_envs).reshape(steps, num_envs) % max(env.num_actions or 2, 2)

    def run(keys):
        def body(state, action):
            state = jax.vmap(env.step)(state, action)
            return state, jnp.concatenate([state.pipeline_state.qpos, state.pipeline_state.qvel], -1)

        return jax.lax.scan(body, jax.vmap(env.reset)(keys), actions)

    return jax.jit(run)(jax.random.split(jax.random.PRNGKey(0), num_envs))


@pytest.mark.slow
def test_no_opt_steps_exactly_as_plain_mjx():
    """Without `opt` (or with the MJCF's own values) the env's physics is bit for bit mjx.step on the
    task's MJCF model, as before `opt` existed."""
    env = envs.make("cartpole-mjx")
    task = env.unwrapped
    states, traj = rollout(env, steps=30, num_envs=1)
    same = rollout(envs.make("cartpole-mjx", opt={"iterations": int(task.mj_model.opt.iterations),
                                                  "integrator": "Euler"}), steps=30, num_envs=1)[1]
    np.testing.assert_array_equal(np.asarray(same), np.asarray(traj))

    model = mjx.put_model(envs.CartPoleMjx().mj_model)  # an independent path: the MJCF, mjx.step, the bin table
    data = task.reset(jax.random.split(jax.random.PRNGKey(0), 1)[0]).pipeline_state
    step = jax.jit(lambda d, ctrl: mjx.step(model, d.replace(ctrl=ctrl)))
    for t in range(30):
        data = step(data, task._bin_table[(t * 1) % 2])
        np.testing.assert_array_equal(np.concatenate([data.qpos, data.qvel]), np.asarray(traj[t, 0]))


def test_opt_changes_the_physics_as_c_mujoco_does():
    """cartpole-mjx with a halved timestep and RK4 in place of the MJCF's Euler follows C MuJoCo given
    the same options."""
    opt = {"timestep": 0.01, "integrator": "RK4"}
    env = envs.make("cartpole-mjx", opt=opt)
    assert env.unwrapped.dt == pytest.approx(0.01)
    _, traj = rollout(env, steps=40, num_envs=1)
    reference = envs.CartPoleMjx().mj_model
    reference.opt.timestep, reference.opt.integrator = 0.01, mujoco.mjtIntegrator.mjINT_RK4
    start = env.unwrapped.reset(jax.random.split(jax.random.PRNGKey(0), 1)[0]).pipeline_state
    data = mujoco.MjData(reference)
    data.qpos[:], data.qvel[:] = np.asarray(start.qpos), np.asarray(start.qvel)
    for t in range(40):
        data.ctrl[:] = np.asarray(env.unwrapped._bin_table[t % 2])
        mujoco.mj_step(reference, data)
        np.testing.assert_allclose(np.asarray(traj[t, 0]), np.concatenate([data.qpos, data.qvel]), atol=2e-5)
    euler = rollout(envs.make("cartpole-mjx"), steps=40, num_envs=1)[1]
    assert np.abs(np.asarray(euler) - np.asarray(traj)).max() > 1e-2  # the option made a difference


@pytest.mark.parametrize("overrides, message", [
    ({"opt": {"iteration": 4}}, r"unknown opt field\(s\) \['iteration'\]; valid fields .*'iterations'"),
    ({"opt": {"iterations": 2.5}}, r"opt.iterations must be an integer >= 1, got 2.5"),
    ({"opt": {"iterations": "4"}}, r"opt.iterations must be an integer"),
    ({"opt": {"timestep": -0.01}}, r"opt.timestep must be a finite number > 0"),
    ({"opt": {"solver": "fast"}}, r"opt.solver must be one of \['cg', 'newton', 'pgs'\]"),
    ({"opt": {"gravity": [0, -9.8]}}, r"opt.gravity must be 3 finite numbers"),
    ({"opt": 4}, r"opt must be a mapping"),
    ({"nconmax": 0, "impl": "warp"}, r"nconmax must be an integer >= 1, got 0"),
])
def test_bad_options_are_refused_before_anything_compiles(overrides, message, monkeypatch):
    monkeypatch.setattr(envs.CartPoleMjx, "__init__", lambda self: pytest.fail("the task was built"))
    with pytest.raises(ValueError, match=message):
        envs.make("cartpole-mjx", **overrides)


def test_checked_opt_checks_again_to_itself():
    """An enum given by name becomes its integer, which a second check (the env's, after the CLI's) keeps."""
    checked = envs.mjx_options.check_opt({"integrator": "euler", "cone": "elliptic", "iterations": 4})
    assert checked == {"integrator": 0, "cone": 1, "iterations": 4}
    assert envs.mjx_options.check_opt(checked) == checked
    with pytest.raises(ValueError, match="opt.integrator must be one of"):
        envs.mjx_options.check_opt({"integrator": 7})


def test_njmax_needs_warp():
    with pytest.raises(ValueError, match=r"\['njmax'\] size MuJoCo Warp's buffers; they need impl='warp'"):
        envs.make("cartpole-mjx", njmax=64)


def test_analytic_tasks_have_no_opt():
    with pytest.raises(ValueError, match="unknown option"):
        envs.make("cartpole", opt={"iterations": 4})


@pytest.mark.slow
def test_opt_on_the_command_line_is_saved_and_reused(tmp_path, capsys):
    out = tmp_path / "run"
    small = ["--steps", "200", "--eval_every", "100", "--learning_starts", "64", "--eval-episodes", "2", "--hidden", "8"]
    assert cli_main(["train", "--env", "cartpole-mjx", "--env-opt", "opt.iterations=4", "--env-opt", "opt.solver=CG",
                     "--env-opt", "opt.gravity=0,0,-9.8", "--out", str(out), *small]) == 0
    saved = checkpoint.load_config(out).env_options
    assert saved == {"opt": {"iterations": 4, "solver": "CG", "gravity": [0.0, 0.0, -9.8]}}
    assert json.loads((out / "config.json").read_text())["env_options"] == saved
    task = load_agent(out)[1].unwrapped  # what eval, rollout and --resume build
    assert int(task.mjx_model.opt.iterations) == 4 and int(task.mj_model.opt.solver) == mujoco.mjtSolver.mjSOL_CG
    capsys.readouterr()
    assert cli_main(["eval", "--checkpoint", str(out), "--episodes", "2", "--env-opt", "opt.ls_iterations=6"]) == 0
    judged = json.loads(capsys.readouterr().out.splitlines()[-1])["env_options"]
    assert judged == {"opt": {**saved["opt"], "ls_iterations": 6}}  # merged field by field
    assert cli_main(["train", "--env", "cartpole-mjx", "--env-opt", "opt.iterations=many"]) == 2
    assert cli_main(["train", "--env", "cartpole-mjx", "--env-opt", "opt.solvr=CG"]) == 2
    assert cli_main(["train", "--env", "cartpole-mjx", "--env-opt", "opt=4"]) == 2


@pytest.mark.skipif(any(d.platform == "gpu" for d in jax.devices()), reason="a GPU machine may run Warp")
@pytest.mark.parametrize("agent", ["dqn", "ppo"])
def test_impl_warp_without_a_gpu_is_a_clear_error_not_a_traceback(agent, tmp_path, capsys):
    env = "cartpole-mjx" if agent == "dqn" else "pendulum-mjx"
    assert cli_main(["train", "--env", env, "--agent", agent, "--impl", "warp", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "mjxsuite: --impl warp: impl='warp' steps MJX with MuJoCo Warp" in err and "Traceback" not in err
    assert not (tmp_path / "run").exists()


def test_warp_logs_warnings_only_unless_the_user_set_its_level(monkeypatch):
    """At Warp's default log level (info) it prints a line for every kernel module it loads:
    `quiet_warp` (run by every impl="warp" env) raises it to warnings, and keeps a level the
    user chose. Checked on a stand-in module: warp-lang is optional."""
    import sys
    import types

    from envs import mjx_warp

    warp = types.SimpleNamespace(LOG_DEBUG=10, LOG_INFO=20, LOG_WARNING=30, config=types.SimpleNamespace(log_level=20))
    monkeypatch.setitem(sys.modules, "warp", warp)
    mjx_warp.quiet_warp()
    assert warp.config.log_level == warp.LOG_WARNING
    warp.config.log_level = warp.LOG_DEBUG
    mjx_warp.quiet_warp()
    assert warp.config.log_level == warp.LOG_DEBUG
