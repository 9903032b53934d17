"""JAX's persistent compilation cache, on by default for the `mjxsuite` command.

An MJX training chunk takes seconds to compile on a CPU; with the cache a second
`mjxsuite train` or `rollout` loads the compiled program from disk instead.

Where and how it is switched: `envs.compile_cache` (`~/.cache/mjxsuite/jax`; the environment
variable `MJXSUITE_COMPILE_CACHE`: `0`/`off`/`false` turns it off, a path puts it there), which
Gymnasium's entry points use too; or pass `--no-compile-cache` to a command. A cache directory
set through JAX itself (`JAX_COMPILATION_CACHE_DIR`) wins. Delete the directory to clear it.

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
from envs import compile_cache
from envs.compile_cache import ENV_VAR, configured_dir, default_dir  # noqa: F401  (kept as this module's names)

def enable(path: str | os.PathLike | None = None) -> Path | None:
    """Turn the persistent cache on (call before the first compile; `envs.compile_cache.enable`,
    which Gymnasium's entry points call too) and the export cache in a subdirectory; returns the
    directory, or None when `MJXSUITE_COMPILE_CACHE` turns it off (a given `path` overrides that)."""
    directory = compile_cache.enable(path)
    if directory is not None:
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
