"""The `mjxsuite` command's train, sweep, eval and rollout (`bench` is added by `benchmarks.cli`).

train, eval and rollout use JAX's persistent compilation cache (see
`agents.jax_compile_cache`): a second run loads its compiled programs from disk, and
`train` its traced training chunk too (`agents.traced_programs`).
`--no-compile-cache` or `MJXSUITE_COMPILE_CACHE=0` turns it off.

Exit status: 0 done, 2 a command that cannot run as given (bad option or value, unknown
env, unusable --out, nothing or something else to --resume), 1 a failure while running
(a damaged checkpoint, a full disk), 130 stopped by Ctrl-C (SIGINT), 143 stopped by SIGTERM. A stopped
run saves its checkpoint first (it says what it saved); a second signal exits at once without saving.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import typing
from collections.abc import Callable, Mapping
from pathlib import Path

from agents import env_options
from agents import sweep as sweeps
from agents.dqn import PRESETS, DQNConfig
from agents.run_steps import CHECKPOINT_EVERY, CHECKPOINT_SECONDS, JUDGE_SHARE, SAVE_COST_FACTOR
from envs.ranges import COUNT, NON_NEGATIVE, NON_NEGATIVE_COUNT, Range


class UsageError(SystemExit):
    """A command that cannot run as given: exit status 2, as argparse's own errors. `main`
    prints the message; in-process callers see it as the exception's text."""

    def __init__(self, message: str):
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


def ranged(kind: type, valid: Range):
    """An argparse `type` that also checks the value's range (argparse names the option)."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            value = text
        if value not in valid:
            raise argparse.ArgumentTypeError(f"must be {valid}, got {text}")
        return value

    return parse


class Command(typing.NamedTuple):
    """A subcommand added to `mjxsuite` from outside this package (see `main`)."""

    add_parser: Callable[[argparse._SubParsersAction], object]  # adds its subparser
    run: Callable[[argparse.Namespace, list[str]], int]  # (parsed args, unparsed rest) -> exit code


def _parse_value(config_class: type, field: dataclasses.Field, text: str):
    kind = typing.get_type_hints(config_class)[field.name]
    if kind is bool:
        if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
            raise ValueError(f"expected true/false, got {text!r}")
        return text.lower() in ("true", "1", "yes")
    if kind == tuple[int, ...]:
        return tuple(int(v) for v in text.split(",") if v)
    if kind == float | None:
        return None if text.lower() == "none" else float(text)
    return kind(text)


def config_from_args(base, pairs: list[str], **given):
    """Apply `--key value` pairs (dashes or underscores), then the fields `given` by the
    command's own options (None: not given), to a config (DQNConfig, PPOConfig, SACConfig),
    with clear errors."""
    fields = {f.name: f for f in dataclasses.fields(base)}
    changes = {}
    i = 0
    while i < len(pairs):
        flag = pairs[i]
        if not flag.startswith("--"):
            raise UsageError(f"unexpected argument {flag!r}")
        name, _, value = flag[2:].partition("=")
        name = name.replace("-", "_")
        if name not in fields:
            raise UsageError(f"unknown option --{name}; {type(base).__name__} fields: {', '.join(sorted(fields))}")
        if not value:
            if i + 1 >= len(pairs):
                raise UsageError(f"--{name} needs a value")
            value = pairs[i + 1]
            i += 1
        try:
            changes[name] = _parse_value(type(base), fields[name], value)
        except ValueError as err:
            raise UsageError(f"bad value for --{name}: {err}")
        i += 1
    changes.update({name: value for name, value in given.items() if value is not None})
    try:
        return dataclasses.replace(base, **changes)
    except ValueError as err:
        raise UsageError(str(err))


AGENTS = ("dqn", "ppo", "sac", "td3")
POLICY_NAMES = {"dqn": "greedy", "ppo": "deterministic", "sac": "deterministic", "td3": "deterministic"}  # what each agent judges


def sweep_fields() -> tuple[str, ...]:
    """The options of `mjxsuite sweep`: every agent's sweepable fields."""
    from agents import registry

    return tuple(dict.fromkeys(name for agent in AGENTS for name in registry.sweepable(agent)))


