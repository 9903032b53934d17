"""The `mjxsuite` console script. Its first line catches SIGINT and SIGTERM
(`agents.signals.catch_early`): the imports that follow (JAX, CUDA's plugin, MuJoCo) take seconds
in which a Ctrl-C would otherwise raise anywhere. Then it runs `agents.cli` with the subcommands
that installed packages add through the `mjxsuite.commands` entry-point group (the benchmarks
package adds `bench`), so the agents never import the benchmarks.

`run` is the script itself: `main`, then an exit without the interpreter's teardown (`exit_now`);
`agents.processes.MJXSUITE` runs it as a program of this interpreter."""

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

    commands = {}
    for point in entry_points(group=COMMANDS_GROUP):
        commands.update(point.load())
    return commands


def main(argv: list[str] | None = None) -> int:
    signals.catch_early()
    from agents import cli

    return cli.main(argv, more_commands())


def run() -> None:
    """The `mjxsuite` console script (pyproject.toml's entry point): `main`'s status as the process's.
    An exception leaves as it would from any script, with its traceback and the usual exit."""
    exit_now(main())


def exit_now(status: int | None) -> None:
    """End the process with `status` once everything it wrote is safe, as the interpreter's own exit
    makes it: every thread that is not a daemon joined (the checkpoint writer finishes its write),
    the atexit handlers run (JAX's, Rerun's, logging's), stdout and stderr flushed. Then `os._exit`
    skips what the interpreter would still do: free every module's objects one by one, XLA's compiled
    programs, buffers and thread pools among them, which saves nothing and keeps the user waiting.
    Every file the commands write is closed before they return (`with` blocks, atomic writes)."""
    for thread in threading.enumerate():
        if thread is not threading.current_thread() and not thread.daemon:
            thread.join()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    os._exit(status or 0)
