"""The `mjxsuite` command's parser: train, sweep, eval and rollout (`bench` is added by `benchmarks.cli`).

Every option is generated from a dataclass field: a command's own settings (`TrainOptions`, ...) and
every field of the agents' configs as `--FIELD VALUE`, with the help the comment on or above the field
gives. `agents.commands` runs the commands.

Exit status: 0 done, 2 a command that cannot run as given, 1 a failure while running (a damaged
checkpoint, a full disk), 130 stopped by SIGINT, 143 by SIGTERM (after saving the checkpoint).
"""

from __future__ import annotations

import argparse
import dataclasses
import difflib
import inspect
import re
import sys
import typing
from collections.abc import Mapping
from dataclasses import field

from agents import commands
from agents.commands import AGENTS, CONFIG, Command, UsageError, config_from_args, config_fields  # noqa: F401
from agents.run_steps import CHECKPOINT_EVERY, CHECKPOINT_SECONDS
from envs.ranges import COUNT, NON_NEGATIVE, NON_NEGATIVE_COUNT, Range

@dataclasses.dataclass(kw_only=True)
class Common:
    # do not use JAX's compilation cache (default: on, in $XDG_CACHE_HOME/mjxsuite/jax; also MJXSUITE_COMPILE_CACHE=0)
    no_compile_cache: bool = False
    imports: list[str] = field(default_factory=list)  # a module or .py file that registers your tasks; repeatable


@dataclasses.dataclass(kw_only=True)
class EnvOverrides:  # given to eval or rollout, they change the saved env's options
    # an envs.make override (envs.options(NAME) lists them), e.g. episode_length=200, an MJX task's solver
    # option opt.solver=CG or MuJoCo Warp's buffers nconmax=N, naconmax=N, njmax=N; repeatable
    env_opts: list[str] = field(default_factory=list)
    # an MJX task's implementation: jax (default) or warp (MuJoCo Warp, NVIDIA GPU, pip install 'mjxsuite[warp]')
    impl: typing.Literal["jax", "warp"] | None = None
    # draw an mjx.Model value per env: body_mass:pole=0.05:0.2 (uniform), =x0.8:1.2 (scale), =0.05 (fixed); repeatable
    randomize: list[str] = field(default_factory=list)
    randomize_per: typing.Literal["episode", "env"] | None = None  # draw again every episode (default) or once per env


@dataclasses.dataclass(kw_only=True)
class RunOptions(Common):
    env: str | None = None  # registered env name, e.g. cartpole or cartpole-mjx (with --resume: the saved one)
    # dqn for discrete tasks, ppo, sac or td3 for continuous ones (default: dqn, or agents/brax_defaults.py's choice)
    agent: typing.Literal["dqn", "ppo", "sac", "td3"] | None = None
    seeds: int | None = None  # agents trained at once (default 1)
    seed: int | None = None  # random seed (default 0)
    # env steps per seed (DQN's total_steps, the others' num_timesteps), rounded up to whole training steps
    steps: int | None = None
    replay: typing.Literal["uniform", "prioritized"] | None = None  # DQN's replay (DQNConfig.replay)
    # a named config that --FIELD options change: DQN's default, quick or many-envs; the task's others (brax_defaults)
    preset: str | None = None
    out: str | None = None  # directory for config.json, metrics.jsonl, checkpoint and eval.json
    resume: bool = False  # continue the run saved in --out from its last checkpoint, with its env, seeds, config
    checkpoint_every: int = CHECKPOINT_EVERY  # chunks between checkpoints in --out (default %(default)s)...
    # ...and at least this many seconds between them, or a multiple of the last save's duration if longer
    checkpoint_seconds: float = CHECKPOINT_SECONDS
    # chunks between judges of the policy, and after the last (default: every chunk, DQN's by a cost model)
    judge_every: int | None = None
    rerun: str | None = None  # a Rerun file (FILE.rrd) to log training curves and greedy rollouts to
    overwrite: bool = False  # replace the run --out holds (else refused: --resume continues it) and --rerun's file
    devices: int | None = None  # local devices to spread the agents over (default: all that split them evenly)
    # bit-for-bit repeatable runs on a GPU, but not of MuJoCo Warp (docs/reliability.md; also MJXSUITE_DETERMINISTIC=1)
    deterministic: bool = False
    # join a multi-host run (jax.distributed.initialize; also MJXSUITE_DISTRIBUTED=1; docs/scaling.md)
    distributed: bool = False


@dataclasses.dataclass(kw_only=True)
class TrainOptions(EnvOverrides, RunOptions):
    # child processes training the seeds, one device each (default: one per GPU for an MJX task; docs/scaling.md)
    processes: int | None = None
    rerun_every: int = 1  # chunks (PPO/SAC: evaluations) between logged evaluation rollouts (0: none)


@dataclasses.dataclass(kw_only=True)
class SweepOptions(RunOptions):
    rerun_every: int = 0  # chunks between logged evaluation rollouts of every agent (default 0: curves only)
    plot: str | None = None  # solve rate and steps to solve per config, a PNG (default: sweep.png in --out)


