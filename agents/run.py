"""The run lifecycle, one for every agent (DQN, PPO, SAC): `train_run` drives an agent's pure
chunks (`init`, then `train_steps` and `evaluate_and_keep_best` as two programs) under jit(vmap) for many seeds
(spread over devices by `agents.sharding`, several configs at once for a sweep), and between
chunks owns the run directory, the progress bar, metrics, checkpoints, signals and the final
evaluation (`agents.run_steps` holds those steps). `load_agent` and `load_policy` read any
run directory back."""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np

import envs
from agents import checkpoint, evaluation, registry, run_steps, sharding, signals, traced_programs
from agents.device_options import default_seed_axis, init_compiler_options, training_compiler_options
from agents.dqn import DQNConfig
from agents.registry import per_agent, sweep_configs
from agents.run_steps import CHECKPOINT_EVERY, CHECKPOINT_SECONDS
from envs.mjx_warp import CompileRules, runs_warp
from envs.ranges import COUNT
from envs.registry import is_mjx_task


# The parts of a run's wall time, named as eval.json's `wall_parts_s` and the command's last line
# (`agents.commands.wall_line`) both say them: start-up (setup_s), compile, train, judge, saves,
# evaluation, and other (host_s, the host's work between chunks).
WALL_PARTS = ("start-up", "compile", "train", "judge", "saves", "evaluation", "other")


@dataclass
class RunResult:
    params: Any  # best parameters per seed (leading seed axis)
    train_state: Any
    history: list[dict] = field(default_factory=list)  # one record per evaluation
    mean_return: list[float] = field(default_factory=list)  # final greedy evaluation per seed
    solve_step: list[int | None] = field(default_factory=list)
    # Seconds from the run's start (compile included) to the judge that first reached solve_return;
    # wall_s: the run's whole time. Both span every session of a resumed run: each checkpoint saves
    # the clock so far (`_Run.clock_now`), which a --resume goes on from (the seconds a killed
    # session spent after its last checkpoint are not counted: their work is done again).
    solve_wall_s: list[float | None] = field(default_factory=list)
    wall_s: float = 0.0  # train_run's whole call, every session's; the parts below add up to it
    compile_s: float = 0.0
    # Where the rest of wall_s went: setting up (the env, the first JAX calls, placing the agents,
    # loading a checkpoint), the training chunks, their greedy judges (`run_steps.JudgeClock`),
    # checkpoint saves, the final greedy evaluation (its compile included), and the rest
    # (`host_s`): the host's work between chunks (metrics files, `on_chunk`, e.g. the Rerun logger).
    setup_s: float = 0.0
    train_s: float = 0.0
    judge_s: float = 0.0
    judges: int = 0  # chunks judged
    save_s: float = 0.0
    eval_s: float = 0.0
    host_s: float = 0.0

    def wall_parts(self) -> dict[str, float]:
        """wall_s's parts by name, in the order they happen: eval.json's `wall_parts_s`, under the
        names the command's last line prints (`WALL_PARTS`)."""
        return dict(zip(WALL_PARTS, (self.setup_s, self.compile_s, self.train_s, self.judge_s, self.save_s,
                                     self.eval_s, self.host_s)))

    def finish(self, start: float, earlier: dict | None = None) -> None:
        """Set wall_s to the time since `start` plus the earlier sessions' (`earlier`: the clock the
        checkpoint a --resume began from saved, `checkpoint.saved_clock`), each part to its own
        plus theirs, and host_s to what the other parts leave of wall_s."""
        earlier = earlier or {}
        before = earlier.get("wall_parts_s", {})
        for name, part in zip(WALL_PARTS[:-1], ("setup_s", "compile_s", "train_s", "judge_s", "save_s", "eval_s")):
            setattr(self, part, getattr(self, part) + before.get(name, 0.0))
        self.earlier_wall_s = earlier.get("wall_s", 0.0)
        self.wall_s = time.perf_counter() - start + self.earlier_wall_s
        self.host_s = max(0.0, self.wall_s - self.setup_s - self.compile_s - self.train_s - self.judge_s - self.save_s
                          - self.eval_s)
    earlier_wall_s: float = 0.0  # the earlier sessions' share of wall_s (0 but after a --resume)
    interrupted: bool = False  # SIGINT or SIGTERM; like `stop_after_chunks`, leaves params None and a checkpoint
    stop_signal: str | None = None  # "SIGINT" or "SIGTERM" when interrupted
    chunks_done: int = 0  # chunks the train state has done at the end of this call
    saved_chunks: int | None = None  # chunks the run directory's checkpoint holds (0: none; None: no directory)
    total_chunks: int = 0  # chunks of the whole run
    chunk_unit: str = "chunks"
    started: bool = True  # False: stopped by a signal before the run touched its directory
    devices: int = 1  # devices the agents were spread over (`agents.sharding`)
    processes: int = 1  # processes that trained them, one device each (`agents.processes`)
    best_seed: int = 0  # the seed `load_policy` acts with (`break_ties`)
    diverged: list[int] = field(default_factory=list)  # seeds whose losses became non-finite


def seed_keys(seed: int, seeds: int) -> jax.Array:
    """Independent keys for `seeds` agents (split, never reused)."""
    return run_keys(seed, seeds)[0]


@partial(jax.jit, static_argnums=(0, 1))
def run_keys(seed: int, seeds: int) -> tuple[jax.Array, jax.Array]:
    """A run's keys for `seeds` agents: their training keys (`seed_keys`) and the keys of the
    final evaluation, the same as five random ops each run by itself give, from one small
    program: on a GPU each of those ops compiled its own, which slowed every run's start
    (docs/bench-gpu.json, "dqn-run-keys")."""
    seed_key = jax.random.PRNGKey(seed)
    return jax.random.split(seed_key, seeds), jax.random.split(jax.random.fold_in(seed_key, 1), seeds)


SEED_AXES = ("vmap", "map")


def seed_batched(fn: Callable, seeds: int, seed_axis: str | None = None) -> Callable:
    """`fn` over a leading seed axis, as `seed_axis` says: "vmap" runs the seeds as one
    batched program, "map" one after another (`lax.map`), each as the unbatched program.
    None picks "vmap" on accelerators and "map" on the CPU, whose XLA runs the plain
    matmuls of one network faster than batched ones (docs/bench-cpu.json, "dqn-seed-scaling").
    One seed is always run unbatched."""
    seed_axis = seed_axis or default_seed_axis()
    if seed_axis not in SEED_AXES:
        raise ValueError(f"unknown seed_axis {seed_axis!r}; choose one of {SEED_AXES}")
    if seeds > 1:
        return jax.vmap(fn) if seed_axis == "vmap" else lambda *args: jax.lax.map(lambda a: fn(*a), args)

    def single(*args):
        out = fn(*jax.tree.map(lambda x: x[0], args))
        return jax.tree.map(lambda x: x[None], out)

    return single