def _choose_agent(env_name: str, agent: str | None, env_opts: dict) -> str:
    """--agent, by default dqn for a discrete task and the table's choice (ppo or sac) for a continuous one;
    a mismatch is refused."""
    import envs

    from agents import brax_defaults, registry

    env = envs.spec(env_name, **env_opts)  # not envs.make: an MJX task would load MJX and take a device
    agent = agent or ("dqn" if env.num_actions is not None else brax_defaults.default_agent(env_name))
    why = registry.misfit(agent, env_name, env.num_actions, env.action_size, env.pixels)
    if why:
        raise UsageError(why)
    return agent


def _agent_config(env_name: str, agent: str, preset: str | None, extra: list[str], steps: int | None,
                  replay: str | None, observation: str = "state"):
    """The agent's config: DQN's preset, or PPO's/SAC's base recipe with the task's row of
    agents/brax_defaults.py (`--preset` picks another; without it, camera images take the task's
    "pixels" recipe where it has one); then --FIELD VALUE and the command's own options
    (`--steps`: env steps per seed for every agent)."""
    from agents import brax_defaults, registry

    if agent == "dqn":
        return config_from_args(_dqn_preset(preset), extra, total_steps=steps, replay=replay)
    if replay is not None:
        raise UsageError(f"--replay chooses DQN's replay; --agent {agent} has "
                         + ("none (drop --replay)" if agent == "ppo" else "a uniform one (drop --replay)"))
    try:
        preset = preset or brax_defaults.default_preset(env_name, agent, observation)
        base = registry.config_class(agent)(**brax_defaults.settings(env_name, agent, preset))
    except ValueError as err:
        raise UsageError(str(err))
    return config_from_args(base, extra, num_timesteps=steps)


def _say_rounding(config) -> None:
    """Say, before anything compiles, how the agent rounded --steps (whole training steps per chunk)."""
    rounding = getattr(config, "rounding", None)
    said = rounding() if callable(rounding) else ""
    if said:
        print(f"note: {said}", file=sys.stderr)


def _say_gpu_sized(env_name: str, agent: str, config, seeds: int, gpus: list[str]) -> None:
    """Say, before anything compiles, when a run on a machine without a GPU is sized for one, and
    which preset fits a CPU (`brax_defaults.gpu_sized_note`)."""
    from agents import brax_defaults

    note = None if gpus else brax_defaults.gpu_sized_note(env_name, agent, config.total_steps, seeds)
    if note:
        print(f"note: {note}", file=sys.stderr)


def _require_registered(env_name: str) -> None:
    import envs

    if env_name not in envs.names():
        raise UsageError(f"unknown env {env_name!r}; registered envs: {', '.join(envs.names())} "
                         "(your own task? --import the module that registers it)")


def cmd_train(args, extra: list[str]) -> int:
    from agents import checkpoint, processes

    if args.resume:
        saved = _saved_run(args, extra, sweep=False)
        if _finished(args, saved):
            return 0
        parts = checkpoint.process_dirs(args.out)
        if parts is None and args.processes not in (None, 1):
            raise UsageError(f"--processes {args.processes}: {args.out} holds a run of one process; resume it without")
        if parts is None:
            result = _train(args, saved.config, resume=True, env_options=saved.env_options, seed_slice=saved.seed_slice)
        else:
            if args.processes not in (None, len(parts)):
                raise UsageError(f"--processes {args.processes}: {args.out} holds a run of {len(parts)} processes; "
                                 "resume it without --processes")
            result = _train_in_processes(args, saved, fresh=False)
        return _report(args, saved.config, result)
    if args.env is None:
        raise UsageError("train needs --env (or --resume with the --out of a saved run)")
    _require_registered(args.env)
    options = _train_env_options(args)
    args.seeds, args.seed = args.seeds or 1, args.seed or 0
    gpus = processes.local_gpus()
    count = processes.count(args.env, args.seeds, args.devices, args.processes, gpus)
    if count > 1:
        processes.keep_off_the_gpus(gpus)  # before JAX's backend starts (at the end: the merge's tie-break)
    agent = _choose_agent(args.env, args.agent, options)
    config = _agent_config(args.env, agent, args.preset, extra, args.steps, args.replay,
                           observation=options.get("observation", "state"))
    _say_rounding(config)
    _say_gpu_sized(args.env, agent, config, args.seeds, gpus)
    if count > 1:
        run = checkpoint.SavedRun(args.env, args.seeds, config, options, args.seed, None, agent, args.judge_every)
        result = _train_in_processes(args, run, fresh=True, count=count, gpus=gpus)
    else:
        result = _train(args, config, env_options=options)
    return _report(args, config, result)


