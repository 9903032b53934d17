"""The run lifecycle of every agent: `train_run` runs an agent's pure chunks under jit(vmap) for many
seeds (spread over devices by `agents.sharding`) and between chunks owns the run directory, metrics,
checkpoints, signals and the final evaluation (`agents.run_steps`). `load_policy` reads a run back."""

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
from agents.device_options import default_seed_axis, init_compiler_options, judge_seed_axis, training_compiler_options
from agents.dqn import DQNConfig
from agents.registry import per_agent, sweep_configs
from agents.run_steps import CHECKPOINT_EVERY, CHECKPOINT_SECONDS
from envs.batching import one_after_another
from envs.mjx_warp import CompileRules, runs_warp
from envs.ranges import COUNT
from envs.registry import is_mjx_task


# The parts of a run's wall time, as eval.json's `wall_parts_s` and the command's last line name them.
WALL_PARTS = ("start-up", "compile", "train", "judge", "saves", "evaluation", "other")
CLOCK_KEYS = ("steps_per_s", "judge_s")  # a chunk's record's seconds: the same run's differ from session to session


@dataclass
class RunResult:
    params: Any  # best parameters per seed (leading seed axis)
    train_state: Any
    history: list[dict] = field(default_factory=list)  # one record per evaluation
    mean_return: list[float] = field(default_factory=list)  # final greedy evaluation per seed
    solve_step: list[int | None] = field(default_factory=list)
    solve_wall_s: list[float | None] = field(default_factory=list)  # seconds to the first judge at solve_return
    wall_s: float = 0.0  # train_run's whole call, every session's; the parts below add up to it
    compile_s: float = 0.0
    setup_s: float = 0.0  # the env, the first JAX calls, placing the agents, loading a checkpoint
    train_s: float = 0.0
    judge_s: float = 0.0  # the greedy judges (`run_steps.JudgeClock`)
    judges: int = 0  # chunks judged
    save_s: float = 0.0
    eval_s: float = 0.0  # the final evaluation, its compile included
    host_s: float = 0.0  # the rest: the host's work between chunks (metrics files, `on_chunk`)
    earlier_wall_s: float = 0.0  # the earlier sessions' share of wall_s (0 but after a --resume)
    interrupted: bool = False  # SIGINT or SIGTERM; like `stop_after_chunks`, leaves params None and a checkpoint
    stop_signal: str | None = None  # "SIGINT" or "SIGTERM" when interrupted
    chunks_done: int = 0  # chunks the train state has done at the end of this call
    saved_chunks: int | None = None  # chunks the run directory's checkpoint holds (0: none; None: no directory)
    total_chunks: int = 0  # chunks of the whole run
    started: bool = True  # False: stopped by a signal before the run touched its directory
    devices: int = 1  # devices the agents were spread over (`agents.sharding`)
    processes: int = 1  # processes that trained them, one device each (`agents.processes`)
    best_seed: int = 0  # the seed `load_policy` acts with (`break_ties`)
    diverged: list[int] = field(default_factory=list)  # seeds whose losses became non-finite

    def wall_parts(self) -> dict[str, float]:
        return dict(zip(WALL_PARTS, (self.setup_s, self.compile_s, self.train_s, self.judge_s, self.save_s,
                                     self.eval_s, self.host_s)))

    def finish(self, start: float, earlier: dict | None = None) -> None:
        """wall_s and its parts, each plus the earlier sessions' (the clock a --resume began from)."""
        earlier = earlier or {}
        before = earlier.get("wall_parts_s", {})
        for name, part in zip(WALL_PARTS[:-1], ("setup_s", "compile_s", "train_s", "judge_s", "save_s", "eval_s")):
            setattr(self, part, getattr(self, part) + before.get(name, 0.0))
        self.earlier_wall_s = earlier.get("wall_s", 0.0)
        self.wall_s = time.perf_counter() - start + self.earlier_wall_s
        self.host_s = max(0.0, self.wall_s - self.setup_s - self.compile_s - self.train_s - self.judge_s - self.save_s
                          - self.eval_s)

    def summary(self, agent: str, env: str, seeds: int, tie_break_return: list, **extra) -> dict:
        """eval.json: the same keys for every agent (docs/training.md); `extra` goes before diverged_seeds."""
        return {"agent": agent, "env": env, "seeds": seeds, "best_seed": self.best_seed,
                "mean_return": self.mean_return, "solve_step": self.solve_step, "solve_wall_s": self.solve_wall_s,
                "wall_s": self.wall_s, "compile_s": self.compile_s, "devices": self.devices,
                "wall_parts_s": self.wall_parts(), "judged_chunks": self.judges, "chunks": self.chunks_done,
                "tie_break_return": tie_break_return, **extra, "diverged_seeds": self.diverged}