def _in_background(work: Callable[[], Any], name: str, after: threading.Event | None = None) -> Future:
    """`work()` on another thread, once `after` is set if given. XLA compiles, and a program runs,
    without holding Python's lock, so the run's inputs are made (on a GPU with the process's first
    allocation) while the programs compile, a fresh run's init program compiles while this thread
    traces and lowers the training chunk and while XLA compiles the chunk, and the final
    evaluation's program compiles while the agents train: each of those is seconds of a short
    run's start. The programs and options are those that compiling them here would give: the
    same results, bit for bit.

    Runs of MuJoCo Warp envs compile beside nothing that runs: their compiles wait (`after`, from
    `envs.mjx_warp.CompileRules.tracing`) until every program is traced, and the run waits for them
    all (docs/mjx.md, "MuJoCo Warp and CUDA graphs")."""
    def waited():
        if after is not None:
            after.wait()
        return work()

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=f"mjxsuite-{name}")
    try:
        return pool.submit(waited)
    finally:
        pool.shutdown(wait=False)  # its one thread ends with its one task


def lower_cached(program: str, fn: Callable, args: tuple, learner: Any, seeds: int, env_name: str,
                 env_options: dict | None, donate: bool = False) -> traced_programs.LoweredProgram:
    """An agent's program (`fn`, for `seeds` seeds of the agent `learner`) lowered for `args`, to compile with the
    training programs' XLA options; with the export cache on (`agents.jax_compile_cache.enable()`),
    its traced program comes from there when an earlier run left it: tracing (`mjx.step` inside
    the training chunk and the evaluation) is most of a warm start."""
    return traced_programs.lower_env_program(program, fn, args, learner.env, env_name, env_options,
                                          extra=key_parts(learner, seeds), donate=donate,
                                          compiler_options=training_compiler_options(env=learner.env))


def lower_evaluation_cached(learner: Any, params: Any, keys: Any, env_name: str, env_options: dict | None,
                            episodes: int | None = None) -> traced_programs.LoweredProgram:
    """Every seed's evaluation over `episodes` fresh episodes (the config's `eval_episodes` when not
    given), lowered through the export cache (`lower_cached`): `(params, keys) -> returns per seed
    and episode`. A run's final evaluation and `mjxsuite eval` of its directory lower the same
    program under the same key, so the command's first call after a run loads the program that the
    run traced and compiled, from the export cache and JAX's compilation cache."""
    episodes = episodes or learner.config.eval_episodes
    seeds = jax.tree.leaves(params)[0].shape[0]
    return lower_cached(f"{type(learner).__name__}.evaluate, {episodes} episodes",
                        jax.vmap(partial(learner.evaluate, num_episodes=episodes)), (params, keys), learner, seeds,
                        env_name, env_options)


def key_parts(learner: Any, seeds: int) -> dict:
    """What an agent's program's export-cache key holds besides the env and the arguments' shapes."""
    return {"config": learner.config, "seeds": seeds}


def _host(tree) -> dict:
    return {k: np.asarray(v).tolist() for k, v in tree.items()}


def train_run(
    env_name: str,
    config: Any = DQNConfig(),  # DQNConfig, PPOConfig, SACConfig or TD3Config: the agent to train
    seeds: int = 1,
    seed: int = 0,
    out_dir: str | Path | None = None,
    resume: bool = False,
    progress: bool = True,
    env_options: dict | None = None,
    on_chunk: Callable[[int, Any, dict], None] | None = None,  # (chunk index, train state, record + "eval_episode")
    stop_after_chunks: int | None = None,
    stop_when_solved: bool = False,
    seed_axis: str | None = None,  # "vmap" or "map" (see `seed_batched`); None: by device
    checkpoint_every: int = CHECKPOINT_EVERY,  # chunks between checkpoints in `out_dir`...
    checkpoint_seconds: float = CHECKPOINT_SECONDS,  # ...and at least these seconds, or SAVE_COST_FACTOR x the
    # last save's duration if longer (0: every checkpoint_every chunks)
    devices: int | None = None,  # devices to spread the agents over; None: all local ones that split them evenly
    sweep: dict[str, list[float]] | None = None,  # a grid over the agent's SWEEPABLE fields: every config x `seeds`
    overwrite: bool = False,  # replace a run that `out_dir` holds (without `resume`); else ValueError
    judge_every: int | None = None,  # judge every this many chunks; None: `run_steps.judge_every`'s cadence
    seed_slice: tuple[int, int] | None = None,  # (start, stop): train only these of the `seeds` (`agents.processes`)
) -> RunResult:
    """Train `seeds` agents (DQN, PPO, SAC or TD3, as `config` says) on `env_name` at once; see
    docs/training.md for the files written to `out_dir`.

    With `resume`, continue the run in `out_dir` (the same env, seeds, seed, config and env
    options, else ValueError) from its last checkpoint, or from the start if it was killed
    before its first: it ends with the parameters of an uninterrupted run.

    The agents (seeds, or with `sweep` every config of the grid times `seeds`, config-major:
    agent `c * seeds + s` is config c with seed s's key) are spread over `devices` devices
    (`agents.sharding`; in a multi-host run every device of every process). One device runs
    the same program as ever; several give every agent the same result.

    With `seed_slice` (start, stop) the run trains seeds start..stop-1 of `seeds`, each with the
    keys a run of all `seeds` gives it, so it ends as that run's seeds do: `agents.processes`
    trains a run's seeds in several processes this way.

    The run's steps, in order (`_Run`): check the settings and open the run directory; compile the
    programs (in the background); train the chunks, each judged on the config's cadence and saved
    on the save clock; then the final evaluation, the tie-break, the final save and eval.json."""
    with signals.StopSignals() as stop:  # SIGINT/SIGTERM: stop between chunks, save, return
        run = _Run(stop, env_name, config, seeds, seed, out_dir, resume, env_options, sweep, judge_every, seed_slice,
                   devices, overwrite, run_steps.SaveClock(checkpoint_every, checkpoint_seconds))
        try:
            if run.placement.same_on_every_process(stop.requested is not None):  # a signal while the command started
                return run.not_started()
            run.compile_programs(progress, record_episode=on_chunk is not None, seed_axis=seed_axis,
                                 evaluates=stop_after_chunks is None or stop_after_chunks >= config.num_chunks)
            run.train_chunks(progress, on_chunk, stop_after_chunks, stop_when_solved)
            return run.finish()
        finally:
            run.lock.release()