@dataclasses.dataclass(kw_only=True)
class EvalOptions(EnvOverrides, Common):
    checkpoint: str  # a directory written by `mjxsuite train --out`
    episodes: int | None = None  # fresh episodes per seed (default: the run's own evaluation's, its eval_episodes)
    seed: int = 123  # the evaluation's random seed


@dataclasses.dataclass(kw_only=True)
class RolloutOptions(EnvOverrides, Common):
    env: str | None = None  # registered env name (default: the checkpoint's)
    checkpoint: str | None = None  # a directory written by `mjxsuite train --out`; random actions without
    episodes: int | None = None  # stop once every env finished this many episodes (default 1)
    num_envs: int = 1  # envs stepped at once
    steps: int | None = None  # steps to run (default: episodes x the time limit)
    scene_envs: int = 1  # envs drawn in 3D
    plot_envs: int = 16  # envs whose observations etc. are plotted
    seed: int = 0  # the rollout's random seed
    rerun: str  # the Rerun file (FILE.rrd) to write
    overwrite: bool = False  # replace an existing file


FLAGS = {"imports": "--import", "env_opts": "--env-opt"}  # where a flag is not the field's name
METAVARS = {"imports": "MODULE", "env_opts": "KEY=VALUE", "randomize": "FIELD:ELEMENT=RANGE"}
RANGES = {"seeds": COUNT, "steps": COUNT, "checkpoint_every": COUNT, "checkpoint_seconds": NON_NEGATIVE,
          "judge_every": COUNT, "processes": COUNT, "rerun_every": NON_NEGATIVE_COUNT, "devices": COUNT,
          "episodes": COUNT, "num_envs": COUNT, "scene_envs": NON_NEGATIVE_COUNT, "plot_envs": NON_NEGATIVE_COUNT}


def field_help(cls: type) -> dict[str, str]:
    """Each field's help: the comment after it in its class's source, else the comment lines above it."""
    helps, above = {}, []
    for klass in reversed(cls.__mro__[:-1]):
        for line in inspect.getsource(klass).splitlines():
            text = line.strip()
            if text.startswith("#"):
                above.append(text.lstrip("# "))
                continue
            name, colon, rest = text.partition(":")
            if colon and name.isidentifier() and "ClassVar" not in rest:
                helps[name] = rest.partition("  #")[2].strip() or " ".join(above)
            above = []
    return helps


def ranged(kind: type, valid: Range):
    """An argparse `type` that also checks the value's range (argparse names the option)."""

    def parse(text: str):
        value = kind(text)  # argparse names the option of a ValueError's text
        if value not in valid:
            raise argparse.ArgumentTypeError(f"must be {valid}, got {text}")
        return value

    parse.__name__ = kind.__name__
    return parse


def add_options(parser: argparse.ArgumentParser, cls: type) -> None:
    """A flag per field of the dataclass `cls`: a bool a switch, a list repeatable, a Literal a choice."""
    helps = field_help(cls)
    for spec in dataclasses.fields(cls):
        kind = typing.get_type_hints(cls)[spec.name]
        kind = typing.get_args(kind)[0] if type(None) in typing.get_args(kind) else kind  # X | None: X
        options = {"help": helps.get(spec.name, ""), "dest": spec.name}
        if spec.default is dataclasses.MISSING and spec.default_factory is dataclasses.MISSING:
            options["required"] = True
        else:
            options["default"] = spec.default_factory() if spec.default is dataclasses.MISSING else spec.default
        if kind is bool:
            options["action"] = "store_true"
        elif typing.get_origin(kind) is list:
            options.update(action="append", metavar=METAVARS[spec.name])
        elif typing.get_origin(kind) is typing.Literal:
            options["choices"] = typing.get_args(kind)
        else:
            options["type"] = ranged(kind, RANGES[spec.name]) if spec.name in RANGES else kind
        parser.add_argument(FLAGS.get(spec.name, "--" + spec.name.replace("_", "-")), **options)


def add_config_fields(parser: argparse.ArgumentParser, agents=AGENTS, sweep: bool = False) -> None:
    """Every field of the `agents`' configs as `--FIELD VALUE`, read as text (`commands.config_from_args`);
    in a sweep, the sweepable fields take comma-separated values."""
    from agents import registry

    taken = {option for action in parser._actions for option in action.option_strings}
    fields: dict[str, list[tuple[str, str]]] = {}  # name -> (agent, help) of each agent that has it
    for agent in agents:
        helps = field_help(registry.config_class(agent))
        for spec in dataclasses.fields(registry.config_class(agent)):
            fields.setdefault(spec.name, []).append((agent, helps.get(spec.name, "")))
    group = parser.add_argument_group("agent config fields", "defaults: the agent's config class or "
                                      "preset; PPO/SAC/TD3 recipes per task: agents/brax_defaults.py")
    swept = {name for agent in agents for name in registry.sweepable(agent)} if sweep else set()
    for name, owners in fields.items():
        if f"--{name}" not in taken:  # DQN's --replay is a run option
            first, texts = next((text for _, text in owners if text), ""), {}
            for agent, text in owners:  # the agents that say the same, or nothing, together
                texts.setdefault(text or first, []).append(agent)
            text = "; ".join(f"{text} ({', '.join(agents)})".lstrip() for text, agents in texts.items())
            values = "; comma-separated values to sweep" if name in swept else ""
            group.add_argument(*dict.fromkeys([f"--{name}", f"--{name.replace('_', '-')}"]), dest=CONFIG + name,
                               metavar="V1,V2,..." if values else "VALUE", help=text.replace("%", "%%") + values)


