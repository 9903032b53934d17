"""The host-side steps of a run (`agents.run.train_run`) between its jitted chunks, whatever the
agent: the run directory and its lock, the progress bar, the save and judge clocks, metrics and
eval.json. The files themselves are `agents.checkpoint`'s.
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

# Periodic checkpoints (docs/reliability.md): every CHECKPOINT_EVERY chunks once CHECKPOINT_SECONDS
# passed, and SAVE_COST_FACTOR times the last save's duration, so that saving takes at most
# 1 / (1 + SAVE_COST_FACTOR) of the wall time however large the state. Before a save is measured, its
# cost is estimated from the state's size at SAVE_BYTES_PER_S.
CHECKPOINT_EVERY = 1
CHECKPOINT_SECONDS = 5.0
SAVE_COST_FACTOR = 20.0
SAVE_BYTES_PER_S = 0.5e9

# A run whose steps overflow MuJoCo Warp's buffers more often than this stops: its agents would
# learn from a state distribution the overflows cut short.
MOST_OVERFLOWING = 0.5


def check_overflow(env, contacts: int, constraints: int, out_of: int, unit: str, where: str, consequence: str,
                   bar: tqdm, told: bool) -> bool:
    """Say once in a run which of MuJoCo Warp's buffers overflowed and how to raise it, or stop the run
    when most of `out_of` overflowed. Returns whether it was said."""
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
    """The run directory, checked before anything compiles: writable (for the writer); with `resume`
    holding this very run; without it, holding no run unless `overwrite`."""
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
    """An exclusive lock (`fcntl.flock` on LOCK_FILE) on a run directory while a run trains in it: a
    second run there is refused, naming the process that holds it, instead of both writing its files."""

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
    """When the next periodic save is due: `every` chunks after the last, and at least `seconds` later,
    or SAVE_COST_FACTOR x the last save's duration if longer (`seconds` 0: every `every` chunks)."""

    def __init__(self, every: int = CHECKPOINT_EVERY, seconds: float = CHECKPOINT_SECONDS):
        COUNT.check("checkpoint_every", every)
        NON_NEGATIVE.check("checkpoint_seconds", seconds)
        self.every, self.seconds = every, seconds
        self.last = 0  # chunks done at the last save (or at the start)
        self.at = time.perf_counter()
        self.save_s = 0.0  # how long the last save took

    def due(self, done: int) -> bool:
        wait_s = max(self.seconds, SAVE_COST_FACTOR * self.save_s) if self.seconds > 0 else 0.0
        return done - self.last >= self.every and time.perf_counter() - self.at >= wait_s

    def expect(self, state_bytes: int) -> None:
        """Space the first save out as if a save of `state_bytes` had been measured, until one is."""
        self.save_s = max(self.save_s, state_bytes / SAVE_BYTES_PER_S)

    def saved(self, done: int, started: float, written_s: float = 0.0) -> None:
        """Record a save of `done` chunks that began at `started`; one written in the background costs
        its write too (`written_s`, the last write's seconds)."""
        self.last, self.at = done, time.perf_counter()
        self.save_s = max(self.at - started, written_s)


# The greedy judge's cadence is a function of the config alone, never of the clock, so that a seed and
# config give the same results whatever the machine or a resume (docs/training.md). DQN's judge is
# spaced out by a cost model of sequential work (`config.chunk_work`), an update counted as UPDATE_COST
# env steps, to stay within JUDGE_SHARE of the chunks it follows.
JUDGE_SHARE = 0.1
UPDATE_COST = 3


def judge_every(config, horizon: int) -> int:
    """The default judge cadence for episodes of at most `horizon` steps: every chunk without `chunk_work`
    (PPO, SAC), else every N-th chunk, the fewest that keep a judge within JUDGE_SHARE."""
    work = getattr(config, "chunk_work", None)
    if work is None:
        return 1
    env_steps, updates = work
    return max(1, math.ceil(horizon / (JUDGE_SHARE * (env_steps + UPDATE_COST * updates))))


class JudgeClock:
    """Which chunks end with the greedy judge: every `every`-th and the last (a candidate for the best)."""

    def __init__(self, every: int, last_chunk: int):
        COUNT.check("judge_every", every)
        self.every, self.last_chunk = every, last_chunk
        self.judge_s = 0.0  # every judge's seconds so far (reported, never read to decide)

    def due(self, index: int) -> bool:
        return index == self.last_chunk or (index + 1) % self.every == 0

    def judged(self, seconds: float) -> None:
        self.judge_s += seconds


# A chunk of more env steps per agent than this runs as several programs (`chunk_parts`), so that the
# bar and a Ctrl-C need not wait for a long chunk; the parts end as the whole chunk does, to the bit.
PART_ENV_STEPS = 100_000


def chunk_parts(config) -> int:
    """How many programs each chunk runs as: the fewest that split its iterations (PPO's) evenly into parts
    of at most PART_ENV_STEPS env steps, or one per iteration; 1 for DQN, SAC, TD3."""
    iterations = getattr(config, "training_steps_per_chunk", None)
    if iterations is None:
        return 1
    per_iteration = config.eval_every // iterations
    return next((parts for parts in range(1, iterations + 1)
                 if iterations % parts == 0 and iterations // parts * per_iteration <= PART_ENV_STEPS), iterations)


def progress_bar(total: int, initial: int, desc: str, enabled: bool = True) -> tqdm:  # over env steps per seed
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
    if out is not None:
        with open(out / checkpoint.METRICS_FILE, "a") as f:
            f.write(json.dumps(record) + "\n")


def write_eval(out: Path | None, summary: dict) -> None:
    if out is not None:
        (out / "eval.json").write_text(json.dumps(summary, indent=2))