class _Run:
    """One `train_run`: its checked settings, and what each of its steps hands the next (the
    programs, the train state, the clocks, the result). Its methods are the steps, in order."""

    def __init__(self, stop: signals.StopSignals, env_name: str, config: Any, seeds: int, seed: int, out_dir,
                 resume: bool, env_options: dict | None, sweep: dict | None, judge_every: int | None,
                 seed_slice: tuple[int, int] | None, devices: int | None, overwrite: bool,
                 clock: run_steps.SaveClock):
        self.start, self.stop, self.clock = time.perf_counter(), stop, clock
        COUNT.check("seeds", seeds)
        self.first, stop_seed = seed_slice or (0, seeds)
        if not 0 <= self.first < stop_seed <= seeds:
            raise ValueError(f"seed_slice {seed_slice} must be (start, stop) with 0 <= start < stop <= seeds ({seeds})")
        if seed_slice is not None and sweep:
            raise ValueError("seed_slice trains part of a train run's seeds; a sweep runs in one process")
        self.env_name, self.config, self.seeds, self.seed, self.env_options = env_name, config, seeds, seed, env_options
        self.stop_seed, self.trained_seeds, self.resume = stop_seed, stop_seed - self.first, resume
        if resume and judge_every is None and out_dir is not None and (Path(out_dir) / checkpoint.CONFIG_FILE).is_file():
            judge_every = checkpoint.load_config(out_dir).judge_every  # the run's own cadence
        self.sweep = sweep or None
        self.configs = sweep_configs(config, self.sweep)
        self.agents = self.trained_seeds * len(self.configs)
        self.env = envs.make(env_name, **(env_options or {}))
        why = registry.misfit(registry.name_of(config), env_name, self.env.num_actions, self.env.action_size,
                              getattr(self.env, "observation_shape", None) is not None)
        if why:  # before anything compiles: DQN's network on camera images fails inside JAX's trace
            raise ValueError(why)
        if judge_every is None:  # from the config and the time limit (`run_steps.judge_every`), saved in config.json
            judge_every = run_steps.judge_every(config, getattr(self.env, "episode_length", None) or 1000)
        self.judge_clock = run_steps.JudgeClock(judge_every, config.num_chunks - 1)
        mjx_task = env_name if is_mjx_task(self.env) else None  # not envs.MjxEnv: it loads mujoco.mjx (start-up time)
        self.placement = sharding.Placement(sharding.choose_devices(self.trained_seeds, devices,
                                                                    configs=len(self.configs), mjx_task=mjx_task))
        self.writer = sharding.is_writer()  # in a multi-host run only process 0 writes; every process reads
        self.agent = registry.name_of(config)
        self.saved_run = checkpoint.SavedRun(env_name, seeds, config, env_options or {}, seed, self.sweep, self.agent,
                                             judge_every, None if seed_slice is None else tuple(seed_slice))
        self.out = run_steps.open_run_dir(out_dir, self.saved_run, resume, self.writer, overwrite)
        self.lock = run_steps.RunDirLock(self.out if self.writer else None)
        self.saves = checkpoint.BackgroundSaves()

    def not_started(self) -> RunResult:
        """The result of a run that a signal stopped before anything compiled."""
        saved = checkpoint.chunks_saved(self.out) if self.out is not None and self.resume else 0
        return RunResult(params=None, train_state=None, interrupted=True, stop_signal=self.stop.name,
                         saved_chunks=None if self.out is None else saved, total_chunks=self.config.num_chunks,
                         wall_s=time.perf_counter() - self.start, started=False)

    # ---- the programs ------------------------------------------------------------------------
    def compile_programs(self, progress: bool, record_episode: bool, seed_axis: str | None, evaluates: bool) -> None:
        """Every program the run needs, compiled in the background (`_in_background`): the inputs
        and the init program (or the checkpoint, on resume), a chunk's training steps and its judge,
        the final evaluation and, on a GPU, the tie-break over every seed. Without `on_chunk` nobody
        sees the judge's episode (`record_episode` False): the chunk records none (less to compile;
        the same train state and metrics). In a multi-host run the final evaluation's arrays are
        gathered and placed anew: it compiles at the end. MuJoCo Warp's rules:
        `envs.mjx_warp.CompileRules` (docs/mjx.md, "MuJoCo Warp and CUDA graphs")."""
        self.learner = registry.make(self.config, self.env, agents=self.agents // self.placement.count)
        self.rules = CompileRules(runs_warp(self.learner.env))
        self.parts = run_steps.chunk_parts(self.config) if hasattr(self.learner, "chunk_loop") else 1
        if progress and self.writer:  # the bar comes once the programs are compiled: seconds, a minute or two on a GPU
            builds = " (MuJoCo Warp also builds its kernels once per machine)" if self.rules.on_warp else ""
            print(f"{self.env_name}: compiling{builds}...", file=sys.stderr, flush=True)
        self.evaluates = evaluates and jax.process_count() == 1
        self.final_evaluation = self.every_seed = None
        with self.rules.tracing() as after_traces:
            inputs, init_program, init_args = self._lower_state(after_traces)
            train_program, judge_program = self._lower_chunk(record_episode, seed_axis or default_seed_axis(),
                                                             after_traces)
            self.params_shape = self.placement.abstract(self.ts.best_params)
            if self.evaluates and self.rules.on_warp:  # compiled with the others, before any Warp kernel runs
                self.final_evaluation = _in_background(
                    self.lower_evaluation(self.params_shape, self.eval_keys).compile, "evaluation", after=after_traces)
        self.judge_program = None if judge_program is None else judge_program.compile()
        self.train_program = None if train_program is None else train_program.result()
        init_args, self.eval_keys = inputs.result()
        if self.final_evaluation is not None:
            self.final_evaluation.result()
        if init_program is not None:
            self.ts = init_program.result()(*init_args)
        self.compile_s = time.perf_counter() - self.compile_start  # a fresh run's init program included
        if self.evaluates and not self.rules.on_warp:
            self._compile_final_beside_training()

    def _run_inputs(self):
        """The init program's arguments and the final evaluation's keys."""
        keys, eval_keys = run_keys(self.seed, self.seeds)
        if self.sweep is None:  # every seed's keys made, these seeds' kept: the same keys whatever the slice
            return (keys[self.first:self.stop_seed],), eval_keys[self.first:self.stop_seed]
        configs = len(self.configs)
        return (jnp.tile(keys, (configs, 1)), per_agent(self.configs, self.seeds)), jnp.tile(eval_keys, (configs, 1))

    def _lower_state(self, after_traces):
        """The inputs, made on another thread while the programs compile from their shapes (making
        them runs the keys' program, and on a GPU the first allocation, where XLA reserves most of
        the device's memory; on several devices, their placement too); the train state's shapes
        from the checkpoint (resume) or from the init program, compiling on another thread."""
        placement = self.placement
        inputs = _in_background(lambda: placement.put(self._run_inputs()), "inputs", after=after_traces)
        init = jax.jit(placement.spread(jax.vmap(self.learner.init)), compiler_options=init_compiler_options())
        init_args, self.eval_keys = placement.abstract(jax.eval_shape(self._run_inputs))
        self.chunks_done, init_program = 0, None
        self.compile_start = time.perf_counter()
        self.earlier = {}  # the clock of the sessions before this one (`RunResult.finish`)
        if self.resume and checkpoint.has_state(self.out):
            ts, self.chunks_done = checkpoint.load_state(self.out, self.env_name, jax.eval_shape(init, *init_args))
            self.earlier = checkpoint.saved_clock(self.out)
            self.ts = placement.put(ts)  # saved from any number of devices, split over this run's
            self.compile_start = time.perf_counter()  # compile_s: the chunk's compile alone
        else:  # a run killed before its first checkpoint resumes from the start, as it began
            traced = init.trace(*init_args)
            init_program = _in_background(traced.lower().compile, "init", after=after_traces)
            self.ts = placement.abstract(traced.out_info)  # the train state's shapes (weak types kept) and placement
            if self.out is not None and self.writer:
                checkpoint.start_run(self.out, self.saved_run)
        if self.out is not None and self.writer:
            checkpoint.keep_metrics(self.out, self.chunks_done)
        return inputs, init_program, init_args

    def _lower_chunk(self, record_episode: bool, seed_axis: str, after_traces):
        """A chunk's two programs, its training steps (compiling on another thread) and its judge
        (lowered, compiled by the caller). One device: each holds a copy of the env's step, and
        together were one program that XLA compiled alone; tracing and lowering hold Python's
        lock, XLA's compile does not, so the training steps are traced first and compile while this
        thread traces the judge. Several devices: two sharded programs are faster than one
        (docs/bench-gpu.json, "dqn-sharded-programs"). A finished run (resumed to evaluate) has none."""
        if self.chunks_done >= self.config.num_chunks:
            return None, None
        learner, ts, per_device = self.learner, self.ts, self.agents // self.placement.count
        if self.parts > 1:  # a chunk in parts (`_in_parts`): the first part's state is kept, so none is donated
            return self._lower_parts(per_device, seed_axis, after_traces), self._lower_judge(
                per_device, seed_axis, record_episode)
        train_fn = seed_batched(partial(_train_steps, learner), per_device, seed_axis)
        judge_fn = seed_batched(partial(learner.evaluate_and_keep_best, record=record_episode), per_device, seed_axis)
        if self.placement.mesh is None:
            kind = type(learner).__name__  # names its programs in the export cache
            judged = (f"{kind}.evaluate_and_keep_best over seeds by {seed_axis}"
                      + ("" if record_episode else ", no episode recorded"))
            lowered = lower_cached(f"{kind}.train_steps over seeds by {seed_axis}", train_fn, (ts,), learner,
                                   self.agents, self.env_name, self.env_options, donate=True)
            train_program = _in_background(lowered.compile, "train", after=after_traces)
            return train_program, lower_cached(judged, judge_fn, (ts, ts.key), learner, self.agents, self.env_name,
                                               self.env_options, donate=True)
        # sharded programs skip the traced-program cache (JAX's compilation cache still applies)
        options = training_compiler_options(env=learner.env)
        spread = self.placement.spread
        train_program = _in_background(partial(jax.jit(spread(train_fn), donate_argnums=0).lower(ts).compile, options),
                                       "train", after=after_traces)
        return train_program, traced_programs.LoweredProgram(
            jax.jit(spread(judge_fn), donate_argnums=0).lower(ts, ts.key), options)

    def _lower_parts(self, per_device: int, seed_axis: str, after_traces) -> Future:
        """The program of one part of a chunk (`evaluation.chunk_part`), compiling on another thread,
        and the carry its first part starts from."""
        learner, ts, parts = self.learner, self.ts, self.parts
        part_fn = seed_batched(partial(_train_part, learner, parts), per_device, seed_axis)
        self.carry_shapes = jax.eval_shape(jax.vmap(partial(evaluation.part_carry, learner.chunk_loop)), ts)
        carry = self.placement.abstract(self.carry_shapes)
        if self.placement.mesh is None:
            lowered = lower_cached(f"{type(learner).__name__}.chunk_part of {parts} over seeds by {seed_axis}",
                                   part_fn, (ts, carry), learner, self.agents, self.env_name, self.env_options)
            return _in_background(lowered.compile, "train", after=after_traces)
        options = training_compiler_options(env=learner.env)
        return _in_background(partial(jax.jit(self.placement.spread(part_fn)).lower(ts, carry).compile, options),
                              "train", after=after_traces)

    def _lower_judge(self, per_device: int, seed_axis: str, record_episode: bool) -> traced_programs.LoweredProgram:
        """The judge's program, lowered (`_lower_chunk` for a chunk in parts)."""
        learner, ts = self.learner, self.ts
        judge_fn = seed_batched(partial(learner.evaluate_and_keep_best, record=record_episode), per_device, seed_axis)
        if self.placement.mesh is None:
            judged = (f"{type(learner).__name__}.evaluate_and_keep_best over seeds by {seed_axis}"
                      + ("" if record_episode else ", no episode recorded"))
            return lower_cached(judged, judge_fn, (ts, ts.key), learner, self.agents, self.env_name,
                                self.env_options, donate=True)
        return traced_programs.LoweredProgram(jax.jit(self.placement.spread(judge_fn), donate_argnums=0).lower(
            ts, ts.key), training_compiler_options(env=learner.env))

    def lower_evaluation(self, params: Any, keys: Any) -> Any:
        """The final evaluation, lowered for these shapes."""
        if self.placement.mesh is None:
            return lower_evaluation_cached(self.learner, params, keys, self.env_name, self.env_options)
        return jax.jit(self.placement.spread(jax.vmap(self.learner.evaluate))).lower(params, keys)

    def _compile_final_beside_training(self) -> None:
        """The final evaluation's program, compiling while the agents train; on a GPU also the
        tie-break's program for every seed: thousands of seeds can tie there (CartPole's held to
        the time limit), and it serves where at least half of them tie. On a CPU, measuring every
        seed costs more than compiling for the tied ones."""
        self.final_evaluation = _in_background(
            lambda: self.lower_evaluation(self.params_shape, self.eval_keys).compile(), "evaluation")
        if self.agents > 1 and self.placement.devices[0].platform == "gpu":
            tie_keys = jax.eval_shape(lambda: tie_break_keys(self.seed, jnp.arange(self.agents)))
            self.every_seed = _in_background(partial(every_seed_tie_break, self.learner, self.env_name,
                                                     self.env_options, self.placement, self.params_shape, tie_keys),
                                             "tie-break")

    # ---- the chunks --------------------------------------------------------------------------
    def train_chunks(self, progress: bool, on_chunk, stop_after_chunks: int | None, stop_when_solved: bool) -> None:
        """Train the chunks from the last checkpoint's on, judging on the config's cadence and saving
        on the save clock, until the last chunk, `stop_after_chunks`, a signal or (with
        `stop_when_solved`) every agent solved. The next chunk is dispatched before this one's host
        work (its metrics to JSON, the bar), so the device trains on while the host works, where
        nothing of that work can change what the next chunk does: no `on_chunk` (it is handed the
        train state, which the next chunk consumes), no stop when solved, no save due, no signal,
        and signals caught (where they are not, a KeyboardInterrupt could come with a chunk in
        flight and its state unlogged)."""
        config = self.config
        self.result = RunResult(params=None, train_state=self.ts, compile_s=self.compile_s,
                                solve_wall_s=list(self.earlier.get("solve_wall_s") or [None] * self.agents),
                                devices=self.placement.count,
                                setup_s=self.compile_start - self.start, total_chunks=config.num_chunks)
        prefill = getattr(config, "prefill_steps", 0)  # SAC's and TD3's first fill of the replay, in `init`
        self.bar = run_steps.progress_bar(prefill + config.num_chunks * config.eval_every,
                                          prefill + self.chunks_done * config.eval_every, self.env_name,
                                          enabled=progress and self.writer)
        self.clock.last = self.chunks_done
        self.clock.expect(sum(leaf.nbytes for leaf in jax.tree.leaves(self.ts)))  # the first save, before one is timed
        self.last, self.solved_early, self.overflow_told = self.chunks_done, False, False
        self.on_chunk, self.stop_when_solved = on_chunk, stop_when_solved
        self.look_ahead = on_chunk is None and not stop_when_solved and self.stop.catching and self.parts == 1
        self.bar_ahead = 0  # env steps the bar moved within the chunk under way (`_in_parts`)
        self.stop_at = config.num_chunks if stop_after_chunks is None else min(config.num_chunks, stop_after_chunks)
        ahead = None  # the next chunk, `_dispatched` early
        try:
            for index in range(self.chunks_done, config.num_chunks):
                if ahead is None:
                    if index >= self.stop_at:
                        break
                    if self._signalled():  # a signal during compile, a chunk or a save
                        self.result.interrupted = True
                        break
                    ahead = self._dispatched(self.ts)
                (self.ts, metrics, eval_key), tick = ahead
                if metrics is None:  # a signal between the parts of a chunk (`_in_parts`)
                    self.result.interrupted = True
                    break
                ahead = self._after_chunk(index, metrics, eval_key, tick)
                if self.solved_early:
                    break
        except KeyboardInterrupt:  # only where no handler could be installed (not the main thread)
            self.result.interrupted = True
        finally:
            self.bar.close()
            self.result.train_state = self.ts

    def _signalled(self) -> bool:
        return self.placement.same_on_every_process(self.stop.requested is not None)

    def _dispatched(self, ts):
        """The next chunk's outputs and when it began (a dispatch can return only once done)."""
        began = time.perf_counter()
        return (self.train_program(ts) if self.parts == 1 else self._in_parts(ts)), began

    def _in_parts(self, ts):
        """A chunk as `self.parts` programs (`evaluation.chunk_part`), with the result of one: the bar
        moves after each part, and a signal between parts drops the chunk under way, returning
        (its start state, None, None): the state of the chunks done, which the run then saves."""
        carry, start = self.placement.put(jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), self.carry_shapes)), ts
        steps = self.config.eval_every // self.parts
        for part in range(self.parts):
            ts, carry, metrics, eval_key = self.train_program(ts, carry)
            if part < self.parts - 1:
                jax.block_until_ready(carry)
                self.bar.update(steps)
                self.bar_ahead += steps
                if self._signalled():
                    return start, None, None
        return ts, metrics, eval_key

    def _save_due(self, done: int) -> bool:
        """A periodic save; a run's last chunk is the final save's (`finish`). Process 0's clock."""
        return self.placement.same_on_every_process(self.out is not None and done < self.config.num_chunks
                                                    and self.clock.due(done))

    def _after_chunk(self, index: int, metrics: dict, eval_key, tick: float):
        """A trained chunk's judge (on the cadence), its record and a periodic save; returns the next
        chunk where it was dispatched ahead (`train_chunks`), else None."""
        judging, eval_episode, placement = self.judge_clock.due(index), None, self.placement
        # The whole chunk done, its train state too, so that its seconds are its own however its
        # dispatch returned (one through MuJoCo Warp's FFI can return once it is done).
        jax.block_until_ready((self.ts, metrics))
        trained_at = time.perf_counter()
        if judging:
            self.ts, judged = self.judge_program(self.ts, eval_key)
            eval_episode = judged.pop("eval_episode")
            metrics = {**judged, **metrics}
            if self.on_chunk is not None and jax.process_count() > 1:  # other hosts' agents too, for the logger
                eval_episode = placement.to_host(eval_episode)
        self.last = index + 1
        look = (self.look_ahead and self.last < self.stop_at and not self._save_due(self.last)
                and not self._signalled())
        ahead = self._dispatched(self.ts) if look and not judging else None  # the device trains on meanwhile
        record = _host(placement.to_host(metrics))
        if judging:
            self.judge_clock.judged(time.perf_counter() - trained_at)
            if look:  # after the judge's results reached the host, whose seconds are the judge's
                ahead = self._dispatched(self.ts)
        self.result.train_s += trained_at - tick
        record["chunk"] = index
        record["steps_per_s"] = self.config.eval_every * self.agents / (trained_at - tick)  # as Brax's training/sps
        self._observe(index, record, eval_episode, judging)
        if ahead is None and not self.solved_early and self._save_due(self.last):
            self._checkpoint(self.ts, self.last)  # written while the next chunks train
        return ahead

    def _observe(self, index: int, record: dict, eval_episode, judging: bool) -> None:
        """What watches a chunk's record: MuJoCo Warp's overflow, diverged seeds, the solve times,
        metrics.jsonl, `on_chunk` (e.g. the Rerun logger) and the progress bar."""
        config, result = self.config, self.result
        self.overflow_told = _check_overflow(self.env, record, config.eval_every, self.bar, self.overflow_told)
        _check_diverged(record, result.diverged, self.first, self.bar)
        result.history.append(record)
        now = time.perf_counter() - self.start + self.earlier.get("wall_s", 0.0)
        for i, solve in enumerate(np.atleast_1d(record.get("eval_return", []))):
            if config.solve_return is not None and solve >= config.solve_return and result.solve_wall_s[i] is None:
                result.solve_wall_s[i] = now
        if self.writer:
            run_steps.append_metrics(self.out, record)
        if self.on_chunk is not None:
            self.on_chunk(index, self.ts, {**record, "eval_episode": eval_episode})
        run_steps.show(self.bar, config.eval_every - self.bar_ahead, record)
        self.bar_ahead = 0
        self.solved_early = self.stop_when_solved and judging and None not in result.solve_wall_s

    def _checkpoint(self, state: Any, done: int, final: bool = False) -> None:
        """A save of `state` after `done` chunks, timed on the save clock."""
        save_start = time.perf_counter()
        save(self.saves, self.out, self.env_name, self.placement, state, done, final=final,
             finished=done == self.config.num_chunks, copy_beside=self.rules.host_copy_beside,
             clock=self.clock_now())
        self.clock.saved(done, save_start, self.saves.written_s)
        self.result.save_s += time.perf_counter() - save_start

    def clock_now(self) -> dict:
        """The run's clock so far, every session's: wall_s, its parts and solve_wall_s, saved with
        each checkpoint (`checkpoint.saved_clock`) for a --resume to go on from."""
        now = dataclasses.replace(self.result, judge_s=self.judge_clock.judge_s)
        now.finish(self.start, self.earlier)
        return {"wall_s": now.wall_s, "wall_parts_s": now.wall_parts(), "solve_wall_s": now.solve_wall_s}

    # ---- the end -------------------------------------------------------------------------------
    def _evaluated(self):
        """Every agent's returns from the final evaluation, dispatched."""
        evaluate = (self.final_evaluation.result() if self.final_evaluation is not None
                    else self.lower_evaluation(self.ts.best_params, self.eval_keys).compile())
        return evaluate(self.ts.best_params, self.eval_keys)

    def finish(self) -> RunResult:
        """The final save, and for a finished run the final evaluation, the tie-break and eval.json.
        A stopped run (a signal, `stop_after_chunks`) keeps its checkpoint and evaluates nothing."""
        result, ts = self.result, self.ts
        finished = self.last == self.config.num_chunks or self.solved_early
        # The final evaluation, where it compiled beside training, is dispatched before the final save:
        # the save's copy to the host, made on this thread where the agents are spread over devices, then
        # runs while the devices evaluate. MuJoCo Warp's rules put it after the save (`CompileRules`).
        eval_start = time.perf_counter()
        early = (finished and not result.interrupted and self.final_evaluation is not None
                 and self.rules.evaluate_before_final_save)
        returns = self._evaluated() if early else None
        eval_s = time.perf_counter() - eval_start
        # Not after other errors: the last periodic checkpoint stands (a failed save must not be retried
        # over it, and a failed chunk may have consumed its donated train state).
        if self.out is not None and self.clock.last != self.last:
            self._checkpoint(ts, self.last, final=True)  # copied and written during the final evaluation
        result.chunks_done, result.saved_chunks = self.last, self.clock.last if self.out is not None else None
        result.judges = sum(map(self.judge_clock.due, range(self.last)))  # every session's, by the config's cadence
        result.judge_s = self.judge_clock.judge_s
        # A signal during the last chunk or save stops without the final evaluation's results (it cannot be
        # cut short once it runs, and one dispatched early is left to end): the checkpoint holds every
        # chunk, and --resume evaluates.
        signalled = self._signalled()  # on every process (a collective where there are several)
        result.interrupted = result.interrupted or signalled
        result.stop_signal = self.stop.name or ("SIGINT" if result.interrupted else None)
        if result.interrupted or not finished:  # checkpoint saved, no final eval
            result.save_s += _waited(self.saves)
            result.finish(self.start, self.earlier)
            return result
        self.stop.finishing("its final evaluation and writes eval.json")  # a signal now says so, and stops nothing
        eval_start = time.perf_counter()
        placement = self.placement
        result.params = ts.best_params if jax.process_count() == 1 else placement.to_host(ts.best_params)
        result.solve_step = [s if s >= 0 else None for s in np.asarray(placement.to_host(ts.solve_step)).tolist()]
        returns = self._evaluated() if returns is None else returns
        result.mean_return = np.asarray(placement.to_host(returns.mean(axis=-1))).tolist()
        every_seed = self.every_seed.result() if self.every_seed else None
        result.best_seed, tie_break = break_ties(self.learner, self.env_name, self.env_options, result.params,
                                                 result.mean_return, self.seed, self.first, every_seed=every_seed)
        result.eval_s = eval_s + time.perf_counter() - eval_start
        result.save_s += _waited(self.saves)
        result.finish(self.start, self.earlier)
        if self.writer:
            run_steps.write_eval(self.out, self._summary(tie_break))
        return result

    def _summary(self, tie_break: dict[int, float]) -> dict:
        """eval.json: the same keys for every agent (docs/training.md)."""
        result = self.result
        return {"agent": self.agent, "env": self.env_name, "seeds": self.trained_seeds, "best_seed": result.best_seed,
                "mean_return": result.mean_return, "solve_step": result.solve_step,
                "solve_wall_s": result.solve_wall_s, "wall_s": result.wall_s, "compile_s": result.compile_s,
                "devices": self.placement.count, "wall_parts_s": result.wall_parts(),
                "judged_chunks": result.judges, "chunks": result.chunks_done,
                "tie_break_return": [tie_break.get(self.first + i) for i in range(self.agents)],
                "diverged_seeds": result.diverged}


