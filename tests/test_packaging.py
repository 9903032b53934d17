"""A non-editable install finds its MJCF assets inside the package, not in the checkout."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # a pip install of the whole project (make test-slow, which CI runs)
def test_non_editable_install_ships_the_assets(tmp_path):
    target = tmp_path / "site"
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target", str(target), str(ROOT)],
                   check=True, capture_output=True, text=True)
    assert (target / "envs" / "assets" / "cartpole.xml").is_file()
    assert (target / "envs" / "tasks" / "cartpole_mjx.py").is_file() and (target / "benchmarks" / "cli.py").is_file()
    script = (
        "import envs, envs.assets as a, jax; "
        "assert envs.__file__.startswith(%r), envs.__file__; "
        "print(a.asset_path('cartpole.xml')); "
        "env = envs.make('cartpole-mjx'); env.step(env.reset(jax.random.PRNGKey(0)), 1)"
    ) % str(target)
    out = subprocess.run([sys.executable, "-c", script], cwd=tmp_path, env={"PYTHONPATH": str(target), "PATH": ""},
                         check=True, capture_output=True, text=True).stdout
    assert out.strip() == str(target / "envs" / "assets" / "cartpole.xml")
    # The console script finds `bench` through the installed entry point, not through an import of benchmarks.
    out = subprocess.run([sys.executable, "-c", "from agents.console import more_commands; print(sorted(more_commands()))"],
                         cwd=tmp_path, env={"PYTHONPATH": str(target), "PATH": ""}, check=True, capture_output=True,
                         text=True).stdout
    assert out.strip() == "['bench']"


def test_the_console_script_adds_the_benchmarks_command():
    """`mjxsuite bench` comes from the benchmarks' `mjxsuite.commands` entry point (agents never import benchmarks)."""
    from agents.console import more_commands

    assert list(more_commands()) == ["bench"]


def test_importing_the_suite_starts_no_jax_backend():
    """Users set JAX's config (platform, x64) after importing us; an import that touched a
    device would have fixed it already, and slowed every start."""
    script = ("import jax._src.xla_bridge as xb, envs, agents.run, agents.cli, benchmarks.cli; "
              "print(xb.backends_are_initialized())")
    out = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", out.stderr