def _train_in_processes(args, run, fresh: bool, count: int = 0, gpus: list[str] | None = None):
    """The run's seeds trained by child processes, one per GPU (`agents.processes`): a new run
    (`fresh`, `count` processes) or the one `args.out` holds. Without --out the children write
    to a temporary directory, removed at the end."""
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
    options += ["--no-compile-cache"] if args.no_compile_cache else []
    options += ["--deterministic"] if args.deterministic else []
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


def _train_env_options(args) -> dict:
    """A new run's `envs.make` overrides: the --env-opt/--impl/--randomize ones, and on camera
    images the task's own defaults for what they leave out (`brax_defaults.pixel_env_options`:
    e.g. the frame stack of cartpole-balance-mjx); config.json saves them all."""
    from agents import brax_defaults

    return brax_defaults.pixel_env_options(args.env, env_options.from_args(args.env, args))


def _dqn_preset(preset: str | None) -> DQNConfig:
    if (preset or "default") not in PRESETS:
        raise UsageError(f"--preset {preset!r} does not exist for --agent dqn; choose one of {', '.join(sorted(PRESETS))}")
    return PRESETS[preset or "default"]


def _saved_run(args, extra: list[str], sweep: bool, swept: tuple[str, ...] = ()):
    """The run in --out that `--resume` continues (a sweep or not, as `sweep` says); its env,
    seeds, seed and config come from there (train_run refuses any given that differ), so
    config options (`extra`, --steps, ..., and the `swept` fields) are refused."""
    from agents import checkpoint

    saved = checkpoint.load_config(args.out)
    if bool(saved.sweep) != sweep:
        command = "sweep" if saved.sweep else "train"
        raise UsageError(f"{args.out} holds a `mjxsuite {command}` run; continue it with "
                         f"`mjxsuite {command} --out {args.out} --resume`")
    own = (("--steps", args.steps), ("--replay", args.replay), ("--preset", args.preset),
           ("--agent", getattr(args, "agent", None)),
           ("--impl", getattr(args, "impl", None)), ("--randomize-per", getattr(args, "randomize_per", None)),
           ("--env-opt", getattr(args, "env_opts", None) or None), ("--randomize", getattr(args, "randomize", None) or None))
    given = [flag for flag, value in own if value is not None] + [f"--{name}" for name in swept]
    if extra or given:
        raise UsageError(f"--resume continues the run saved in {args.out} with its own config; "
                         f"drop {' '.join(given + extra)} or start a new --out")
    args.env = args.env or saved.env
    args.seeds = args.seeds or saved.seeds
    args.seed = saved.seed if args.seed is None else args.seed
    _require_registered(args.env)
    return saved


def _train(args, config, **kwargs):
    """train_run, writing a Rerun file with --rerun (its path is checked before training starts)."""
    from agents.run import train_run

    kwargs.update(seeds=args.seeds, seed=args.seed, out_dir=args.out, checkpoint_every=args.checkpoint_every,
                  checkpoint_seconds=args.checkpoint_seconds, devices=args.devices, overwrite=args.overwrite,
                  judge_every=args.judge_every)
    if not args.rerun:
        return train_run(args.env, config, **kwargs)
    from agents import sharding

    if not sharding.is_writer():  # process 0 writes the file; the others still gather their agents' episodes for it
        return train_run(args.env, config, on_chunk=lambda *_: None, **kwargs)
    from agents import registry
    from agents.training_log import CURVES, TrainingLogger

    grid = kwargs.get("sweep")
    agents = args.seeds * (len(registry.sweep_configs(config, grid)) if grid else 1)
    logger = TrainingLogger(args.rerun, args.env, config, seeds=agents, overwrite=args.overwrite,
                            rollout_every=args.rerun_every,
                            agent_paths=sweeps.agent_paths(config, grid, args.seeds) if grid else None,
                            env_options=kwargs.get("env_options"), curves=CURVES[registry.name_of(config)])
    try:
        return train_run(args.env, config, on_chunk=logger, **kwargs)
    finally:
        logger.close()
        print(f"wrote Rerun recording {args.rerun}")


