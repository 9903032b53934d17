"""Seeds of a run trained by several processes, one per GPU, started by `mjxsuite train` itself: XLA's
GPU compiler crashes on a batched MJX step spread over GPUs in one program (`agents.sharding.MJX_OVER_GPUS`),
so each child is an ordinary one-GPU `mjxsuite train --resume` of `D/processes/K/`, with the keys the
whole run gives its seeds. The layout and lifecycle: docs/scaling.md, "An MJX task's seeds over every GPU".
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import NamedTuple

from agents import checkpoint, run_steps, sharding, signals

PROCESSES_DIR = checkpoint.PROCESSES_DIR
LOG_FILE = "log.txt"
PROGRESS_SECONDS = 10.0  # between the parent's lines of progress
# Asks for N processes where --processes is not given (e.g. in a job script).
PROCESSES_ENV = "MJXSUITE_PROCESSES"
# `mjxsuite` as a program of this interpreter, also from a checkout that was never installed.
MJXSUITE = [sys.executable, "-c", "from agents.console import run; run()"]
# A child's `mjxsuite`: the same, ended with its parent (`signals.die_with_parent`).
CHILD_MJXSUITE = [sys.executable, "-c",
                  "from agents.signals import die_with_parent; die_with_parent(); from agents.console import run; run()"]


class ProcessFailed(Exception):
    """A child process failed: the command exits 1, naming it and its log."""


class Child(NamedTuple):
    index: int
    directory: Path
    seed_slice: tuple[int, int]
    gpu: str | None  # CUDA_VISIBLE_DEVICES for it; None: the environment's as it is (a CPU)

    def describe(self) -> str:
        start, stop = self.seed_slice
        seeds = f"seed {start}" if stop - start == 1 else f"seeds {start}-{stop - 1}"
        return f"process {self.index} ({seeds}{'' if self.gpu is None else f', GPU {self.gpu}'})"


def local_gpus() -> list[str]:
    """This host's NVIDIA GPUs as CUDA_VISIBLE_DEVICES names them, found without starting JAX's backend
    (which would hold memory on every GPU the children train on). Empty where there is no CUDA."""
    platforms = os.environ.get("JAX_PLATFORMS", "")
    if platforms and not any(name in platforms for name in ("cuda", "gpu")):
        return []
    visible = os.environ.get("CUDA_VISIBLE_DEVICES")
    if visible is not None:
        return [name.strip() for name in visible.split(",") if name.strip() not in ("", "-1")]
    try:
        listed = subprocess.run(["nvidia-smi", "--list-gpus"], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return []
    count = sum(line.startswith("GPU ") for line in listed.stdout.splitlines()) if listed.returncode == 0 else 0
    return [str(i) for i in range(count)]


def count(env_name: str, seeds: int, devices: int | None, processes: int | None, gpus: list[str]) -> int:
    """How many processes train a new run's seeds: `processes` when given; for an MJX task on a host with
    several GPUs, `devices` (None: as many as split the seeds evenly); else 1. ValueError if none split."""
    from envs.registry import makes_mjx_task

    if processes is None and os.environ.get(PROCESSES_ENV):
        text = os.environ[PROCESSES_ENV]
        if not text.isdigit() or int(text) < 1:
            raise ValueError(f"{PROCESSES_ENV}={text}: must be a number of processes, 1 or more")
        processes = int(text)
    if processes is not None:
        if processes > 1 and devices not in (None, 1):
            raise ValueError(f"--processes {processes} gives each process one device; drop --devices {devices}")
        option, asked = "--processes", processes
    elif makes_mjx_task(env_name) and len(gpus) > 1:
        if devices is not None and devices > len(gpus):
            raise ValueError(f"--devices must be between 1 and the {len(gpus)} local GPUs, got {devices}")
        option, asked = "--devices", devices or max(k for k in range(1, len(gpus) + 1) if seeds % k == 0)
    else:
        return 1
    if seeds % asked:
        fix = max(k for k in range(1, asked + 1) if seeds % k == 0)
        raise ValueError(f"{option} {asked}: {seeds} seeds do not split evenly over {asked} processes (one per GPU): "
                         f"use {sharding.seeds_that_split(seeds, asked)}, or {option} {fix}")
    return asked


def keep_off_the_gpus(gpus: list[str]) -> None:
    """The parent's JAX (if it starts: a task's spec, a tie-break at the end) on the first GPU only,
    taking memory as it needs it, beside the children. Must run before JAX starts its backend."""
    if gpus:
        os.environ["CUDA_VISIBLE_DEVICES"] = gpus[0]
        os.environ["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"


def children_of(out: Path, gpus: list[str]) -> list[Child]:
    """The processes of the run in `out` (processes.json), each given a GPU in turn (none on a CPU)."""
    return [Child(index, directory, seed_slice, gpus[index % len(gpus)] if gpus else None)
            for index, (directory, seed_slice) in enumerate(checkpoint.process_dirs(out))]


def start(out: Path, run: checkpoint.SavedRun, processes: int, overwrite: bool) -> None:
    """A new run in `out` for `processes` processes: its files and each process's run directory."""
    run_steps.open_run_dir(out, run, resume=False, writer=True, overwrite=overwrite)
    shutil.rmtree(out / PROCESSES_DIR, ignore_errors=True)  # an overwritten run's processes
    checkpoint.start_run(out, run)
    per_process = run.seeds // processes
    entries = []
    for index in range(processes):
        seed_slice = (index * per_process, (index + 1) * per_process)
        directory = Path(PROCESSES_DIR) / str(index)
        (out / directory).mkdir(parents=True)
        checkpoint.start_run(out / directory, run._replace(seed_slice=seed_slice))
        entries.append({"directory": str(directory), "seed_slice": list(seed_slice)})
    checkpoint.atomic_write(out / checkpoint.PROCESSES_FILE, json.dumps({"processes": entries}, indent=2).encode())


