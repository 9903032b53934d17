"""JAX's persistent compilation cache, on by default for the `mjxsuite` command.

An MJX training chunk takes seconds to compile on a CPU; with the cache a second
`mjxsuite train` or `rollout` loads the compiled program from disk instead.

Where: `$XDG_CACHE_HOME/mjxsuite/jax`, i.e. `~/.cache/mjxsuite/jax` by default.
Switch it with the environment variable `MJXSUITE_COMPILE_CACHE`: `0`/`off`/`false`
turns it off, a path puts it there; or pass `--no-compile-cache` to a command.
A cache directory set through JAX itself (`JAX_COMPILATION_CACHE_DIR`) wins.
Delete the directory to clear it.

`enable()` also turns on `agents.traced_programs` in a subdirectory, which keeps the traced
programs of `train`, `eval` and `rollout`, so a second run skips tracing too; `disable()`
turns both off.

Python users call `enable()` themselves (importing the suite changes no global state).
`CompileCounter` counts traces, compiles and cache hits, to check that nothing
recompiles between training chunks.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Self

import jax
from jax import monitoring

from agents import traced_programs

ENV_VAR = "MJXSUITE_COMPILE_CACHE"
_OFF = ("0", "off", "false", "no")


def default_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "mjxsuite" / "jax"


def configured_dir() -> Path | None:
    """The directory `enable()` would use: None when the environment variable turns the cache off."""
    setting = os.environ.get(ENV_VAR, "").strip()
    if setting.lower() in _OFF:
        return None
    if setting and setting.lower() not in ("1", "on", "true", "yes"):
        return Path(setting).expanduser()
    return default_dir()


def enable(path: str | os.PathLike | None = None) -> Path | None:
    """Turn the persistent cache on (call before the first compile); returns its directory,
    or None when `MJXSUITE_COMPILE_CACHE` turns it off (a given `path` overrides that)."""
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
    # such programs (init, evaluation, small chunks), and they add up at startup.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    traced_programs.enable(directory / traced_programs.SUBDIR)
    return directory


def disable() -> None:
    """Turn the persistent cache (and the export cache) off for this process (before the first compile)."""
    jax.config.update("jax_compilation_cache_dir", None)
    jax.config.update("jax_enable_compilation_cache", False)
    traced_programs.disable()


class CompileCounter:
    """Counts, while active, the functions traced to jaxprs, the programs handed to
    the compiler (`compiles`, cache loads included) and the persistent-cache hits.

        with CompileCounter() as counter:
            ...
        counter.traces, counter.compiles, counter.cache_hits
    """

    _TRACE = "/jax/core/compile/jaxpr_trace_duration"
    _COMPILE = "/jax/core/compile/backend_compile_duration"
    _HIT = "/jax/compilation_cache/cache_hits"

    def __init__(self):
        self.traces = self.compiles = self.cache_hits = 0
        self.compile_s = 0.0
        self.traced: list[str] = []  # the functions traced and the programs compiled, by name, in order
        self.compiled: list[str] = []

    def _on_duration(self, event: str, seconds: float, fun_name: str = "", **_) -> None:
        if event == self._TRACE:
            self.traces += 1
            self.traced.append(fun_name)
        elif event == self._COMPILE:
            self.compiles += 1
            self.compile_s += seconds
            self.compiled.append(fun_name)

    def _on_event(self, event: str, **_) -> None:
        if event == self._HIT:
            self.cache_hits += 1

    def __enter__(self) -> Self:
        monitoring.register_event_duration_secs_listener(self._on_duration)
        monitoring.register_event_listener(self._on_event)
        return self

    def __exit__(self, *exc) -> None:
        monitoring.unregister_event_duration_listener(self._on_duration)
        monitoring.unregister_event_listener(self._on_event)