def build_parser(more: Mapping[str, Command] | None = None) -> argparse.ArgumentParser:
    """The `mjxsuite` argument parser: train, sweep, eval and rollout, plus the subcommands in `more`."""
    parser = argparse.ArgumentParser(prog="mjxsuite", description="JAX RL environments on MuJoCo-MJX, with DQN, "
                                     "PPO, SAC and TD3.")
    sub = parser.add_subparsers(dest="command", required=True)
    commands_ = {
        "train": (TrainOptions, "train DQN, PPO, SAC or TD3 (--agent), many seeds at once; any field of the "
                                "agent's config can be set with --FIELD VALUE"),
        "sweep": (SweepOptions, "train a grid of configs x seeds as one program; swept fields take comma-separated "
                                "values, other config fields --FIELD VALUE; writes sweep.json and sweep.png to --out"),
        "eval": (EvalOptions, "evaluate a saved run's policies, every seed"),
        "rollout": (RolloutOptions, "log a rollout (random, or greedy from a checkpoint) to a Rerun file"),
    }
    for name, (options, text) in commands_.items():
        command = sub.add_parser(name, help=text, description=text)
        add_options(command, options)
        if name in ("train", "sweep"):
            add_config_fields(command, sweep=name == "sweep")
    for command in (more or {}).values():
        command.add_parser(sub)
    return parser


def joined_negative_values(argv: list[str]) -> list[str]:
    """`--FIELD -1,2` as `--FIELD=-1,2`: argparse takes any other value starting with '-' for an option."""
    joined = []
    for word in argv:
        if joined and re.fullmatch(r"--[\w-]+", joined[-1]) and re.match(r"-[\d.]", word) and \
                not re.fullmatch(r"-\d+|-\d*\.\d+", word):
            joined[-1] += "=" + word
        else:
            joined.append(word)
    return joined


def _use_compile_cache(args) -> None:
    from agents import jax_compile_cache

    jax_compile_cache.disable() if args.no_compile_cache else jax_compile_cache.enable()


def _refuse_unknown(parser: argparse.ArgumentParser, command: str, extra: list[str]) -> None:
    """An unknown option, with the nearest known one."""
    known = [option for action in parser._subparsers._group_actions[0].choices[command]._actions
             for option in action.option_strings]
    near = difflib.get_close_matches(extra[0].partition("=")[0], known, n=1)
    raise UsageError(f"unknown option {extra[0]} for `mjxsuite {command}`" + (f"; did you mean {near[0]}?" if near
                     else "") + f" (`mjxsuite {command} --help` lists every option)")


def main(argv: list[str] | None = None, more: Mapping[str, Command] | None = None) -> int:
    """Run one `mjxsuite` command; `more` adds subcommands by name (`bench`, so agents never import benchmarks)."""
    more = more or {}
    parser = build_parser(more)
    args, extra = parser.parse_known_args(joined_negative_values(sys.argv[1:] if argv is None else argv))
    if args.command in ("train", "sweep") and args.resume and not args.out:
        parser.error("--resume needs --out")
    handlers = {"train": commands.cmd_train, "sweep": commands.cmd_sweep, "eval": commands.cmd_eval,
                "rollout": commands.cmd_rollout, **{name: command.run for name, command in more.items()}}
    from agents.checkpoint import CheckpointError
    from agents.processes import ProcessFailed
    from envs.mjx_warp import WarpUnavailable  # not envs.mjx_env: that loads mujoco.mjx (start-up time)

    from agents import signals

    signals.dump_stacks_on_signal()
    if args.command not in ("train", "sweep"):
        signals.release_early()  # only a training run stops at a signal of its own accord
    try:
        if extra and args.command not in more:
            _refuse_unknown(parser, args.command, extra)
        if args.command in ("train", "sweep", "eval", "rollout"):
            _use_compile_cache(args)
            commands.import_tasks(args.imports)
        if args.command in ("train", "sweep"):
            commands.before_any_jax(args)
        return handlers[args.command](args, extra)
    except UsageError as err:
        print(f"mjxsuite: {err}", file=sys.stderr)
        raise
    except (ValueError, FileNotFoundError, WarpUnavailable) as err:  # the envs and agents APIs refuse bad input so
        print(f"mjxsuite: {'--impl warp: ' * isinstance(err, WarpUnavailable)}{err}", file=sys.stderr)
        return 2
    except (CheckpointError, OSError, ProcessFailed) as err:
        print(f"mjxsuite: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