def seed_keys(seed: int, seeds: int) -> jax.Array:
    """Independent keys for `seeds` agents (split, never reused)."""
    return run_keys(seed, seeds)[0]


@partial(jax.jit, static_argnums=(0, 1))
def run_keys(seed: int, seeds: int) -> tuple[jax.Array, jax.Array]:
    """A run's training and final evaluation keys, from one program (docs/bench-gpu.json, "dqn-run-keys")."""
    seed_key = jax.random.PRNGKey(seed)
    return jax.random.split(seed_key, seeds), jax.random.split(jax.random.fold_in(seed_key, 1), seeds)


SEED_AXES = ("vmap", "map")


def seed_batched(fn: Callable, seeds: int, seed_axis: str | None = None) -> Callable:
    """`fn` over a leading seed axis, batched ("vmap") or one seed after another ("map"; None: by device,
    docs/bench-cpu.json "dqn-seed-scaling"). One seed runs unbatched."""
    seed_axis = seed_axis or default_seed_axis()
    if seed_axis not in SEED_AXES:
        raise ValueError(f"unknown seed_axis {seed_axis!r}; choose one of {SEED_AXES}")
    if seeds > 1:
        return jax.vmap(fn) if seed_axis == "vmap" else partial(_map_in_place, fn)

    def single(*args):
        return jax.tree.map(lambda x: x[None], fn(*jax.tree.map(lambda x: x[0], args)))

    return single


def _map_in_place(fn: Callable, state: Any, *args):
    """`fn(state, *args) -> (state, *outputs)` over the leading seed axis, one seed after another, each seed's new
    state written into `state`'s buffers: a donated train state is updated in place, where `lax.map`'s stacked
    outputs would hold a second copy of every seed's replay."""
    at = lambda tree, i: jax.tree.map(lambda x: jax.lax.dynamic_index_in_dim(x, i, keepdims=False), tree)
    put = lambda tree, new, i: jax.tree.map(lambda x, v: jax.lax.dynamic_update_index_in_dim(x, v, i, 0), tree, new)

    def one_seed(state, i):
        new = fn(*at((state, *args), i))
        return put(state, new[0], i), new[1:]

    state, outputs = jax.lax.scan(one_seed, state, jnp.arange(len(jax.tree.leaves(state)[0])))
    return (state, *outputs)


def seeds_init(learner: Any, seeds: int) -> Callable:
    """`learner.init` over a leading seed axis (a sweep's takes each agent's hyperparameters too), one seed after
    another on the CPU, where a batched QR (image networks' orthogonal init) may wait forever."""
    return one_after_another(learner.init) if seeds > 1 and default_seed_axis() == "map" else jax.vmap(learner.init)


def _in_background(work: Callable[[], Any], name: str, after: threading.Event | None = None) -> Future:
    """`work()` on another thread (XLA compiles without Python's lock), once `after` is set if given: on
    MuJoCo Warp, once every program is traced (docs/mjx.md, "MuJoCo Warp and CUDA graphs")."""
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
    """An agent's program lowered for `args` through the export cache (`agents.traced_programs`)."""
    return traced_programs.lower_env_program(program, fn, args, learner.env, env_name, env_options,
                                          extra=key_parts(learner, seeds), donate=donate,
                                          compiler_options=training_compiler_options(env=learner.env))


def lower_evaluation_cached(learner: Any, params: Any, keys: Any, env_name: str, env_options: dict | None,
                            episodes: int | None = None) -> traced_programs.LoweredProgram:
    """Every seed's evaluation through the export cache, shared by a run and `mjxsuite eval` of it."""
    episodes = episodes or learner.config.eval_episodes
    seeds = jax.tree.leaves(params)[0].shape[0]
    return lower_cached(f"{type(learner).__name__}.evaluate, {episodes} episodes",
                        jax.vmap(partial(learner.evaluate, num_episodes=episodes)), (params, keys), learner, seeds,
                        env_name, env_options)