def _waited(saves: checkpoint.BackgroundSaves) -> float:
    """Seconds spent waiting for the save under way to reach the disk."""
    start = time.perf_counter()
    saves.wait()
    return time.perf_counter() - start


def _train_steps(learner: Any, ts: Any) -> tuple[Any, dict, jax.Array]:
    """`learner.train_steps(ts)` with the env steps done in its metrics: a chunk the judge skips
    still says where the run stands (the logger's timeline, metrics.jsonl)."""
    ts, metrics, eval_key = learner.train_steps(ts)
    return ts, {**metrics, "env_steps": ts.env_steps}, eval_key


def _train_part(learner: Any, parts: int, ts: Any, carry: tuple) -> tuple:
    """One of `parts` parts of a chunk (`evaluation.chunk_part`), its metrics with the env steps
    done (`_train_steps`)."""
    ts, carry, metrics, eval_key = evaluation.chunk_part(learner.chunk_loop(ts), parts, ts, carry)
    return ts, carry, {**metrics, "env_steps": ts.env_steps}, eval_key


def _check_diverged(record: dict, diverged: list[int], first: int, bar) -> None:
    """Say once per seed when a chunk's losses became non-finite (the seed diverged), and add it to
    `diverged` (run seed indices): its best parameters so far stay, the other seeds train on."""
    losses = [np.atleast_1d(np.asarray(v, dtype=np.float64)) for k, v in record.items() if k.endswith("loss")]
    if not losses:
        return
    bad = ~np.isfinite(np.stack(losses)).all(axis=0)
    for i in np.flatnonzero(bad):
        if first + i not in diverged:
            diverged.append(int(first + i))
            bar.write(f"seed {first + i} diverged in chunk {record['chunk']}: its loss is not finite. Its best "
                      "parameters so far stay its policy; the other seeds train on (a lower learning_rate or "
                      "max_grad_norm may keep it finite)")


