"""Start-up: DQN on an analytic task and `mjxsuite --help` never import mujoco (0.19 s on an H100
machine, most of it loading GLFW), mujoco.mjx (which loads MuJoCo Warp and Warp, about 2.5 s) nor
Brax; the public names that need them load on first use."""

import subprocess
import sys
from pathlib import Path

import agents
import envs

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("mujoco", "warp", "brax")


def test_the_analytic_dqn_path_imports_neither_mujoco_nor_brax():
    """Also: `envs.spec` of every built-in task (MuJoCo Warp's too) imports the task's module and
    builds it without its device state: no mujoco.mjx, no Warp, no JAX backend (the parent of
    per-GPU processes asks it before it starts them)."""
    script = (
        "import sys, agents.cli, envs\n"
        "from jax._src import xla_bridge\n"
        "agents.cli.build_parser().format_help()\n"
        "envs.make('cartpole'), envs.options('acrobot'), envs.names()\n"
        f"print(sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r} or m.startswith({HEAVY!r})))\n"
        "specs = [envs.spec(name) for name in envs.names()]\n"
        "assert envs.spec('hopper', impl='warp', nconmax=64).action_size == 3\n"
        "print(sorted(m for m in sys.modules if m.startswith(('mujoco.mjx', 'warp'))), xla_bridge.backends_are_initialized())\n"
    )
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, check=True)
    before_spec, after_spec = out.stdout.strip().splitlines()
    assert before_spec == "[]", f"imported at start-up: {before_spec}"
    assert after_spec == "[] False", f"the specs loaded MJX or a device: {after_spec}"


def test_every_public_name_resolves():
    for package in (envs, agents):
        missing = [name for name in package.__all__ if getattr(package, name, None) is None]
        assert not missing, f"{package.__name__} lacks {missing}"
    assert callable(envs.randomize) and envs.mjx_env.MjxEnv is envs.MjxEnv  # the function, not the submodule