def key_parts(learner: Any, seeds: int) -> dict:
    return {"config": learner.config, "seeds": seeds}


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
    """Train `seeds` agents (as `config` says) on `env_name` at once (docs/training.md). With `resume`,
    continue the run in `out_dir` from its last checkpoint: it ends as an uninterrupted run would. With
    `sweep`, agent `c * seeds + s` is config c with seed s's key; with `seed_slice`, seeds keep the keys
    a run of all `seeds` gives them. The steps are `_Run`'s methods, in order."""
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
    """One `train_run`: its checked settings and what each step (a method, in order) hands the next."""

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
        # Between checkpoints, best_params.ckpt alone after a judge that raised a best return, on a clock of its own:
        # a run stopped before its next checkpoint (spaced out by its replay's size) keeps its best policy.
        self.policy_clock, self.policy_best = run_steps.SaveClock(1, clock.seconds), None

    def not_started(self) -> RunResult:  # a signal before anything compiled
        saved = checkpoint.chunks_saved(self.out) if self.out is not None and self.resume else 0
        return RunResult(params=None, train_state=None, interrupted=True, stop_signal=self.stop.name,
                         saved_chunks=None if self.out is None else saved, total_chunks=self.config.num_chunks,
                         wall_s=time.perf_counter() - self.start, started=False)

    # ---- the programs ------------------------------------------------------------------------
    def compile_programs(self, progress: bool, record_episode: bool, seed_axis: str | None, evaluates: bool) -> None:
        """Every program the run needs, compiled in the background; a multi-host run's final evaluation
        compiles at the end. Warp's rules: `CompileRules` (docs/mjx.md, "MuJoCo Warp and CUDA graphs")."""
        self.learner = registry.make(self.config, self.env, agents=self.agents // self.placement.count)
        self.rules = CompileRules(runs_warp(self.learner.env))
        self.parts = run_steps.chunk_parts(self.config) if hasattr(self.learner, "chunk_loop") else 1
        if progress and self.writer:  # the bar comes once the programs are compiled
            builds = " (MuJoCo Warp also builds its kernels once per machine)" if self.rules.on_warp else ""
            print(f"{self.env_name}: compiling{builds}...", file=sys.stderr, flush=True)
        self.evaluates = evaluates and jax.process_count() == 1
        self.final_evaluation = self.every_seed = None
        with self.rules.tracing() as after_traces:
            inputs, init_program, init_args = self._lower_state(after_traces)
            train_program, judge_program = self._lower_chunk(
                record_episode, seed_axis or default_seed_axis(learner=self.learner), after_traces)
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

    def _run_inputs(self):  # the init program's arguments and the final evaluation's keys
        keys, eval_keys = run_keys(self.seed, self.seeds)
        if self.sweep is None:  # every seed's keys made, these seeds' kept: the same keys whatever the slice
            return (keys[self.first:self.stop_seed],), eval_keys[self.first:self.stop_seed]
        configs = len(self.configs)
        return (jnp.tile(keys, (configs, 1)), per_agent(self.configs, self.seeds)), jnp.tile(eval_keys, (configs, 1))

    def _lower_state(self, after_traces):
        """The inputs, made on another thread, and the train state: the checkpoint's, or the init program's."""
        placement = self.placement
        inputs = _in_background(lambda: placement.put(self._run_inputs()), "inputs", after=after_traces)
        init = jax.jit(placement.spread(seeds_init(self.learner, self.agents // placement.count)),
                       compiler_options=init_compiler_options())
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
        """A chunk's training steps, compiling on another thread while this one lowers its judge (two programs:
        docs/bench-gpu.json, "dqn-sharded-programs"). A finished run has none."""
        if self.chunks_done >= self.config.num_chunks:
            return None, None
        learner, ts, per_device = self.learner, self.ts, self.agents // self.placement.count
        kind = type(learner).__name__  # names its programs in the export cache
        if self.parts > 1:  # a chunk in parts (`_in_parts`): the first part's state is kept, so none is donated
            part_fn = seed_batched(partial(_train_part, learner, self.parts), per_device, seed_axis)
            self.carry_shapes = jax.eval_shape(jax.vmap(partial(evaluation.part_carry, learner.chunk_loop)), ts)
            train = self._lower(f"{kind}.chunk_part of {self.parts} over seeds by {seed_axis}", part_fn,
                                (ts, self.placement.abstract(self.carry_shapes)))
        else:
            train = self._lower(f"{kind}.train_steps over seeds by {seed_axis}",
                                seed_batched(partial(_train_steps, learner), per_device, seed_axis), (ts,), donate=True)
        train_program = _in_background(train.compile, "train", after=after_traces)
        judge_axis = judge_seed_axis(seed_axis, learner=learner)
        judge_fn = seed_batched(partial(learner.evaluate_and_keep_best, record=record_episode), per_device, judge_axis)
        judged = (f"{kind}.evaluate_and_keep_best over seeds by {judge_axis}"
                  + ("" if record_episode else ", no episode recorded"))
        return train_program, self._lower(judged, judge_fn, (ts, ts.key), donate=True)

    def _lower(self, program: str, fn: Callable, args: tuple, donate: bool = False) -> traced_programs.LoweredProgram:
        """`fn` lowered for `args`, through the export cache on one device (sharded programs skip it)."""
        if self.placement.mesh is None:
            return lower_cached(program, fn, args, self.learner, self.agents, self.env_name, self.env_options,
                                donate=donate)
        return traced_programs.LoweredProgram(
            jax.jit(self.placement.spread(fn), donate_argnums=0 if donate else ()).lower(*args),
            training_compiler_options(env=self.learner.env))

    def lower_evaluation(self, params: Any, keys: Any) -> Any:
        if self.placement.mesh is None:
            return lower_evaluation_cached(self.learner, params, keys, self.env_name, self.env_options)
        return jax.jit(self.placement.spread(jax.vmap(self.learner.evaluate))).lower(params, keys)

    def _compile_final_beside_training(self) -> None:
        """The final evaluation, compiling while the agents train; on a GPU also the tie-break for every
        seed (on a CPU, measuring every seed costs more than compiling for the tied ones)."""
        self.final_evaluation = _in_background(
            lambda: self.lower_evaluation(self.params_shape, self.eval_keys).compile(), "evaluation")
        if self.agents > 1 and self.placement.devices[0].platform == "gpu":
            tie_keys = jax.eval_shape(lambda: tie_break_keys(self.seed, jnp.arange(self.agents)))
            self.every_seed = _in_background(partial(every_seed_tie_break, self.learner, self.env_name,
                                                     self.env_options, self.placement, self.params_shape, tie_keys),
                                             "tie-break")

    # ---- the chunks --------------------------------------------------------------------------
    def train_chunks(self, progress: bool, on_chunk, stop_after_chunks: int | None, stop_when_solved: bool) -> None:
        """Train the chunks, judged and saved on their clocks, until the last, `stop_after_chunks`, a signal or
        every agent solved. The next chunk is dispatched before this one's host work where nothing of that
        work can change it (`look_ahead`)."""
        config = self.config
        self.result = RunResult(params=None, train_state=self.ts, compile_s=self.compile_s,
                                solve_wall_s=list(self.earlier.get("solve_wall_s") or [None] * self.agents),
                                devices=self.placement.count, setup_s=self.compile_start - self.start,
                                total_chunks=config.num_chunks)
        prefill = getattr(config, "prefill_steps", 0)  # SAC's and TD3's first fill of the replay, in `init`
        self.bar = run_steps.progress_bar(prefill + config.num_chunks * config.eval_every,
                                          prefill + self.chunks_done * config.eval_every, self.env_name,
                                          enabled=progress and self.writer)
        self.clock.last = self.chunks_done
        self.clock.expect(sum(leaf.nbytes for leaf in jax.tree.leaves(self.ts)))  # the first save, before one is timed
        self.last, self.solved_early, self.overflow_told = self.chunks_done, False, False
        self.on_chunk, self.stop_when_solved = on_chunk, stop_when_solved
        # on_chunk gets the state the next chunk consumes; uncaught signals could leave a chunk unlogged
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
        """A chunk as `self.parts` programs; a signal between parts drops it: (its start state, None, None)."""
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
        """A periodic save (the last chunk's is `finish`'s), by process 0's clock."""
        return self.placement.same_on_every_process(self.out is not None and done < self.config.num_chunks
                                                    and self.clock.due(done))

    def _after_chunk(self, index: int, metrics: dict, eval_key, tick: float):
        """A trained chunk's judge, record and periodic save; returns the next chunk if dispatched ahead."""
        judging, eval_episode, placement = self.judge_clock.due(index), None, self.placement
        # The whole chunk done, so that its seconds are its own however its dispatch returned
        jax.block_until_ready((self.ts, metrics))
        trained_at = time.perf_counter()
        if judging:
            self.ts, judged = self.judge_program(self.ts, eval_key)
            eval_episode = judged.pop("eval_episode")
            metrics = {**judged, **metrics}
            if self.on_chunk is not None and jax.process_count() > 1:  # other hosts' agents too, for the logger
                eval_episode = placement.to_host(eval_episode)
        self.last = index + 1
        save_due = self._save_due(self.last)
        look = self.look_ahead and self.last < self.stop_at and not save_due and not self._signalled()
        ahead = self._dispatched(self.ts) if look and not judging else None  # the device trains on meanwhile
        record = {k: np.asarray(v).tolist() for k, v in placement.to_host(metrics).items()}
        policy = None
        if judging:
            record["judge_s"] = time.perf_counter() - trained_at
            self.judge_clock.judged(record["judge_s"])
            if not save_due:  # read before the next chunk takes the state
                policy = self._new_policy(record["best_return"])
            if look:  # after the judge's results reached the host, whose seconds are the judge's
                ahead = self._dispatched(self.ts)
        self.result.train_s += trained_at - tick
        record["chunk"] = index
        record["steps_per_s"] = self.config.eval_every * self.agents / (trained_at - tick)  # as Brax's training/sps
        self._observe(index, record, eval_episode, judging)
        if ahead is None and not self.solved_early and self._save_due(self.last):
            self._checkpoint(self.ts, self.last)  # written while the next chunks train
        elif policy is not None:
            self._save_policy(*policy)
        return ahead

    def _new_policy(self, best: list[float]):
        """A host copy of the best parameters where the judge's best returns `best` rose since the last policy
        written and its clock allows another while no save is under way, else None (the same on every process)."""
        due = self.out is not None and best != self.policy_best and self.policy_clock.due(self.last)
        if not self.placement.same_on_every_process(due and not self.saves.busy()):
            return None
        return jax.tree.map(np.array, self.placement.to_host(self.ts.best_params)), best  # copies: buffers are reused

    def _save_policy(self, params, best) -> None:
        save_start = time.perf_counter()
        if self.writer:  # a few MB, written while the next chunk trains
            checkpoint.save_policy(self.out, self.env_name, params, best)
        self.policy_best = best
        self.policy_clock.saved(self.last, save_start)
        self.result.save_s += time.perf_counter() - save_start

    def _observe(self, index: int, record: dict, eval_episode, judging: bool) -> None:
        """What watches a chunk's record: overflow, divergence, solve times, metrics, `on_chunk`, the bar."""
        config, result = self.config, self.result
        most = [int(np.max(record.get(f"overflow_{kind}", 0))) for kind in ("contacts", "constraints")]
        self.overflow_told = run_steps.check_overflow(self.env, *most, config.eval_every, "env-steps",
                                                      f"chunk {record['chunk']}", "they ended their episodes and "
                                                      "stayed out of the replay", self.bar, self.overflow_told)
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
        save_start = time.perf_counter()
        save(self.saves, self.out, self.env_name, self.placement, state, done, final=final,
             finished=done == self.config.num_chunks, copy_beside=self.rules.host_copy_beside, clock=self.clock_now())
        self.clock.saved(done, save_start, self.saves.written_s)
        self.result.save_s += time.perf_counter() - save_start

    def clock_now(self) -> dict:
        """The run's clock so far, every session's, saved with each checkpoint for a --resume."""
        now = dataclasses.replace(self.result, judge_s=self.judge_clock.judge_s)
        now.finish(self.start, self.earlier)
        return {"wall_s": now.wall_s, "wall_parts_s": now.wall_parts(), "solve_wall_s": now.solve_wall_s}

    # ---- the end -------------------------------------------------------------------------------
    def _evaluated(self):  # the final evaluation, dispatched
        evaluate = (self.final_evaluation.result() if self.final_evaluation is not None
                    else self.lower_evaluation(self.ts.best_params, self.eval_keys).compile())
        return evaluate(self.ts.best_params, self.eval_keys)

    def finish(self) -> RunResult:
        """The final save, and for a finished run the final evaluation, the tie-break and eval.json."""
        result, ts = self.result, self.ts
        finished = self.last == self.config.num_chunks or self.solved_early
        # The final evaluation goes before the final save, whose host copy overlaps it, except on Warp
        eval_start = time.perf_counter()
        early = (finished and not result.interrupted and self.final_evaluation is not None
                 and self.rules.evaluate_before_final_save)
        returns = self._evaluated() if early else None
        eval_s = time.perf_counter() - eval_start
        # Not after errors: a failed chunk may have consumed its donated state, so the last checkpoint stands.
        if self.out is not None and self.clock.last != self.last:
            self._checkpoint(ts, self.last, final=True)  # copied and written during the final evaluation
        result.chunks_done, result.saved_chunks = self.last, self.clock.last if self.out is not None else None
        result.judges = sum(map(self.judge_clock.due, range(self.last)))  # every session's, by the config's cadence
        result.judge_s = self.judge_clock.judge_s
        # A signal during the last chunk or save skips the final evaluation; --resume evaluates.
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
            run_steps.write_eval(self.out, result.summary(self.agent, self.env_name, self.trained_seeds,
                                                          [tie_break.get(self.first + i) for i in range(self.agents)]))
        return result


def _waited(saves: checkpoint.BackgroundSaves) -> float:
    start = time.perf_counter()
    saves.wait()
    return time.perf_counter() - start


def _train_steps(learner: Any, ts: Any) -> tuple[Any, dict, jax.Array]:
    """`learner.train_steps(ts)`, its metrics saying where the run stands even where not judged."""
    ts, metrics, eval_key = learner.train_steps(ts)
    return ts, {**metrics, "env_steps": ts.env_steps}, eval_key


def _train_part(learner: Any, parts: int, ts: Any, carry: tuple) -> tuple:
    """One of `parts` parts of a chunk (`evaluation.chunk_part`), as `_train_steps`."""
    ts, carry, metrics, eval_key = evaluation.chunk_part(learner.chunk_loop(ts), parts, ts, carry)
    return ts, carry, {**metrics, "env_steps": ts.env_steps}, eval_key


def _check_diverged(record: dict, diverged: list[int], first: int, bar) -> None:
    """Say once per seed when a chunk's losses became non-finite, adding it to `diverged`."""
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


TIE_BREAK_LENGTH = 4  # a tie-break's episodes are this many time limits long...
TIE_BREAK_EPISODES = 4  # ...and this many times as many as an evaluation's


def tie_break_program(agent: Any, env_name: str, env_options: dict | None,
                      placement: sharding.Placement | None = None) -> Callable:
    """The tie-break's longer evaluation, jitted: `(params, keys) -> mean return per agent`."""
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
    """`tie_break_program` compiled for every row of `params`, placing the host's keys: `break_ties`' `every_seed`."""
    program = tie_break_program(agent, env_name, env_options, placement).lower(
        placement.abstract(params), placement.abstract(keys)).compile()
    return lambda params, keys: program(params, placement.put(keys))


def tie_break_keys(seed: int, indices: Any) -> jax.Array:  # by each seed's index in the run
    tie_key = jax.random.fold_in(jax.random.PRNGKey(seed), 2)
    return jax.vmap(lambda i: jax.random.fold_in(tie_key, i))(jnp.asarray(indices))


def tied_seeds(returns: list[float]) -> np.ndarray:
    returns = np.nan_to_num(np.asarray(returns, dtype=np.float64), nan=-np.inf)  # a diverged seed never ties
    best = returns.max()
    if not np.isfinite(best):  # no seed has a finite return: the first stands
        return np.zeros(1, dtype=np.int64)
    return np.flatnonzero(returns >= best - 1e-6 * max(1.0, abs(best)))


def unmeasured_ties(returns: list[float], measured: dict[int, float] | None, first: int = 0) -> list[int]:
    """The tied seeds (indices into `returns`) not yet `measured` by run seed index."""
    tied = tied_seeds(returns)
    return [] if len(tied) == 1 else [int(i) for i in tied if first + i not in (measured or {})]


def break_ties(agent: Any, env_name: str, env_options: dict | None, params: Any, returns: list[float],
               seed: int, first: int = 0, measured: dict[int, float] | None = None,
               every_seed: Callable | None = None) -> tuple[int, dict[int, float]]:
    """The best seed (an index into `returns`, the run's seeds from `first`) and the tied seeds' longer
    returns (by run seed index; `measured`: those already known). A longer evaluation tells tied seeds
    apart, so that a policy that only holds out to the time limit loses to one that keeps balancing."""
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
    """A checkpoint of every agent, written by process 0 on another thread, which on one device also makes
    the `final` save's copy to the host unless `copy_beside` is False (docs/mjx.md, "MuJoCo Warp and CUDA graphs")."""
    if finished:
        ts = checkpoint.without_replay(ts)
    if final and copy_beside and placement.mesh is None and jax.process_count() == 1:
        saves.save(out, env_name, partial(placement.to_host, ts), chunks_done, finished, clock)
        return
    host = placement.to_host(ts)
    if sharding.is_writer():
        if placement.devices[0].platform == "cpu":  # host arrays sharing memory with reused device buffers
            host = jax.tree.map(lambda x: x if isinstance(x, np.ndarray) and x.flags.owndata else np.array(x), host)
        saves.save(out, env_name, host, chunks_done, finished, clock)


def load_agent(out_dir: str | Path, env: envs.Env | None = None) -> tuple[str, envs.Env, Any, Any]:
    """`(env_name, env, agent, best_params)` from a run directory (`env`: the saved env by default)."""
    saved = checkpoint.load_config(out_dir)
    env = env or checkpoint.saved_env(out_dir)[1]
    agent = registry.make(saved.config, env)
    agents = saved.trained_seeds * len(sweep_configs(saved.config, saved.sweep))
    template = jax.eval_shape(jax.vmap(agent.fresh_params), seed_keys(0, agents))  # best_params' shapes, no envs
    return saved.env, env, agent, checkpoint.load_best_params(out_dir, template)


def pick_seed(out_dir: str | Path, params: Any, seed_index: int | None = None) -> Any:
    """One seed's parameters: `seed_index`, or the run's best seed (`checkpoint.best_seed`)."""
    seeds = jax.tree.leaves(params)[0].shape[0]
    seed_index = checkpoint.best_seed(out_dir) if seed_index is None else checked_seed_index(seed_index)
    if not 0 <= seed_index < seeds:
        raise ValueError(f"{out_dir} holds {seeds} seeds; seed index {seed_index} is out of range")
    return jax.tree.map(lambda x: x[seed_index], params)


def checked_seed_index(seed_index: Any) -> int:
    if isinstance(seed_index, bool) or not isinstance(seed_index, (int, np.integer)):
        raise TypeError(f"seed_index must be an int (a seed's index in the run, 0 for the first) or None for the "
                        f"run's best seed; got {seed_index!r} ({type(seed_index).__name__})")
    return int(seed_index)


def checked_observations(obs, env_name: str, size: int) -> np.ndarray:
    """`obs` as float32 numpy, refused unless of `size` and finite (so that broken physics is noticed)."""
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
    """`frames` as uint8 numpy, refused unless uint8 images of `shape` (float ones would look black)."""
    frames = np.asarray(frames)
    if frames.dtype != np.uint8 or frames.shape[-3:] != tuple(shape):
        raise ValueError(f"{env_name} observes uint8 camera images of shape {tuple(shape)} (height, width, "
                         f"channels); got {frames.dtype} of shape {frames.shape}: pass the env's `obs` as it is")
    return frames


def load_policy(out_dir: str | Path, seed_index: int | None = None) -> Callable[[np.ndarray], np.ndarray]:
    """The policy of a run directory, `policy(obs) -> action(s)` in the task's action space, for one
    observation or a batch, with the run's best seed unless `seed_index` picks one."""
    if seed_index is not None:
        checked_seed_index(seed_index)  # before anything loads
    env_name, env, agent, params = load_agent(out_dir)
    params = pick_seed(out_dir, params, seed_index)
    if env.num_actions is not None:
        act, dtype = jax.jit(lambda obs: agent.policy(params, obs)), np.int64
    else:  # an action in [-1, 1] as the control the task applies (`MjxEnv.action_to_ctrl`'s arithmetic)
        low, high, dtype = np.asarray(env.action_low, np.float32), np.asarray(env.action_high, np.float32), np.float32
        centre, half_range = 0.5 * (high + low), 0.5 * (high - low)
        act = jax.jit(lambda obs: centre + jnp.clip(agent.policy(params, obs), -1.0, 1.0) * half_range)
    image = getattr(env, "observation_shape", None)

    def policy(obs):
        obs = (checked_frames(obs, env_name, image) if image is not None
               else checked_observations(obs, env_name, env.observation_size))
        return np.asarray(act(obs), dtype)

    return policy
