"""The `mjxsuite` console script: it catches SIGINT and SIGTERM first (`agents.signals.catch_early`),
then loads the command (`benchmarks.cli`), whose imports (JAX, CUDA's plugin, MuJoCo) take seconds
in which a Ctrl-C would otherwise raise anywhere."""

from __future__ import annotations

from agents import signals


def main() -> int:
    signals.catch_early()
    from benchmarks.cli import main as run

    return run()