def _finished(args, saved) -> bool:
    """Whether the run in `out` has finished (every chunk saved and its eval.json written); then say
    so with its results, and leave every file as it is: a resume of a finished run has nothing to do
    (once its identity and its files are checked, as any resume's are)."""
    import json

    from agents import checkpoint

    out = args.out
    summary = Path(out) / "eval.json"
    if not summary.is_file() or checkpoint.chunks_saved(Path(out)) < saved.config.num_chunks:
        return False
    checkpoint.check_resumable(Path(out), saved._replace(env=args.env, seeds=args.seeds, seed=args.seed))
    checkpoint.check_saved(out, saved.env)
    results = json.loads(summary.read_text())
    returns = ", ".join(f"{r:.1f}" for r in results.get("mean_return", []))
    print(f"{out} holds a finished run ({checkpoint.describe(Path(out))}): nothing to resume. Its final mean "
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
    """What a run stopped by a signal says (only what was saved), and its exit status: 130 after
    SIGINT, 143 after SIGTERM."""
    import signal

    from agents import sharding
    from agents.signals import exit_status

    name = result.stop_signal or "SIGINT"
    if sharding.is_writer():
        resume = f"`mjxsuite {command} --out {args.out} --resume`"
        if not args.out:
            print(f"stopped by {name}; nothing saved (no --out)")
        elif result.saved_chunks:
            print(f"stopped by {name}; checkpoint saved in {args.out} ({result.saved_chunks} of "
                  f"{result.total_chunks} {result.chunk_unit} done); continue with {resume}")
        elif result.started:
            print(f"stopped by {name} before the first checkpoint: nothing trained is saved in {args.out}; "
                  f"{resume} starts the run from the beginning")
        else:  # stopped while the command started: the directory holds what it held before
            print(f"stopped by {name} before the run started: nothing was written to {args.out}")
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
    """Where the process's wall time went: start-up (Python, imports, setting the run up),
    compile, training, checkpoint saves, the final evaluation, and the rest (host work
    between chunks: metrics, the Rerun logger, progress)."""
    parts = result.wall_parts()
    age = process_age_s()
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


def cmd_sweep(args, extra: list[str]) -> int:
    """A grid over the sweepable config fields (comma-separated values) times --seeds, as one program."""
    from agents import registry

    grid = {name: getattr(args, name) for name in sweep_fields() if getattr(args, name) is not None}
    if args.resume:
        saved = _saved_run(args, extra, sweep=True, swept=tuple(grid))
        config, grid = saved.config, saved.sweep
        result = _train(args, config, resume=True, env_options=saved.env_options, sweep=grid)
    else:
        if args.env is None:
            raise UsageError("sweep needs --env (or --resume with the --out of a saved sweep)")
        _require_registered(args.env)
        agent = _choose_agent(args.env, args.agent, {})
        sweepable = registry.sweepable(agent)
        _refuse_fixed_field_lists(extra, agent, sweepable)
        if not grid:
            raise UsageError("sweep needs at least one field with several values, e.g. --learning_rate 5e-4,1e-3; "
                             f"sweepable fields of --agent {agent}: {', '.join(sweepable) or 'none'}")
        args.seeds, args.seed = args.seeds or 1, args.seed or 0
        config = _agent_config(args.env, agent, args.preset, extra, args.steps, args.replay)
        try:
            registry.sweep_configs(config, grid)  # every combination in range, before anything compiles
        except ValueError as err:
            raise UsageError(str(err))
        _say_rounding(config)
        result = _train(args, config, sweep=grid)
    from agents import sharding

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


def _refuse_fixed_field_lists(pairs: list[str], agent: str, sweepable: tuple[str, ...]) -> None:
    """A comma-separated list given to a config field that cannot be swept: name the ones that can."""
    from agents import registry

    fields = {f.name: f for f in dataclasses.fields(registry.config_class(agent))}
    for flag, value in zip(pairs, pairs[1:] + [""]):
        name, _, inline = flag[2:].partition("=") if flag.startswith("--") else ("", "", "")
        name = name.replace("-", "_")
        if name in fields and "hidden" not in name and "," in (inline or value):
            raise UsageError(f"--{name} cannot be swept: one compiled program has one set of array shapes and loops; "
                             f"sweepable fields of --agent {agent}: {', '.join(sweepable) or 'none'} "
                             f"(run one sweep per value of --{name})")


def float_list(text: str) -> list[float]:
    """Comma-separated numbers, e.g. 5e-4,1e-3 (an argparse `type`)."""
    try:
        values = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers, got {text!r}")
    repeated = sorted({v for v in values if values.count(v) > 1})
    if repeated:  # each config trains once: a repeat would train the same agents twice
        raise argparse.ArgumentTypeError(f"{text!r} lists {', '.join(f'{v:g}' for v in repeated)} more than once; "
                                         "give each value once")
    return values


def cmd_eval(args, extra: list[str]) -> int:
    """Every seed's policy (DQN's greedy one, PPO's and SAC's deterministic one) over fresh episodes."""
    import jax
    import numpy as np

    from agents import checkpoint
    from agents.run import load_agent, lower_evaluation_cached

    if extra:
        raise UsageError(f"eval: unexpected arguments {extra}")
    # Given env options judge the policy on other ones, e.g. across --randomize ranges, or --impl jax.
    saved = checkpoint.load_config(args.checkpoint)
    env_name, env, options = checkpoint.saved_env(args.checkpoint, env_options.from_args(saved.env, args))
    _, _, agent, params = load_agent(args.checkpoint, env)
    seeds = jax.tree.leaves(params)[0].shape[0]
    keys = jax.random.split(jax.random.PRNGKey(args.seed), seeds)
    episodes = args.episodes or saved.config.eval_episodes  # the run's own judge's, by default
    evaluate = lower_evaluation_cached(agent, params, keys, env_name, options, episodes).compile()
    returns = evaluate(params, keys)
    means = np.asarray(returns.mean(axis=-1))
    for i, mean in enumerate(means):
        print(f"seed {i}: {POLICY_NAMES[saved.agent]} policy's mean return {mean:.1f} over {episodes} episodes")
    print(json.dumps({"env": env_name, "env_options": options, "episodes": episodes,
                      "mean_return": means.tolist()}))
    return 0


def cmd_rollout(args, extra: list[str]) -> int:
    import jax
    import numpy as np

    import envs
    from agents.saved_policies import collect_rollout_cached
    from envs import recording

    if extra:
        raise UsageError(f"rollout: unexpected arguments {extra}")
    recording.check_output_path(args.rerun, args.overwrite)  # before anything compiles
    if args.env is not None:
        _require_registered(args.env)
    if args.checkpoint:
        from agents import checkpoint
        from agents.saved_policies import load_greedy

        saved = checkpoint.load_config(args.checkpoint)
        other_env = args.env is not None and args.env != saved.env
        # The saved env, with the options given (e.g. --randomize ranges, --impl jax) on top.
        trained_on, env, options = checkpoint.saved_env(args.checkpoint,
                                                        None if other_env else env_options.from_args(saved.env, args))
        _, env, policy, params = load_greedy(args.checkpoint, env=env)
        policy_name = {POLICY_NAMES[saved.agent]: saved.config}
        env_name = trained_on
        if other_env:
            other = envs.make(args.env, **env_options.from_args(args.env, args))
            spaces = lambda e: (e.observation_size, e.num_actions, e.action_size)  # noqa: E731
            if spaces(other) != spaces(env):
                raise UsageError(f"rollout: the policy in {args.checkpoint} was trained on {trained_on}, "
                                 f"whose observations/actions do not match {args.env}'s")
            env, env_name, options = other, args.env, env_options.from_args(args.env, args)
    elif args.env is None:
        raise UsageError("rollout: give --env (random policy) and/or --checkpoint (greedy policy)")
    else:
        options = env_options.from_args(args.env, args)
        env, env_name = envs.make(args.env, **options), args.env
        policy, params, policy_name = recording.random_policy(env), None, "random"
    episodes = args.episodes or (None if args.steps else 1)
    steps = args.steps or episodes * getattr(env, "episode_length", 1000)
    rollout = collect_rollout_cached(env, env_name, options, policy, policy_name, jax.random.PRNGKey(args.seed),
                                     num_envs=args.num_envs, steps=steps, params=params, scene_envs=args.scene_envs)
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


def _use_compile_cache(args) -> None:
    from agents import jax_compile_cache

    if getattr(args, "no_compile_cache", False):
        jax_compile_cache.disable()
    else:
        jax_compile_cache.enable()


def import_tasks(modules: list[str]) -> None:
    """Import the user's task modules (`--import`), so their `envs.register` calls run."""
    import importlib
    import importlib.util

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


def build_parser(more: Mapping[str, Command] | None = None) -> argparse.ArgumentParser:
    """The `mjxsuite` argument parser: train, eval and rollout, plus the subcommands in `more`."""
    parser = argparse.ArgumentParser(prog="mjxsuite", description="JAX RL environments on MuJoCo-MJX, with DQN, PPO and SAC.")
    sub = parser.add_subparsers(dest="command", required=True)
    cached, tasks, spread = _parent_parsers()
    train = _add_train(sub, cached, tasks, spread)
    _add_sweep(sub, train, cached, tasks, spread)
    _add_eval_and_rollout(sub, cached, tasks)
    for command in (more or {}).values():
        command.add_parser(sub)
    return parser




def _parent_parsers() -> tuple[argparse.ArgumentParser, ...]:
    """The options several commands share: the compile cache, --import, and where agents run."""
    cached = argparse.ArgumentParser(add_help=False)
    cached.add_argument("--no-compile-cache", action="store_true",
                        help="do not use JAX's persistent compilation cache nor the cache of traced "
                             "programs inside it (default: on, in $XDG_CACHE_HOME/mjxsuite/jax; "
                             "MJXSUITE_COMPILE_CACHE=0 also turns it off, a path moves it)")

    tasks = argparse.ArgumentParser(add_help=False)
    tasks.add_argument("--import", dest="imports", action="append", default=[], metavar="MODULE",
                       help="import a module (a name importable from the current directory, or a .py file) "
                            "that registers your own tasks; repeatable")

    spread = argparse.ArgumentParser(add_help=False)
    spread.add_argument("--devices", type=ranged(int, COUNT),
                        help="local devices to spread the agents over (default: all that split them evenly); "
                             "an MJX task's `train` on several GPUs runs one process per device (see --processes)")
    spread.add_argument("--deterministic", action="store_true",
                        help="bit-for-bit repeatable runs on a GPU: XLA's deterministic ops (also "
                             "MJXSUITE_DETERMINISTIC=1); MuJoCo Warp is not deterministic (docs/reliability.md)")
    spread.add_argument("--distributed", action="store_true",
                        help="join a multi-host run (jax.distributed.initialize; also MJXSUITE_DISTRIBUTED=1): "
                             "agents spread over every device of every process, process 0 writes (docs/scaling.md)")

    return cached, tasks, spread


def _add_train(sub, cached, tasks, spread) -> argparse.ArgumentParser:
    """`mjxsuite train`'s options (a config's fields come as --FIELD VALUE, `config_from_args`)."""
    from agents import processes, registry

    train = sub.add_parser("train", help="train DQN, PPO or SAC (--agent), many seeds at once; any field of the "
                                         "agent's config can be set with --FIELD VALUE", parents=[cached, tasks, spread],
                           epilog="; ".join(f"{registry.config_class(agent).__name__} fields (--agent {agent}): "
                                            + ", ".join(f.name for f in dataclasses.fields(registry.config_class(agent)))
                                            for agent in AGENTS)
                                  + ". PPO/SAC defaults per task: agents/brax_defaults.py")
    train.add_argument("--env", help="registered env name, e.g. cartpole or cartpole-mjx (with --resume: the saved one)")
    train.add_argument("--agent", choices=AGENTS,
                       help="dqn for discrete tasks, ppo or sac for continuous ones "
                            "(default: dqn for a discrete task; for a continuous one, ppo or the task's choice in "
                            "agents/brax_defaults.py: sac for half-cheetah and walker2d)")
    train.add_argument("--seeds", type=ranged(int, COUNT), help="agents trained at once (default 1)")
    train.add_argument("--seed", type=int, help="random seed (default 0)")
    train.add_argument("--steps", type=ranged(int, COUNT),
                       help="env steps per seed, for every agent (DQNConfig.total_steps; PPO/SAC: num_timesteps, "
                            "rounded up to whole training steps per chunk, as the run says before it compiles)")
    env_options.add_arguments(train)
    train.add_argument("--replay", choices=["uniform", "prioritized"])
    train.add_argument("--preset",
                       help=f"a named config (default: default) that --FIELD options then change. DQN: {', '.join(sorted(PRESETS))} "
                            "(many-envs is for GPUs: 32 envs per agent, batch 512, 4 updates per iteration; "
                            "docs/training.md); PPO/SAC: the task's recipes in agents/brax_defaults.py")
    train.add_argument("--out", help="directory for config.json, metrics.jsonl, checkpoint and eval.json")
    train.add_argument("--resume", action="store_true",
                       help="continue the run saved in --out from its last checkpoint (env, seeds and config from there)")
    train.add_argument("--checkpoint-every", type=ranged(int, COUNT), default=CHECKPOINT_EVERY, metavar="CHUNKS",
                       help="chunks (of eval_every steps) between checkpoints in --out (default %(default)s)...")
    train.add_argument("--checkpoint-seconds", type=ranged(float, NON_NEGATIVE), default=CHECKPOINT_SECONDS,
                       metavar="S", help=f"...and at least S seconds between them, or {SAVE_COST_FACTOR:g}x the last save's "
                            "duration if longer (default %(default)s; 0: no limit)")
    train.add_argument("--judge-every", type=ranged(int, COUNT), metavar="CHUNKS",
                       help="judge the greedy policy (keep the best parameters, find the solve step) every CHUNKS "
                            "chunks and after the last (default: from the config, saved in config.json: PPO, SAC "
                            f"and TD3 every chunk, DQN as often as keeps a judge within {100 * JUDGE_SHARE:g}%% of "
                            "a chunk's env steps and updates; docs/training.md)")
    train.add_argument("--processes", type=ranged(int, COUNT), metavar="K",
                        help="train the seeds in K child processes, each an ordinary one-device run of its share "
                             "(one GPU each, in turn; on a CPU each uses the CPU), merged into --out (default: "
                             "for an MJX task on a host with several GPUs, as many as --devices says; else 1; "
                             f"also {processes.PROCESSES_ENV}=K; docs/scaling.md)")
    train.add_argument("--rerun", metavar="FILE.rrd", help="log training curves and greedy rollouts to a Rerun file")
    train.add_argument("--overwrite", action="store_true",
                       help="replace the run that --out holds (else refused: --resume continues it) "
                            "and an existing --rerun file")
    train.add_argument("--rerun-every", type=ranged(int, NON_NEGATIVE_COUNT), default=1, metavar="N",
                       help="chunks (PPO/SAC: evaluations) between logged evaluation rollouts (0: none)")

    return train


def _add_sweep(sub, train, cached, tasks, spread) -> None:
    """`mjxsuite sweep`: train's run options, and comma-separated values for the swept fields."""
    from agents import registry

    sweep = sub.add_parser("sweep", parents=[cached, tasks, spread],
                           help="train a grid of configs x seeds as one program; swept fields take comma-separated "
                                "values, other config fields --FIELD VALUE",
                           epilog="sweepable fields: " + "; ".join(f"--agent {agent}: {', '.join(registry.sweepable(agent))}"
                                                                  for agent in AGENTS if registry.sweepable(agent))
                                  + "; writes sweep.json and sweep.png to --out")
    # The options train and sweep share are train's own (one definition; argparse's parents do the same).
    shared = {"env", "agent", "seeds", "seed", "steps", "replay", "preset", "out", "resume", "checkpoint_every",
              "checkpoint_seconds", "judge_every", "rerun", "overwrite"}
    for action in train._actions:
        if action.dest in shared:
            sweep._add_action(action)
    sweep.add_argument("--rerun-every", type=ranged(int, NON_NEGATIVE_COUNT), default=0, metavar="N",
                       help="chunks between logged evaluation rollouts of every agent (default 0: curves only)")
    sweep.add_argument("--plot", metavar="FILE.png", help="solve rate and steps to solve per config "
                                                          "(default: sweep.png in --out; needs matplotlib)")
    for name in sweep_fields():
        sweep.add_argument(f"--{name}", *([f"--{name.replace('_', '-')}"] if "_" in name else []), dest=name,
                           type=float_list, metavar="V1,V2,...", help="values to sweep")



def _add_eval_and_rollout(sub, cached, tasks) -> None:
    """`mjxsuite eval` and `mjxsuite rollout` of a saved run."""
    evaluate = sub.add_parser("eval", help="evaluate a saved run's policies, every seed", parents=[cached, tasks])
    evaluate.add_argument("--checkpoint", required=True, help="a directory written by `mjxsuite train --out`")
    evaluate.add_argument("--episodes", type=ranged(int, COUNT),
                          help="fresh episodes per seed (default: the run's own evaluation's, its eval_episodes)")
    evaluate.add_argument("--seed", type=int, default=123)
    env_options.add_arguments(evaluate)  # given, they change the saved env options for this evaluation

    rollout = sub.add_parser("rollout", help="log a rollout (random, or greedy from a checkpoint) to a Rerun file",
                             parents=[cached, tasks])
    rollout.add_argument("--env", help="registered env name (default: the checkpoint's)")
    rollout.add_argument("--checkpoint", help="a directory written by `mjxsuite train --out`; random actions without")
    rollout.add_argument("--episodes", type=ranged(int, COUNT),
                         help="stop once every env finished this many episodes (default 1)")
    rollout.add_argument("--num-envs", type=ranged(int, COUNT), default=1)
    rollout.add_argument("--steps", type=ranged(int, COUNT), help="steps to run (default: episodes x the time limit)")
    rollout.add_argument("--scene-envs", type=ranged(int, NON_NEGATIVE_COUNT), default=1, help="envs drawn in 3D")
    rollout.add_argument("--plot-envs", type=ranged(int, NON_NEGATIVE_COUNT), default=16,
                         help="envs whose observations etc. are plotted")
    rollout.add_argument("--seed", type=int, default=0)
    rollout.add_argument("--rerun", required=True, metavar="FILE.rrd", help="the Rerun file to write")
    rollout.add_argument("--overwrite", action="store_true", help="replace an existing file")
    env_options.add_arguments(rollout)  # with --checkpoint, they change the saved env options


def main(argv: list[str] | None = None, more: Mapping[str, Command] | None = None) -> int:
    """Run one `mjxsuite` command. `more` adds subcommands by name; the `mjxsuite` script
    (`benchmarks.cli.main`) adds `bench` this way, so this package never imports `benchmarks`."""
    more = more or {}
    parser = build_parser(more)
    args, extra = parser.parse_known_args(argv)
    if args.command in ("train", "sweep") and args.resume and not args.out:
        parser.error("--resume needs --out")
    handlers = {"train": cmd_train, "sweep": cmd_sweep, "eval": cmd_eval, "rollout": cmd_rollout,
                **{name: command.run for name, command in more.items()}}
    handler = handlers[args.command]
    from agents.checkpoint import CheckpointError
    from agents.processes import ProcessFailed
    from envs.mjx_warp import WarpUnavailable  # not envs.mjx_env: that loads mujoco.mjx (start-up time)

    from agents import signals

    if args.command not in ("train", "sweep"):
        signals.release_early()  # only a training run stops at a signal of its own accord
    try:
        if args.command in ("train", "sweep") and (args.deterministic or os.environ.get("MJXSUITE_DETERMINISTIC") == "1"):
            from agents.device_options import make_deterministic

            make_deterministic()  # before any JAX computation
            if getattr(args, "impl", None) == "warp":
                print("note: --deterministic makes XLA's ops deterministic; MuJoCo Warp's physics is not "
                      "(docs/reliability.md): runs with --impl warp still differ from run to run", file=sys.stderr)
        if args.command in ("train", "sweep", "eval", "rollout"):
            _use_compile_cache(args)
            import_tasks(args.imports)
        if args.command in ("train", "sweep"):
            from agents import sharding

            if sharding.distributed_requested(args.distributed):  # before any JAX computation
                sharding.initialize_distributed()
        return handler(args, extra)
    except UsageError as err:
        print(f"mjxsuite: {err}", file=sys.stderr)
        raise
    except (ValueError, FileNotFoundError) as err:  # the envs and agents APIs refuse bad input with these
        print(f"mjxsuite: {err}", file=sys.stderr)
        return 2
    except WarpUnavailable as err:
        print(f"mjxsuite: --impl warp: {err}", file=sys.stderr)
        return 2
    except (CheckpointError, OSError, ProcessFailed) as err:
        print(f"mjxsuite: {err}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
