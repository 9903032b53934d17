"""JAX's persistent compilation cache, on by default for the `mjxsuite` command (`--no-compile-cache`
or `MJXSUITE_COMPILE_CACHE`, `envs.compile_cache`, turn it off), with `agents.traced_programs` in a
subdirectory, so a second run skips compiling and tracing. Python users call `enable()` themselves.
`CompileCounter` counts traces, compiles and cache hits.
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
    """Turn the persistent and export caches on, before the first compile: the directory, or None if off."""
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
    """Counts, inside `with CompileCounter() as counter:`, traces, compiles and persistent-cache hits."""

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
