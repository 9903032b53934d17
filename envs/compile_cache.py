"""JAX's persistent compilation cache: where it lives and how it is switched, for every entry
point that turns it on (the `mjxsuite` command through `agents.jax_compile_cache`, and
Gymnasium's `gymnasium.make("mjxsuite/...")` / `make_vec` through `envs.interop.gymnasium`), so a
new process loads its compiled programs from disk instead of compiling them again.

Where: `$XDG_CACHE_HOME/mjxsuite/jax`, i.e. `~/.cache/mjxsuite/jax` by default. Switch it with
the environment variable `MJXSUITE_COMPILE_CACHE`: `0`/`off`/`false` turns it off, a path puts it
there. A cache directory set through JAX itself (`JAX_COMPILATION_CACHE_DIR`) wins, and a process
that turned JAX's cache off (`jax_enable_compilation_cache` False) keeps it off.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

# XLA options of the proofs' own programs (`envs.interop.gymnasium_equality.transitions`, `envs.interop.dm_control.
# transitions` and `steps_from`): none, XLA's defaults, as a training's programs. A proof's bound holds for the program
# it compiled; tests/conftest.py, which builds the tests' other programs with a cheaper backend, sets users' here.
PROOF_COMPILER_OPTIONS: dict[str, Any] = {}

ENV_VAR = "MJXSUITE_COMPILE_CACHE"
_OFF = ("0", "off", "false", "no")


def default_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "mjxsuite" / "jax"


def configured_dir() -> Path | None:
    """The directory `enable` would use: None when the environment variable turns the cache off."""
    setting = os.environ.get(ENV_VAR, "").strip()
    if setting.lower() in _OFF:
        return None
    if setting and setting.lower() not in ("1", "on", "true", "yes"):
        return Path(setting).expanduser()
    return default_dir()


def enable(path: str | os.PathLike | None = None) -> Path | None:
    """Turn JAX's persistent cache on (before the process's first compile); returns its directory,
    or None when `MJXSUITE_COMPILE_CACHE` turns it off (a given `path` overrides that)."""
    import jax

    already = jax.config.jax_compilation_cache_dir
    if already:  # set through JAX's own flag or environment variable: respect it
        directory = Path(already)
    else:
        directory = Path(path).expanduser() if path is not None else configured_dir()
        if directory is None:
            return None
        directory.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(directory))
    # JAX's defaults skip programs that compile in under a second; ours are many
    # such programs (init, evaluation, small chunks, an env's step), and they add up at startup.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    return directory


def enable_unless_off() -> Path | None:
    """`enable()` unless this process turned JAX's cache off (`jax_enable_compilation_cache` False,
    as `agents.jax_compile_cache.disable` and `--no-compile-cache` leave it): what Gymnasium's
    entry points call, once per env they make."""
    import jax

    return enable() if jax.config.jax_enable_compilation_cache else None
