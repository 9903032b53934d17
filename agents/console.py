"""The `mjxsuite` console script: it catches signals first (`agents.signals.catch_early`: the imports
that follow are slow), then runs `agents.cli` with the subcommands installed packages add through
the `mjxsuite.commands` entry points (benchmarks adds `bench`, so the agents never import it)."""

from __future__ import annotations

import atexit
import os
import sys
import threading

from agents import signals

COMMANDS_GROUP = "mjxsuite.commands"  # each entry point: a mapping of subcommand names to agents.cli.Command


def more_commands() -> dict:
    """The subcommands installed packages add (none where mjxsuite runs from a checkout uninstalled)."""
    from importlib.metadata import entry_points

    return {name: command for point in entry_points(group=COMMANDS_GROUP) for name, command in point.load().items()}


def main(argv: list[str] | None = None) -> int:
    signals.catch_early()
    from agents import cli

    return cli.main(argv, more_commands())


def run() -> None:
    """The `mjxsuite` console script (pyproject.toml's entry point): `main`'s status as the process's."""
    exit_now(main())


def exit_now(status: int | None) -> None:
    """End the process with `status` once all it wrote is safe (threads joined, atexit run, streams flushed),
    then `os._exit`: freeing every object one by one saves nothing."""
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    os._exit(status or 0)