def child_environment(child: Child) -> dict[str, str]:
    env = dict(os.environ)
    if child.gpu is not None:
        env["CUDA_VISIBLE_DEVICES"] = child.gpu
    # mjxsuite as this process imported it, and no second round of processes
    package_root = str(Path(__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (package_root, env.get("PYTHONPATH")) if p)
    env.pop(PROCESSES_ENV, None)
    env["PYTHONUNBUFFERED"] = "1"  # its log.txt as it happens, not when a buffer fills
    env[signals.PARENT_PID_ENV] = str(os.getpid())  # it stops and saves when this process ends, even by SIGKILL
    return env


def finished(child: Child) -> bool:
    return (child.directory / "eval.json").is_file()


def chunks_done(child: Child) -> int:
    """Chunks (PPO/SAC: evaluations) the child has done: its metrics.jsonl's lines."""
    try:
        with open(child.directory / checkpoint.METRICS_FILE, "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def run_children(children: list[Child], options: list[str], total_chunks: int) -> tuple[dict[int, int], str | None]:
    """Start the unfinished children and wait for them: (exit status by index, the stopping signal's name)."""
    pending = [child for child in children if not finished(child)]
    running: dict[int, subprocess.Popen] = {}
    statuses: dict[int, int] = {child.index: 0 for child in children if finished(child)}
    with signals.ForwardSignals(lambda: list(running.values())) as forwarding:
        if forwarding.requested is not None:  # a signal during the imports: nothing started
            return statuses, forwarding.name
        for child in pending:
            log = open(child.directory / LOG_FILE, "a")
            command = [*CHILD_MJXSUITE, "train", "--out", str(child.directory), "--resume", "--devices", "1", *options]
            # A session of its own: a terminal's Ctrl-C reaches each child once, passed on by this process.
            running[child.index] = subprocess.Popen(command, stdout=log, stderr=subprocess.STDOUT,
                                                    env=child_environment(child), start_new_session=True)
            log.close()
            forwarding.catch_up(running[child.index])
            print(f"{child.describe()}: training, log {child.directory / LOG_FILE}", flush=True)
            if forwarding.requested is not None:  # stopping: start no more
                break
        said, last_said = "", time.monotonic()
        while running:
            time.sleep(0.2)
            for index, process in list(running.items()):
                if process.poll() is not None:
                    statuses[index] = running.pop(index).returncode
                    print(f"{children[index].describe()}: " + ("done" if process.returncode == 0 else
                                                               f"exited with status {process.returncode}"), flush=True)
            if running and time.monotonic() - last_said >= PROGRESS_SECONDS:
                line = "chunks done: " + ", ".join(f"process {child.index} {chunks_done(child)}/{total_chunks}"
                                                    for child in children)
                if line != said:
                    print(line, flush=True)
                said, last_said = line, time.monotonic()
        return statuses, forwarding.name


def failure(children: list[Child], statuses: dict[int, int]) -> ProcessFailed:
    """What failed, and where each failed child's log is (with its last line)."""
    lines = []
    for child in children:
        if statuses.get(child.index, 0) != 0:
            log = child.directory / LOG_FILE
            tail = [line for line in log.read_text(errors="replace").splitlines() if line.strip()][-1:] if log.is_file() else []
            lines.append(f"{child.describe()} failed with exit status {statuses[child.index]}; its log: {log}"
                         + (f" (last line: {tail[0].strip()})" if tail else ""))
    return ProcessFailed("; ".join(lines))


def merge(out: Path, run: checkpoint.SavedRun, children: list[Child], start_time: float):
    """The finished run's eval.json from its processes' ones (every seed in order, the best by
    `agents.run.break_ties` over every seed), and the `RunResult` the command reports (no parameters)."""
    from agents.run import RunResult, break_ties, load_agent, unmeasured_ties

    evals = [json.loads((child.directory / "eval.json").read_text()) for child in children]
    mean_return = [value for e in evals for value in e["mean_return"]]
    tie_break = [value for e in evals for value in e.get("tie_break_return") or [None] * len(e["mean_return"])]
    measured = {i: v for i, v in enumerate(tie_break) if v is not None}
    # The processes measured their own ties as this would: only seeds tied across processes load here.
    agent = params = None
    if unmeasured_ties(mean_return, measured):
        _, _, agent, params = load_agent(out)
    best_seed, tie_break_now = break_ties(agent, run.env, run.env_options, params, mean_return, run.seed,
                                         measured=measured)
    slowest = max(evals, key=lambda e: e["wall_s"])  # where the run's time went: its slowest process
    parts = slowest["wall_parts_s"]
    result = RunResult(params=None, train_state=None, mean_return=mean_return,
                       solve_step=[s for e in evals for s in e["solve_step"]],
                       solve_wall_s=[s for e in evals for s in e["solve_wall_s"]],
                       compile_s=max(e["compile_s"] for e in evals), setup_s=parts["start-up"], train_s=parts["train"],
                       judge_s=parts["judge"], save_s=parts["saves"], eval_s=parts["evaluation"],
                       judges=max(e["judged_chunks"] for e in evals), chunks_done=max(e["chunks"] for e in evals),
                       devices=len(children), processes=len(children), best_seed=best_seed,
                       diverged=[d for e in evals for d in e.get("diverged_seeds", [])])
    # The parent's wall time, at least the slowest process's; what its parts leave is "other"
    result.finish(start_time, {"wall_s": max(0.0, slowest["wall_s"] - (time.perf_counter() - start_time))})
    summary = result.summary(run.agent, run.env, run.seeds, [tie_break_now.get(i) for i in range(len(mean_return))],
                             processes=len(children))
    checkpoint.atomic_write(out / "eval.json", json.dumps(summary, indent=2).encode())
    return result


def train(out: Path, run: checkpoint.SavedRun, total_chunks: int, options: list[str], gpus: list[str]):
    """Train (or go on training) the processes of the run in `out` and merge their results: the
    `RunResult` to report, interrupted when a signal stopped them. ProcessFailed when one failed."""
    from agents.run import RunResult

    start_time = time.perf_counter()
    children = children_of(out, gpus)
    statuses, stop_signal = run_children(children, options, total_chunks)
    if stop_signal is not None:
        saved = min(checkpoint.chunks_saved(child.directory) for child in children)
        return RunResult(params=None, train_state=None, interrupted=True, stop_signal=stop_signal,
                         saved_chunks=saved, total_chunks=total_chunks, processes=len(children))
    if any(statuses.values()) or len(statuses) < len(children):
        raise failure(children, statuses)
    return merge(out, run, children, start_time)
