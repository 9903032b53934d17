"""The `mjxsuite` console script. Its first line catches SIGINT and SIGTERM
(`agents.signals.catch_early`): the imports that follow (JAX, CUDA's plugin, MuJoCo) take seconds
in which a Ctrl-C would otherwise raise anywhere. Then it runs `agents.cli` with the subcommands
that installed packages add through the `mjxsuite.commands` entry-point group (the benchmarks
package adds `bench`), so the agents never import the benchmarks."""

from __future__ import annotations

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
