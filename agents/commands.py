"""What `mjxsuite train`, `sweep`, `eval` and `rollout` do, once `agents.cli` has parsed them: the
agent and config for a task, the checks before anything compiles, the run, and its report."""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import json
import os
import signal
import sys
import typing
from collections.abc import Callable
from pathlib import Path

from agents import env_options
from agents import sweep as sweeps

AGENTS = ("dqn", "ppo", "sac", "td3")
POLICY_NAMES = {"dqn": "greedy", "ppo": "deterministic", "sac": "deterministic", "td3": "deterministic"}  # judged
CONFIG = "field."  # the namespace prefix of the agents' config fields (`agents.cli.add_config_fields`)


class UsageError(SystemExit):
    """A command that cannot run as given: exit status 2, as argparse's own errors; `str()` is the message."""

    def __init__(self, message: str):
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


class Command(typing.NamedTuple):
    """A subcommand added to `mjxsuite` from outside this package (see `agents.cli.main`)."""

    add_parser: Callable[[argparse._SubParsersAction], object]  # adds its subparser
    run: Callable[[argparse.Namespace, list[str]], int]  # (parsed args, unparsed rest) -> exit code


def config_fields(args: argparse.Namespace) -> dict[str, str]:
    """The config fields given on the command line, as text by name."""
    return {name[len(CONFIG):]: value for name, value in vars(args).items()
            if name.startswith(CONFIG) and value is not None}


def _parse_value(kind: type, text: str):
    if kind is bool:
        return env_options.parse_bool(text)
    if kind == tuple[int, ...]:
        return tuple(int(v) for v in text.split(",") if v)
    if kind == float | None:
        return None if text.lower() == "none" else float(text)
    return kind(text)


def config_from_args(base, fields: dict[str, str], **given):
    """`base` with the config `fields` given as text, then the command's own options `given` (None: not given)."""
    from agents.registry import SAME_FIELD

    kinds = typing.get_type_hints(type(base))
    changes = {}
    for name, text in fields.items():
        if name not in kinds or name == "RANGES":
            hint = f" ({name} is {SAME_FIELD[name]} here)" if SAME_FIELD.get(name) in kinds else ""
            raise UsageError(f"{type(base).__name__} has no field {name}{hint}; its fields: "
                             + ", ".join(f.name for f in dataclasses.fields(base)))
        try:
            changes[name] = _parse_value(kinds[name], text)
        except ValueError as err:
            raise UsageError(f"bad value for --{name}: {err}")
    try:
        return dataclasses.replace(base, **changes, **{k: v for k, v in given.items() if v is not None})
    except ValueError as err:
        raise UsageError(str(err))


def choose_agent(env_name: str, agent: str | None, env_opts: dict) -> str:
    """--agent, by default dqn or the table's choice for a continuous task; a mismatch is refused."""
    import envs

    from agents import brax_defaults, registry

    env = envs.spec(env_name, **env_opts)  # not envs.make: an MJX task would load MJX and take a device
    agent = agent or ("dqn" if env.num_actions is not None else brax_defaults.default_agent(env_name, env.pixels))
    why = registry.misfit(agent, env_name, env.num_actions, env.action_size, env.pixels)
    if why:
        raise UsageError(why)
    return agent


def agent_config(env_name: str, agent: str, preset: str | None, fields: dict[str, str], steps: int | None,
                 replay: str | None, observation: str = "state"):
    """DQN's preset or the task's recipe (agents/brax_defaults.py), with the config `fields` and `--steps`."""
    from agents import brax_defaults, registry
    from agents.dqn import PRESETS

    if agent == "dqn":
        if (preset or "default") not in PRESETS:
            raise UsageError(f"--preset {preset!r} does not exist for --agent dqn; choose one of "
                             f"{', '.join(sorted(PRESETS))}")
        return config_from_args(PRESETS[preset or "default"], fields, total_steps=steps, replay=replay)
    if replay is not None:
        raise UsageError(f"--replay chooses DQN's replay; --agent {agent} has "
                         + ("none (drop --replay)" if agent == "ppo" else "a uniform one (drop --replay)"))
    try:
        preset = preset or brax_defaults.default_preset(env_name, agent, observation)
        base = registry.config_class(agent)(**brax_defaults.settings(env_name, agent, preset))
    except ValueError as err:
        raise UsageError(str(err))
    return config_from_args(base, fields, num_timesteps=steps)


