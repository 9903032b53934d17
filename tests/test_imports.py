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
    script = (
        "import sys, agents.cli, envs\n"
        "agents.cli.build_parser().format_help()\n"
        "envs.make('cartpole'), envs.options('acrobot'), envs.names()\n"
        f"print(sorted(m for m in sys.modules if m.split('.')[0] in {HEAVY!r} or m.startswith({HEAVY!r})))\n"
    )
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", f"imported at start-up: {out.stdout.strip()}"


def test_every_public_name_resolves():
    for package in (envs, agents):
        missing = [name for name in package.__all__ if getattr(package, name, None) is None]
        assert not missing, f"{package.__name__} lacks {missing}"
    assert callable(envs.randomize) and envs.mjx_env.MjxEnv is envs.MjxEnv  # the function, not the submodule
