"""The host-side steps of a run's lifecycle (`agents.run.train_run`) between its jitted chunks,
whatever the agent: the run directory, the progress bar, the save clock, metrics and eval.json.

    out = open_run_dir(out_dir, run, resume)      # checked before anything compiles
    bar = progress_bar(total, done, env_name)
    ... after each chunk:
        append_metrics(out, record); show(bar, steps, record)
        if clock.due(chunks): save(...); clock.saved(chunks, seconds)
    write_eval(out, summary)

The files themselves (config.json, the checkpoints, metrics.jsonl) are `agents.checkpoint`'s.
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from agents import checkpoint
from envs.ranges import COUNT, NON_NEGATIVE

# Periodic checkpoints: after every CHECKPOINT_EVERY chunks, once
# CHECKPOINT_SECONDS have passed since the last save: a kill loses at most that much training, and
# saving a small run costs about 1% of its wall time (docs/reliability.md has the measurements).
CHECKPOINT_EVERY = 1
CHECKPOINT_SECONDS = 5.0
# A save's cost grows with the agents (each DQN agent holds its replay buffer; docs/reliability.md),
# so the next periodic save also waits SAVE_COST_FACTOR times the last save's duration: saving then
# takes at most 1 / (1 + SAVE_COST_FACTOR) of the wall time (~5%) however large the state, while runs
# whose saves are shorter than CHECKPOINT_SECONDS / SAVE_COST_FACTOR keep the CHECKPOINT_SECONDS rhythm.
SAVE_COST_FACTOR = 20.0
# Before the first save is measured, its cost is estimated from the train state's size at this
# rate (the copy to the host, the checksums and the write together; a lower bound of what was
# measured for large states on GPU hosts and the 2-core CPU, docs/reliability.md): a run whose
# state takes long to save does not spend its first seconds saving it.
SAVE_BYTES_PER_S = 0.5e9


# A run whose steps overflow MuJoCo Warp's buffers more often than this stops: its agents would
# learn from the few steps that fit, in a state distribution the overflows cut short.
MOST_OVERFLOWING = 0.5


def check_overflow(env, contacts: int, constraints: int, out_of: int, unit: str, where: str, consequence: str,
                   bar: tqdm, told: bool) -> bool:
    """Say once in a run which of MuJoCo Warp's buffers overflowed on how many of `out_of` `unit`
    (env-steps, evaluation episodes) and how to raise it; stop the run with that message when
    most of them overflowed. `where`: "chunk 3", "evaluation 2"; `consequence`: what became of
    those steps. Returns whether it was said."""
    if not contacts and not constraints:
        return told
    from agents.env_options import overflow_report

    report = f"{overflow_report(env, contacts, constraints, out_of, unit)} Those steps are not physics: {consequence}."
    if max(contacts, constraints) > MOST_OVERFLOWING * out_of:
        raise RuntimeError(f"{report} Most {unit} of {where} overflowed: the run stops rather than train on them.")
    if not told:
        bar.write(f"{where}: {report}")
    return True


def open_run_dir(out_dir, run: checkpoint.SavedRun, resume: bool, writer: bool = True,
                 overwrite: bool = False) -> Path | None:
    """The run directory, checked before anything compiles: writable (for the process that
    writes); with `resume` holding this very run (ValueError naming what differs); without it,
    holding no run unless `overwrite` allows replacing it."""
    out = None if out_dir is None else checkpoint.check_writable(out_dir) if writer else Path(out_dir)
    if resume:
        if out is None:
            raise ValueError("resume needs out_dir, the directory of the run to continue")
        checkpoint.check_resumable(out, run)
    elif out is not None and not overwrite and (out / checkpoint.CONFIG_FILE).is_file():
        raise ValueError(f"--out {out} holds a run already ({checkpoint.describe(out)}); continue it with --resume, "
                         "replace it with --overwrite, or choose another --out")
    return out


LOCK_FILE = ".lock"


class RunDirLock:
    """An exclusive lock on a run directory while a run trains in it (`fcntl.flock` on its
    LOCK_FILE, released when the run returns or its process ends): a second `mjxsuite train
    --out DIR` or `--resume` of the same directory is refused, naming the process that holds it,
    instead of both appending to one metrics.jsonl and overwriting each other's checkpoints."""

    def __init__(self, out: Path | None):
        self.file = None
        if out is None:
            return
        import fcntl
        import os

        self.file = open(out / LOCK_FILE, "a+")
        try:
            fcntl.flock(self.file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self.file.seek(0)
            holder = self.file.read().strip() or "another process"
            self.file.close()
            raise ValueError(f"--out {out} is in use by a run training there ({holder}); wait for it to end, "
                             "or choose another --out") from None
        self.file.seek(0)
        self.file.truncate()
        self.file.write(f"pid {os.getpid()}")
        self.file.flush()

    def release(self) -> None:
        if self.file is not None:
            self.file.close()  # closing the file releases the lock
            self.file = None


class SaveClock:
    """When the next periodic save is due: `every` units (chunks or evaluations) after the last,
    and at least `seconds` later, or SAVE_COST_FACTOR x the last save's duration if longer
    (`seconds` 0: every `every` units)."""

    def __init__(self, every: int = CHECKPOINT_EVERY, seconds: float = CHECKPOINT_SECONDS, done: int = 0):
        COUNT.check("checkpoint_every", every)
        NON_NEGATIVE.check("checkpoint_seconds", seconds)
        self.every, self.seconds = every, seconds
        self.last = done  # units done at the last save (or at the start)
        self.at = time.perf_counter()
        self.save_s = 0.0  # how long the last save took

    def due(self, done: int) -> bool:
        wait_s = max(self.seconds, SAVE_COST_FACTOR * self.save_s) if self.seconds > 0 else 0.0
        return done - self.last >= self.every and time.perf_counter() - self.at >= wait_s

    def expect(self, state_bytes: int) -> None:
        """Space the first save out as if a save of `state_bytes` had been measured
        (SAVE_BYTES_PER_S), until one is."""
        self.save_s = max(self.save_s, state_bytes / SAVE_BYTES_PER_S)

    def saved(self, done: int, started: float, written_s: float = 0.0) -> None:
        """Record a save of `done` units that began at `started` (time.perf_counter()). A save
        written in the background costs its write too: `written_s`, the last write's seconds
        (saves of one run are all the same size)."""
        self.last, self.at = done, time.perf_counter()
        self.save_s = max(self.at - started, written_s)


# The greedy judge's cadence is a function of the run's config alone, never of the clock, so a seed
# and config give the same judged chunks, best parameters and solve steps whatever the compile
# cache, the machine's load, the evaluation's size or a resume. PPO and SAC judge every chunk:
# their `num_evals` is the run's count of evaluations, as in Brax, a handful per run. DQN's chunks
# are the host loop's step (progress, signals, saves), hundreds per run, so its judge is spaced
# out by a cost model of sequential work (`config.chunk_work`): a judge runs its episodes side by
# side for up to the time limit (`horizon` batched env steps, however many episodes); a chunk runs
# its batched env steps and gradient updates one after another, an update counted as UPDATE_COST
# env steps (a backward pass and the optimizer beside a forward pass). A chunk is judged every
# `judge_every` chunks, the fewest that keep a judge within JUDGE_SHARE of the chunks it follows.
JUDGE_SHARE = 0.1
UPDATE_COST = 3


def judge_every(config, horizon: int) -> int:
    """The default judge cadence of a run of `config` on a task whose episodes last at most
    `horizon` steps: every chunk for an agent without `chunk_work` (PPO, SAC) or where a judge
    costs at most JUDGE_SHARE of a chunk's sequential work, else every N-th chunk. A larger
    evaluation (more episodes) never judges fewer chunks."""
    work = getattr(config, "chunk_work", None)
    if work is None:
        return 1
    env_steps, updates = work
    return max(1, math.ceil(horizon / (JUDGE_SHARE * (env_steps + UPDATE_COST * updates))))


class JudgeClock:
    """Which chunks end with the greedy judge (the evaluation that keeps the best parameters and
    finds the solve step): every `every`-th chunk (chunk index + 1 a multiple of it) and the
    run's last, whose final parameters are a candidate for the best. The same chunks in every
    run of a config (`judge_every` gives the default `every`)."""

    def __init__(self, every: int, last_chunk: int):
        COUNT.check("judge_every", every)
        self.every, self.last_chunk = every, last_chunk
        self.judge_s = 0.0  # every judge's seconds so far (reported, never read to decide)

    def due(self, index: int) -> bool:
        """Whether chunk `index` (0-based) is judged."""
        return index == self.last_chunk or (index + 1) % self.every == 0

    def judged(self, seconds: float) -> None:
        """Record a judge that took `seconds`."""
        self.judge_s += seconds


# A chunk of more env steps (per agent) than PART_ENV_STEPS runs as several programs, each of at
# most that many where its iterations split evenly (`chunk_parts`): on a CPU a GPU recipe's chunk
# is minutes to hours of work, and the bar and a Ctrl-C wait for the program under way to end.
# The parts end as the whole chunk does, to the bit (`agents.evaluation.chunk_part`).
PART_ENV_STEPS = 100_000


def chunk_parts(config) -> int:
    """How many programs each chunk of a run of `config` runs as: the fewest that split its
    iterations (PPO's `training_steps_per_chunk`) evenly into parts of at most PART_ENV_STEPS env
    steps, or one per iteration where none does; 1 for an agent whose chunk does not split (DQN's,
    SAC's and TD3's chunks are `eval_every` env steps, short by their recipes). A function of the
    config alone, and the results do not depend on it."""
    iterations = getattr(config, "training_steps_per_chunk", None)
    if iterations is None:
        return 1
    per_iteration = config.eval_every // iterations
    return next((parts for parts in range(1, iterations + 1)
                 if iterations % parts == 0 and iterations // parts * per_iteration <= PART_ENV_STEPS), iterations)


def progress_bar(total: int, initial: int, desc: str, enabled: bool = True) -> tqdm:
    """The progress bar over env steps (per seed) a run shows."""
    return tqdm(total=total, initial=initial, unit="step", disable=not enabled, desc=desc, dynamic_ncols=True)


def show(bar: tqdm, steps: int, record: dict) -> None:
    """Advance `bar` by `steps` env steps and show the record's evaluation and speed."""
    bar.update(steps)
    if record.get("eval_return") is None:  # a chunk the judge skipped (`JudgeClock`): the last figures stay
        return
    postfix = {"eval": f"{np.mean(record['eval_return']):.1f}"}
    if record.get("best_return") is not None:
        postfix["best"] = f"{np.mean(record['best_return']):.1f}"
    if record.get("steps_per_s"):
        postfix["sps"] = f"{record['steps_per_s']:.0f}"
    bar.set_postfix(**postfix)


def append_metrics(out: Path | None, record: dict) -> None:
    """One evaluation's record as a line of metrics.jsonl (nothing without a run directory)."""
    if out is not None:
        with open(out / checkpoint.METRICS_FILE, "a") as f:
            f.write(json.dumps(record) + "\n")


def write_eval(out: Path | None, summary: dict) -> None:
    """The finished run's eval.json."""
    if out is not None:
        (out / "eval.json").write_text(json.dumps(summary, indent=2))