def _check_overflow(env: envs.Env, record: dict, chunk_steps: int, bar, told: bool) -> bool:
    """`run_steps.check_overflow` for a chunk's record (the most any agent's steps overflowed)."""
    return run_steps.check_overflow(env, int(np.max(record.get("overflow_contacts", 0))),
                                 int(np.max(record.get("overflow_constraints", 0))), chunk_steps, "env-steps",
                                 f"chunk {record['chunk']}", "they ended their episodes and stayed out of the replay",
                                 bar, told)


TIE_BREAK_LENGTH = 4  # a tie-break's episodes are this many time limits long...
TIE_BREAK_EPISODES = 4  # ...and this many times as many as an evaluation's


def tie_break_program(agent: Any, env_name: str, env_options: dict | None,
                      placement: sharding.Placement | None = None) -> Callable:
    """The tie-break's longer evaluation over a batch of agents, jitted: `(params, keys) -> mean
    return per agent` (`break_ties`); with `placement`, the agents spread over its devices."""
    options = dict(env_options or {})
    length = getattr(agent.env, "episode_length", None)
    if length is not None and "episode_length" in envs.options(env_name):
        options["episode_length"] = TIE_BREAK_LENGTH * length
    longer = registry.make(agent.config, envs.make(env_name, **options))
    episodes = TIE_BREAK_EPISODES * agent.config.eval_episodes
    measure = jax.vmap(lambda p, k: longer.evaluate(p, k, episodes).mean())
    return jax.jit(measure if placement is None else placement.spread(measure))