def say_rounding(config) -> None:
    """Say, before anything compiles, how the agent rounded --steps (whole training steps per chunk)."""
    if config.rounding():
        print(f"note: {config.rounding()}", file=sys.stderr)


def say_gpu_sized(env_name: str, agent: str, config, seeds: int, gpus: list[str], pixels: bool = False) -> None:
    """Say, before anything compiles, when a run without a GPU is sized for one (`brax_defaults.gpu_sized_note`)."""
    from agents import brax_defaults

    note = None if gpus else brax_defaults.gpu_sized_note(env_name, agent, config.total_steps, seeds, pixels)
    if note:
        print(f"note: {note}", file=sys.stderr)


def before_any_jax(args) -> None:
    """What a training run sets before any JAX computation: deterministic ops, a multi-host runtime."""
    from agents import sharding

    if args.deterministic or os.environ.get("MJXSUITE_DETERMINISTIC") == "1":
        from agents.device_options import make_deterministic

        make_deterministic()
        if getattr(args, "impl", None) == "warp":
            print("note: --deterministic makes XLA's ops deterministic; MuJoCo Warp's physics is not "
                  "(docs/reliability.md): runs with --impl warp still differ from run to run", file=sys.stderr)
    if args.distributed or os.environ.get(sharding.DISTRIBUTED_ENV, "").lower() in ("1", "true", "yes"):
        sharding.initialize_distributed()


def require_registered(env_name: str) -> None:
    import envs

    if env_name not in envs.names():
        raise UsageError(f"unknown env {env_name!r}; registered envs: {', '.join(envs.names())} "
                         "(your own task? --import the module that registers it)")


def import_tasks(modules: list[str]) -> None:
    """Import the user's task modules (`--import`), so their `envs.register` calls run."""
    for module in modules:
        try:
            if module.endswith(".py"):
                spec = importlib.util.spec_from_file_location(Path(module).stem, module)
                if spec is None or not Path(module).is_file():
                    raise FileNotFoundError(f"no such file {module!r}")
                loaded = importlib.util.module_from_spec(spec)
                sys.modules[spec.name] = loaded
                spec.loader.exec_module(loaded)
            else:
                if os.getcwd() not in sys.path:
                    sys.path.insert(0, os.getcwd())
                importlib.import_module(module)
        except Exception as err:
            raise UsageError(f"--import {module}: {type(err).__name__}: {err}")


def train_env_options(args) -> dict:
    """A new run's `envs.make` overrides, the task's on camera images (`brax_defaults.pixel_env_options`)."""
    from agents import brax_defaults

    return brax_defaults.pixel_env_options(args.env, env_options.from_args(args.env, args))


def cmd_train(args, extra: list[str]) -> int:
    from agents import checkpoint, processes

    if args.resume:
        saved = _saved_run(args, sweep=False)
        if _finished(args, saved):
            return 0
        parts = checkpoint.process_dirs(args.out)
        if args.processes not in (None, len(parts or [None])):
            held = len(parts or [None])
            raise UsageError(f"--processes {args.processes}: {args.out} holds a run of {held} process"
                             f"{'es' * (held > 1)}; resume it without --processes")
        result = (_train(args, saved.config, resume=True, env_options=saved.env_options, seed_slice=saved.seed_slice)
                  if parts is None else _train_in_processes(args, saved, fresh=False))
        return _report(args, saved.config, result)
    if args.env is None:
        raise UsageError("train needs --env (or --resume with the --out of a saved run)")
    require_registered(args.env)
    options = train_env_options(args)
    args.seeds, args.seed = args.seeds or 1, args.seed or 0
    gpus = processes.local_gpus()
    count = processes.count(args.env, args.seeds, args.devices, args.processes, gpus)
    if count > 1:
        processes.keep_off_the_gpus(gpus)  # before JAX's backend starts (at the end: the merge's tie-break)
    agent = choose_agent(args.env, args.agent, options)
    config = agent_config(args.env, agent, args.preset, config_fields(args), args.steps, args.replay,
                          observation=options.get("observation", "state"))
    say_rounding(config)
    say_gpu_sized(args.env, agent, config, args.seeds, gpus, pixels=options.get("observation") == "pixels")
    if count > 1:
        run = checkpoint.SavedRun(args.env, args.seeds, config, options, args.seed, None, agent, args.judge_every)
        return _report(args, config, _train_in_processes(args, run, fresh=True, count=count, gpus=gpus))
    return _report(args, config, _train(args, config, env_options=options))


