"""JAX's persistent compilation cache (`agents.jax_compile_cache`): where it lives, how it is
turned off, a second process loading from it, and no retracing between training chunks."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from agents.cli import main as cli_main
from agents.dqn import DQNConfig
from agents.jax_compile_cache import ENV_VAR, CompileCounter, configured_dir, default_dir
from agents.run import train_run

# Slow run: processes that share a compile cache (the fast run is `make test`'s five minutes; docs/claims.md).
pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[1]


def test_compile_cache_location_and_opt_out(monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    monkeypatch.delenv("MJXSUITE_COMPILE_CACHE", raising=False)
    assert default_dir() == tmp_path / "xdg" / "mjxsuite" / "jax" == configured_dir()
    monkeypatch.setenv("MJXSUITE_COMPILE_CACHE", "0")
    assert configured_dir() is None
    monkeypatch.setenv("MJXSUITE_COMPILE_CACHE", str(tmp_path / "elsewhere"))
    assert configured_dir() == tmp_path / "elsewhere"


_CACHED_PROGRAM = """
import sys
from agents import jax_compile_cache
print(jax_compile_cache.enable())
import jax, numpy
with jax_compile_cache.CompileCounter() as counter:
    jax.block_until_ready(jax.jit(lambda x: jax.numpy.sin(x) * 2 + 1)(numpy.arange(3.0)))
print(counter.compiles, counter.cache_hits)
"""


def _run_cached(env_vars: dict) -> list[str]:
    environ = {**os.environ, "JAX_PLATFORMS": "cpu", **env_vars}
    environ.pop("JAX_COMPILATION_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-c", _CACHED_PROGRAM], env=environ, cwd=ROOT, capture_output=True,
                          text=True, check=True)
    return done.stdout.split("\n")


def test_a_second_process_loads_small_programs_from_the_cache(tmp_path):
    cache = tmp_path / "cache"
    first = _run_cached({"MJXSUITE_COMPILE_CACHE": str(cache)})
    compiles, hits = map(int, first[1].split())
    assert first[0] == str(cache) and compiles >= 1 and hits == 0
    assert any(cache.iterdir())  # written, although the program compiles in far less than a second
    second = _run_cached({"MJXSUITE_COMPILE_CACHE": str(cache)})
    assert second[1] == f"{compiles} {compiles}"  # every program loaded from the cache
    off = _run_cached({"MJXSUITE_COMPILE_CACHE": "0", "XDG_CACHE_HOME": str(tmp_path / "unused")})
    assert off[0] == "None" and off[1] == f"{compiles} 0" and not (tmp_path / "unused").exists()


def test_no_compile_cache_flag_is_accepted_by_every_command(monkeypatch, tmp_path):
    from agents import cli

    calls = []
    monkeypatch.setattr(cli, "_use_compile_cache", lambda args: calls.append(args.no_compile_cache))
    with pytest.raises(SystemExit, match="unknown env"):
        cli_main(["rollout", "--no-compile-cache", "--env", "no-such-env", "--rerun", str(tmp_path / "x.rrd")])
    with pytest.raises(SystemExit, match="unknown env"):
        cli_main(["train", "--no-compile-cache", "--env", "no-such-env"])
    assert cli_main(["eval", "--checkpoint", str(tmp_path / "missing")]) != 0
    assert calls == [True, True, False]


def test_training_chunks_compile_once(tmp_path):
    """Nothing is traced or compiled again after the first chunk, Rerun logging included; the
    final evaluation's program, compiling on another thread meanwhile, compiles once."""
    pytest.importorskip("rerun")
    from agents.training_log import TrainingLogger

    config = DQNConfig(total_steps=400, learning_starts=64, batch_size=32, buffer_size=256, eval_every=100,
                       eval_episodes=4, hidden=(16,))
    logger = TrainingLogger(tmp_path / "train.rrd", "cartpole", config)
    counts = []

    def on_chunk(index, train_state, record):
        logger(index, train_state, record)
        counts.append((len(counter.traced), len(counter.compiled)))

    with CompileCounter() as counter:
        try:
            train_run("cartpole", config, progress=False, on_chunk=on_chunk)
        finally:
            logger.close()
    assert len(counts) == config.num_chunks == 4
    (traced, compiled), (last_traced, last_compiled) = counts[0], counts[-1]
    between = counter.traced[traced:last_traced] + counter.compiled[compiled:last_compiled]
    assert all("evaluate" in name for name in between), between  # the final evaluation's, on its own thread
    # one program for the chunk's training steps, one for its evaluation (the judge)
    assert counter.compiled.count("jit(evaluate)") == 1 and counter.compiled.count("jit(single)") == 2
    assert counter.compiles == len(counter.compiled) >= 4  # the counter does see compiles (init, chunk's two, final evaluation)


GYMNASIUM_PROCESS = """
import gymnasium, jax
vec = gymnasium.make_vec("mjxsuite/CartPole-v1", num_envs=2)
vec.reset(seed=0)
vec.step(vec.action_space.sample())
print(jax.config.jax_compilation_cache_dir)
"""


@pytest.mark.parametrize("setting", ["a path", "0"])
def test_gymnasiums_entry_points_turn_the_compile_cache_on_as_the_command_does(tmp_path, setting):
    """Case 94: a Gymnasium env made in a new process compiled from scratch every time; its entry
    points now turn on the persistent cache (`envs.compile_cache`), with the command's switch."""
    cache = tmp_path / "cache"
    environ = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    environ[ENV_VAR] = str(cache) if setting == "a path" else setting
    done = subprocess.run([sys.executable, "-c", GYMNASIUM_PROCESS], env=environ, cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    if setting == "a path":
        assert done.stdout.split()[-1] == str(cache) and any(cache.iterdir())  # the env's programs were written
    else:
        assert done.stdout.split()[-1] == "None" and not cache.exists()