def every_seed_tie_break(agent: Any, env_name: str, env_options: dict | None, placement: sharding.Placement,
                         params: Any, keys: Any) -> Callable:
    """`tie_break_program` for every row of `params`, spread by `placement`, compiled for `params`'
    and `keys`' shapes (arrays, or their shapes before the arrays exist): `break_ties`' `every_seed`,
    `(params, keys) -> mean return per agent`, which places the host's keys as the agents are."""
    program = tie_break_program(agent, env_name, env_options, placement).lower(
        placement.abstract(params), placement.abstract(keys)).compile()
    return lambda params, keys: program(params, placement.put(keys))


def tie_break_keys(seed: int, indices: Any) -> jax.Array:
    """The tie-break's key of each seed, by its index in the run."""
    tie_key = jax.random.fold_in(jax.random.PRNGKey(seed), 2)
    return jax.vmap(lambda i: jax.random.fold_in(tie_key, i))(jnp.asarray(indices))


def tied_seeds(returns: list[float]) -> np.ndarray:
    """The indices of the seeds that tie for the best final evaluation (`break_ties`)."""
    returns = np.nan_to_num(np.asarray(returns, dtype=np.float64), nan=-np.inf)  # a diverged seed never ties
    best = returns.max()
    if not np.isfinite(best):  # no seed has a finite return: the first stands
        return np.zeros(1, dtype=np.int64)
    return np.flatnonzero(returns >= best - 1e-6 * max(1.0, abs(best)))