def _train_in_processes(args, run, fresh: bool, count: int = 0, gpus: list[str] | None = None):
    """The run's seeds trained by child processes, one per GPU (`agents.processes`), new (`fresh`) or resumed."""
    import contextlib
    import tempfile

    from agents import processes

    for flag, given in (("--rerun", args.rerun), ("--distributed", args.distributed)):
        if given:
            raise UsageError(f"{flag} runs in one process; training in several processes (one per GPU) takes "
                             f"none: drop {flag}, or add --devices 1")
    if gpus is None:
        gpus = processes.local_gpus()
        processes.keep_off_the_gpus(gpus)
    options = ["--checkpoint-every", str(args.checkpoint_every), "--checkpoint-seconds", str(args.checkpoint_seconds)]
    options += ["--judge-every", str(args.judge_every)] if args.judge_every is not None else []
    options += ["--no-compile-cache"] * args.no_compile_cache + ["--deterministic"] * args.deterministic
    for module in args.imports:
        options += ["--import", str(Path(module).resolve()) if module.endswith(".py") else module]
    with tempfile.TemporaryDirectory(prefix="mjxsuite-") if args.out is None else contextlib.nullcontext() as temporary:
        out = Path(args.out or temporary)
        if fresh:
            print(f"training {run.seeds} seeds in {count} processes, one per "
                  + (f"GPU ({', '.join(gpus[:count])})" if len(gpus) >= count else "device")
                  + f" (docs/scaling.md){'' if args.out else '; no --out: their files are removed at the end'}",
                  flush=True)
            processes.start(out, run, count, args.overwrite)
        return processes.train(out, run, run.config.num_chunks, options, gpus)


def _saved_run(args, sweep: bool):
    """The run in --out that `--resume` continues (a sweep or not), with its own config: config options are refused."""
    from agents import checkpoint

    saved = checkpoint.load_config(args.out)
    if bool(saved.sweep) != sweep:
        command = "sweep" if saved.sweep else "train"
        raise UsageError(f"{args.out} holds a `mjxsuite {command}` run; continue it with "
                         f"`mjxsuite {command} --out {args.out} --resume`")
    own = ("steps", "replay", "preset", "agent", "impl", "randomize_per", "env_opts", "randomize")
    given = [f"--{name.replace('_', '-')}" for name in own if getattr(args, name, None)]
    given += [f"--{name} {text}" for name, text in config_fields(args).items()]
    if given:
        raise UsageError(f"--resume continues the run saved in {args.out} with its own config; "
                         f"drop {' '.join(given)} or start a new --out")
    args.env, args.seeds = args.env or saved.env, args.seeds or saved.seeds
    args.seed = saved.seed if args.seed is None else args.seed
    require_registered(args.env)
    return saved


def _train(args, config, **kwargs):
    """train_run, writing a Rerun file with --rerun (its path is checked before training starts)."""
    from agents import registry, sharding
    from agents.run import train_run

    kwargs.update(seeds=args.seeds, seed=args.seed, out_dir=args.out, checkpoint_every=args.checkpoint_every,
                  checkpoint_seconds=args.checkpoint_seconds, devices=args.devices, overwrite=args.overwrite,
                  judge_every=args.judge_every)
    if not args.rerun:
        return train_run(args.env, config, **kwargs)
    if not sharding.is_writer():  # process 0 writes the file; the others still gather their agents' episodes for it
        return train_run(args.env, config, on_chunk=lambda *_: None, **kwargs)
    from agents.training_log import CURVES, TrainingLogger

    grid = kwargs.get("sweep")
    logger = TrainingLogger(args.rerun, args.env, config, overwrite=args.overwrite, rollout_every=args.rerun_every,
                            seeds=args.seeds * (len(registry.sweep_configs(config, grid)) if grid else 1),
                            agent_paths=sweeps.agent_paths(config, grid, args.seeds) if grid else None,
                            env_options=kwargs.get("env_options"), curves=CURVES[registry.name_of(config)])
    try:
        return train_run(args.env, config, on_chunk=logger, **kwargs)
    finally:
        logger.close()
        print(f"wrote Rerun recording {args.rerun}")


def _finished(args, saved) -> bool:
    """Whether the run in --out has finished; then say so with its results (once it is checked), changing no file."""
    from agents import checkpoint

    out = Path(args.out)
    if not (out / "eval.json").is_file() or checkpoint.chunks_saved(out) < saved.config.num_chunks:
        return False
    checkpoint.check_resumable(out, saved._replace(env=args.env, seeds=args.seeds, seed=args.seed))
    checkpoint.check_saved(out, saved.env)
    returns = ", ".join(f"{r:.1f}" for r in json.loads((out / "eval.json").read_text()).get("mean_return", []))
    print(f"{out} holds a finished run ({checkpoint.describe(out)}): nothing to resume. Its final mean "
          f"returns: {returns} (eval.json). `mjxsuite eval --checkpoint {out}` evaluates it again; "
          "--overwrite without --resume trains it anew")
    return True


def _report(args, config, result) -> int:
    from agents import registry, sharding

    if result.interrupted:
        return _report_stop(args, result)
    if not sharding.is_writer():  # process 0 reports for every host
        return 0
    _report_devices(result)
    policy = POLICY_NAMES[registry.name_of(config)]
    for i, (ret, solve) in enumerate(zip(result.mean_return, result.solve_step)):
        reached = "" if config.solve_return is None else (
            f"; first reached {config.solve_return:g} at step {solve if solve is not None else 'never'}")
        best = " (the best seed: load_policy's default)" if len(result.mean_return) > 1 and i == result.best_seed else ""
        best += " (diverged: its loss became non-finite; this is its best policy before)" if i in result.diverged else ""
        print(f"seed {i}: {policy} policy's mean return {ret:.1f} over {config.eval_episodes} episodes{reached}{best}")
    print(wall_line(result) + (f"; wrote {args.out}" if args.out else ""))
    return 0


def _report_stop(args, result, command: str = "train") -> int:
    """What a run stopped by a signal says (what was saved), and its exit status (130 or 143)."""
    from agents import sharding
    from agents.signals import exit_status

    name, resume = result.stop_signal or "SIGINT", f"`mjxsuite {command} --out {args.out} --resume`"
    if sharding.is_writer():
        print(f"stopped by {name}" + (
            "; nothing saved (no --out)" if not args.out else
            f"; checkpoint saved in {args.out} ({result.saved_chunks} of {result.total_chunks} chunks "
            f"done); continue with {resume}" if result.saved_chunks else
            f" before the first checkpoint: nothing trained is saved in {args.out}; {resume} starts the run from "
            "the beginning" if result.started else  # else stopped while the command started: nothing written
            f" before the run started: nothing was written to {args.out}"))
    return exit_status(getattr(signal, name))


def process_age_s() -> float | None:
    """Seconds since this process started (from Linux's /proc; None where there is none)."""
    try:
        fields = Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()
        started = int(fields[19]) / os.sysconf("SC_CLK_TCK")  # field 22, starttime, in ticks after boot
        return float(Path("/proc/uptime").read_text().split()[0]) - started
    except (OSError, ValueError, IndexError, AttributeError):
        return None


def wall_line(result) -> str:
    """Where the process's wall time went: start-up, compile, training, saves, the final evaluation, the rest."""
    parts, age = result.wall_parts(), process_age_s()
    wall = result.wall_s if age is None else max(age + result.earlier_wall_s, result.wall_s)
    parts["start-up"] += wall - result.wall_s  # the process's start before the run's
    return f"wall {wall:.1f}s = " + " + ".join(f"{name} {seconds:.1f}" for name, seconds in parts.items()) + " s"


def _report_devices(result) -> None:
    if result.processes > 1:
        print(f"trained in {result.processes} processes, one device each")
        return
    import jax

    available = jax.device_count() if jax.process_count() > 1 else jax.local_device_count()
    if result.devices > 1 or available > 1:
        print(f"spread over {result.devices} of {available} devices")