def unmeasured_ties(returns: list[float], measured: dict[int, float] | None, first: int = 0) -> list[int]:
    """The tied seeds (indices into `returns`) whose longer evaluation `break_ties` has yet to run:
    none where one seed is best or `measured` holds every tied one's (by run seed index)."""
    tied = tied_seeds(returns)
    return [] if len(tied) == 1 else [int(i) for i in tied if first + i not in (measured or {})]


def break_ties(agent: Any, env_name: str, env_options: dict | None, params: Any, returns: list[float],
               seed: int, first: int = 0, measured: dict[int, float] | None = None,
               every_seed: Callable | None = None) -> tuple[int, dict[int, float]]:
    """The best seed by the final evaluation (an index into `returns`); seeds that tie there (many
    CartPole seeds hold every episode to its time limit) are told apart by a longer evaluation:
    more episodes, each TIE_BREAK_LENGTH time limits long where the task takes `episode_length`,
    so a policy that only holds out to the limit loses to one that keeps balancing. Ties after
    that go to the first. Also returns the tied seeds' longer returns, by run seed index.

    `returns` (and `params`' rows) are the run's seeds `first`, `first + 1`, ...: a seed's longer
    evaluation draws its keys from its index in the run, so a process of a run measures its
    seeds as one process of the whole run would, and the merge (`agents.processes`) passes
    those (`measured`) instead of measuring them again. `every_seed`, `tie_break_program`
    compiled ahead for all of `params`' rows, measures them all where at least half of them are
    to be measured (else the tied seeds' program is compiled here)."""
    tied = tied_seeds(returns)
    if len(tied) == 1:
        return int(tied[0]), {}
    longer_returns = {index: value for index, value in (measured or {}).items() if index - first in tied}
    missing = unmeasured_ties(returns, measured, first)
    if missing:
        if every_seed is not None and 2 * len(missing) >= len(returns):
            measured_now = np.asarray(every_seed(params, tie_break_keys(seed, first + jnp.arange(len(returns)))))[missing]
        else:
            candidates = jax.tree.map(lambda x: jnp.asarray(x)[np.asarray(missing)], jax.device_get(params))
            measured_now = tie_break_program(agent, env_name, env_options)(
                candidates, tie_break_keys(seed, first + jnp.asarray(missing)))
        longer_returns.update({first + i: float(v) for i, v in zip(missing, np.asarray(measured_now))})
    best = max(tied, key=lambda i: (longer_returns[first + i], -i))
    return int(best), {first + int(i): longer_returns[first + int(i)] for i in tied}