def float_list(name: str, text: str) -> list[float]:
    """A swept field's comma-separated numbers, e.g. 5e-4,1e-3."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UsageError(f"--{name} {text!r}: expected comma-separated numbers, e.g. --{name} 5e-4,1e-3")
    repeated = sorted({v for v in values if values.count(v) > 1})
    if repeated:  # each config trains once: a repeat would train the same agents twice
        raise UsageError(f"--{name} {text!r} lists {', '.join(f'{v:g}' for v in repeated)} more than once; "
                         "give each value once")
    return values


def sweep_grid(agent: str, fields: dict[str, str]) -> dict[str, list[float]]:
    """The swept fields, taken out of the config `fields`: the sweepable ones, and any other given a list."""
    from agents import registry

    sweepable = registry.sweepable(agent)
    if not sweepable:
        raise UsageError(f"--agent {agent} runs cannot be swept in one program (its training has no per-agent "
                         "hyperparameters); run one `mjxsuite train` per config")
    kinds = typing.get_type_hints(registry.config_class(agent))
    swept = [name for name, text in fields.items() if any(name in registry.sweepable(a) for a in AGENTS)
             or ("," in text and kinds.get(name) != tuple[int, ...])]
    for name in swept:
        if name in kinds and name not in sweepable:
            raise UsageError(f"--{name} cannot be swept: one compiled program has one set of array shapes and "
                             f"loops; sweepable fields of --agent {agent}: {', '.join(sweepable)} (run one sweep "
                             f"per value of --{name})")
    grid = {name: float_list(name, fields.pop(name)) for name in swept}
    if not grid:
        raise UsageError("sweep needs at least one field with several values, e.g. --learning_rate 5e-4,1e-3; "
                         f"sweepable fields of --agent {agent}: {', '.join(sweepable)}")
    return grid


def cmd_sweep(args, extra: list[str]) -> int:
    """A grid over the sweepable config fields (comma-separated values) times --seeds, as one program."""
    from agents import registry, sharding

    if args.resume:
        saved = _saved_run(args, sweep=True)
        config, grid = saved.config, saved.sweep
        result = _train(args, config, resume=True, env_options=saved.env_options, sweep=grid)
    else:
        if args.env is None:
            raise UsageError("sweep needs --env (or --resume with the --out of a saved sweep)")
        require_registered(args.env)
        agent = choose_agent(args.env, args.agent, {})
        fields = config_fields(args)
        grid = sweep_grid(agent, fields)
        args.seeds, args.seed = args.seeds or 1, args.seed or 0
        config = agent_config(args.env, agent, args.preset, fields, args.steps, args.replay)
        try:
            registry.sweep_configs(config, grid)  # every combination in range, before anything compiles
        except ValueError as err:
            raise UsageError(str(err))
        say_rounding(config)
        result = _train(args, config, sweep=grid)
    if result.interrupted:
        return _report_stop(args, result, "sweep")
    if not sharding.is_writer():
        return 0
    summary = sweeps.summarize(args.env, config, grid, args.seeds, result)
    print(sweeps.markdown_table(summary))
    _report_devices(result)
    print(f"{len(summary['configs'])} configs x {args.seeds} seeds: {wall_line(result)}")
    if args.out:
        print(f"wrote {sweeps.write_summary(args.out, summary)}")
    plot_path = args.plot or (Path(args.out) / sweeps.PLOT_FILE if args.out else None)
    if plot_path is not None:
        written = sweeps.plot(summary, plot_path)
        print(f"wrote {written}" if written else
              "no plot: matplotlib is not installed (pip install 'mjxsuite[sweep]' or matplotlib)")
    return 0


def agent_label(index: int, seeds: int, sweep: dict | None) -> str:
    """Agent `index` of a run: a seed, or in a sweep config `index // seeds` with seed `index % seeds`."""
    return f"agent {index} (config {index // seeds}, seed {index % seeds})" if sweep else f"seed {index}"


def cmd_eval(args, extra: list[str]) -> int:
    """Every seed's policy (DQN's greedy one, PPO's and SAC's deterministic one) over fresh episodes."""
    import jax
    import numpy as np

    from agents import checkpoint
    from agents.run import load_agent, lower_evaluation_cached

    # Given env options judge the policy on other ones, e.g. across --randomize ranges, or --impl jax.
    saved = checkpoint.load_config(args.checkpoint)
    env_name, env, options = checkpoint.saved_env(args.checkpoint, env_options.from_args(saved.env, args))
    _, _, agent, params = load_agent(args.checkpoint, env)
    seeds = jax.tree.leaves(params)[0].shape[0]
    keys = jax.random.split(jax.random.PRNGKey(args.seed), seeds)
    episodes = args.episodes or saved.config.eval_episodes  # the run's own judge's, by default
    evaluate = lower_evaluation_cached(agent, params, keys, env_name, options, episodes).compile()
    means = np.asarray(evaluate(params, keys).mean(axis=-1))
    for i, mean in enumerate(means):
        print(f"{agent_label(i, saved.seeds, saved.sweep)}: {POLICY_NAMES[saved.agent]} policy's mean return "
              f"{mean:.1f} over {episodes} episodes")
    print(json.dumps({"env": env_name, "env_options": options, "episodes": episodes, "mean_return": means.tolist()}))
    return 0


def cmd_rollout(args, extra: list[str]) -> int:
    import jax
    import numpy as np

    import envs
    from agents import traced_programs
    from envs import recording, rollouts

    recording.check_output_path(args.rerun, args.overwrite)  # before anything compiles
    if args.env is not None:
        require_registered(args.env)
    if args.checkpoint:
        from agents import checkpoint
        from agents.run import load_agent, pick_seed

        saved = checkpoint.load_config(args.checkpoint)
        other_env = args.env is not None and args.env != saved.env
        # The saved env, with the options given (e.g. --randomize ranges, --impl jax) on top.
        env_name, env, options = checkpoint.saved_env(args.checkpoint,
                                                      None if other_env else env_options.from_args(saved.env, args))
        _, _, agent, params = load_agent(args.checkpoint, env)
        # Its deterministic policy, the best seed's parameters; the config names it in the export cache's key.
        policy, params = lambda params, obs, key: agent.policy(params, obs), pick_seed(args.checkpoint, params)
        policy_name = {POLICY_NAMES[saved.agent]: saved.config}
        if other_env:
            options = env_options.from_args(args.env, args)
            other = envs.make(args.env, **options)
            spaces = lambda e: (e.observation_size, e.num_actions, e.action_size)  # noqa: E731
            if spaces(other) != spaces(env):
                raise UsageError(f"rollout: the policy in {args.checkpoint} was trained on {env_name}, "
                                 f"whose observations/actions do not match {args.env}'s")
            env, env_name = other, args.env
    elif args.env is None:
        raise UsageError("rollout: give --env (random policy) and/or --checkpoint (greedy policy)")
    else:
        options = env_options.from_args(args.env, args)
        env, env_name = envs.make(args.env, **options), args.env
        policy, params, policy_name = recording.random_policy(env), None, "random"
    episodes = args.episodes or (None if args.steps else 1)
    steps = args.steps or episodes * getattr(env, "episode_length", 1000)
    key = jax.random.PRNGKey(args.seed)
    program = rollouts.rollout_program(env, policy, args.num_envs, steps, args.scene_envs)  # through the export cache
    rollout = traced_programs.lower_env_program(
        "rollout", program, (key, params), env, env_name, options,
        extra={"policy": policy_name, "num_envs": args.num_envs, "steps": steps, "scene_envs": args.scene_envs},
    ).compile()(key, params)
    if episodes:
        rollout = recording.trim_to_episodes(rollout, episodes)
    rec = recording.open_recording(args.rerun, args.overwrite, blueprint=recording.rollout_blueprint())
    try:
        recording.log_rollout(rec, env, rollout, plot_envs=args.plot_envs)
    finally:
        recording.close_recording(rec)
    done = np.asarray(rollout.done) > 0
    returns = np.asarray(rollout.episode_return)[done]
    mean = f"mean return {returns.mean():.1f}" if done.any() else "no episode finished"
    print(f"logged {done.shape[0]} steps of {done.shape[1]} envs ({done.sum()} episodes, {mean}) to {args.rerun}")
    return 0