def save(saves: checkpoint.BackgroundSaves, out: Path, env_name: str, placement: sharding.Placement, ts: Any,
         chunks_done: int, final: bool = False, finished: bool = False, copy_beside: bool = True,
         clock: dict | None = None) -> None:
    """A checkpoint of every agent, gathered to the host (on every process; process 0 writes it).

    The files are written on another thread while the run goes on (the next chunks, or the final
    evaluation): what waits is the copy to the host and the previous save's write, if still under
    way. Each write is atomic, so a kill loses at most the chunks since the last save on disk (one
    checkpoint interval, plus the write under way). A CPU's host arrays can share memory with the
    device buffers that the next chunk reuses: those are copied. The `final` save's arrays are
    used by nothing after it (the final evaluation reads them, nothing donates them): on one
    device its copy to the host is made on the writing thread too (arrays split over devices are
    copied here: never fetched by two threads at once), unless `copy_beside` is False (an env on
    MuJoCo Warp: `envs.mjx_warp.CompileRules`, docs/mjx.md "MuJoCo Warp and CUDA graphs"). A
    `finished` run's replay buffers are neither copied nor written (`checkpoint.without_replay`).
    `clock`: the run's clock at the save (`_Run.clock_now`), saved beside the state."""
    if finished:
        ts = checkpoint.without_replay(ts)
    if final and copy_beside and placement.mesh is None and jax.process_count() == 1:
        saves.save(out, env_name, partial(placement.to_host, ts), chunks_done, finished, clock)
        return
    host = placement.to_host(ts)
    if sharding.is_writer():
        if placement.devices[0].platform == "cpu":
            host = jax.tree.map(lambda x: x if isinstance(x, np.ndarray) and x.flags.owndata else np.array(x), host)
        saves.save(out, env_name, host, chunks_done, finished, clock)


def load_agent(out_dir: str | Path, env: envs.Env | None = None) -> tuple[str, envs.Env, Any, Any]:
    """`(env_name, env, agent, best_params)` from a `mjxsuite train --out` directory, whatever
    the agent (DQN, PPO, SAC); `best_params` has a leading seed axis. `env`: the saved env made
    here (`checkpoint.saved_env`, the default), or one with other options."""
    saved = checkpoint.load_config(out_dir)
    env = env or checkpoint.saved_env(out_dir)[1]
    agent = registry.make(saved.config, env)
    agents = saved.trained_seeds * len(sweep_configs(saved.config, saved.sweep))
    template = jax.eval_shape(jax.vmap(agent.init), seed_keys(0, agents)).best_params
    return saved.env, env, agent, checkpoint.load_best_params(out_dir, template)


def pick_seed(out_dir: str | Path, params: Any, seed_index: int | None = None) -> Any:
    """One seed's parameters: `seed_index`, or the run's best seed (`checkpoint.best_seed`)."""
    seeds = jax.tree.leaves(params)[0].shape[0]
    seed_index = checkpoint.best_seed(out_dir) if seed_index is None else checked_seed_index(seed_index)
    if not 0 <= seed_index < seeds:
        raise ValueError(f"{out_dir} holds {seeds} seeds; seed index {seed_index} is out of range")
    return jax.tree.map(lambda x: x[seed_index], params)


def checked_seed_index(seed_index: Any) -> int:
    """`seed_index` as an int, refused with a clear error unless it is a whole number (a str or a
    float would fail deep inside numpy's indexing)."""
    if isinstance(seed_index, bool) or not isinstance(seed_index, (int, np.integer)):
        raise TypeError(f"seed_index must be an int (a seed's index in the run, 0 for the first) or None for the "
                        f"run's best seed; got {seed_index!r} ({type(seed_index).__name__})")
    return int(seed_index)


def action_bounds(env: envs.Env) -> tuple[np.ndarray, np.ndarray]:
    """Gymnasium's action space of a continuous `env` (`Env.action_low`/`action_high`: for an MJX
    task each actuator's ctrlrange, which `MjxEnv.action_to_ctrl` scales [-1, 1] to)."""
    return np.asarray(env.action_low, np.float32), np.asarray(env.action_high, np.float32)


def to_action_space(action: jax.Array, low: np.ndarray, high: np.ndarray) -> jax.Array:
    """A policy action in [-1, 1] as the control the task applies: `MjxEnv.action_to_ctrl`'s
    arithmetic (centre + a * half-range), so the two agree to the bit."""
    return 0.5 * (high + low) + jnp.clip(action, -1.0, 1.0) * 0.5 * (high - low)


def checked_observations(obs, env_name: str, size: int) -> np.ndarray:
    """`obs` (one observation or a batch) as float32 numpy, refused with a clear error unless its
    last axis has `size` values and every one is finite: a policy fed NaN answers NaN or an
    arbitrary action without a word, which is how broken physics goes unnoticed."""
    obs = np.asarray(obs, np.float32)
    if obs.shape[-1:] != (size,):
        raise ValueError(f"{env_name} observations have size {size}; got shape {obs.shape}")
    bad = ~np.isfinite(obs)
    if bad.any():
        first = tuple(int(i) for i in np.argwhere(bad)[0])
        where = (f"first in observation {first[0]} of the batch, at value {first[1]}" if len(first) == 2
                 else f"first at value {first[-1]}" if len(first) == 1 else f"first at index {first}")
        raise ValueError(f"the policy of {env_name} got a non-finite observation ({int(bad.sum())} NaN or inf "
                         f"values, {where}: {obs[first]}); check the env that produced it (NaN physics ends an "
                         "episode in mjxsuite's own envs) before acting on it")
    return obs


def checked_frames(frames, env_name: str, shape: tuple[int, ...]) -> np.ndarray:
    """`frames` (one camera image or a batch) as uint8 numpy, refused with a clear error unless
    they are uint8 images of `shape`: float images (say in [0, 1]) would be read as nearly black."""
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.shape[-3:] != tuple(shape):
        raise ValueError(f"{env_name} observes uint8 camera images of shape {tuple(shape)} (height, width, "
                         f"channels); got {frames.dtype} of shape {frames.shape}: pass the env's `obs` as it is")
    return frames


def load_policy(out_dir: str | Path, seed_index: int | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """The policy of a `mjxsuite train --out` directory: `policy(obs) -> action(s)`.

    Takes one observation or a batch (numpy or JAX). DQN's greedy policy returns integer
    actions; PPO's and SAC's deterministic policy (the mode) float32 actions in the task's
    Gymnasium action space. With several trained seeds it uses the run's best seed
    (`checkpoint.best_seed`) unless `seed_index` picks one. Non-finite observations are refused;
    a run trained on camera images (`observation="pixels"`) takes uint8 frames as its env gives them.
    """
    if seed_index is not None:
        checked_seed_index(seed_index)  # before anything loads
    env_name, env, agent, params = load_agent(out_dir)
    params = pick_seed(out_dir, params, seed_index)
    if env.num_actions is not None:
        act = jax.jit(lambda obs: agent.policy(params, obs))
        to_numpy = lambda action: np.asarray(action).astype(np.int64)  # noqa: E731
    else:
        low, high = action_bounds(env)
        act = jax.jit(lambda obs: to_action_space(agent.policy(params, obs), low, high))
        to_numpy = lambda action: np.asarray(action, np.float32)  # noqa: E731

    image = getattr(env, "observation_shape", None)

    def policy(obs):
        if image is not None:
            return to_numpy(act(checked_frames(obs, env_name, image)))
        return to_numpy(act(checked_observations(obs, env_name, env.observation_size)))

    return policy
