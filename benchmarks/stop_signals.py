"""Ctrl-C at random moments of concurrent `mjxsuite train` runs (issue #42): each must exit with
130, having saved what it did, never aborting (a KeyboardInterrupt inside MuJoCo Warp's FFI
callback used to end in `free(): invalid size`, exit -6).

    python -m benchmarks.stop_signals --env hopper --runs 10 --low 3 --high 90 \\
        [--train-args "--agent ppo --impl warp"] [--json FILE]

The runs start together (one GPU shared; each gets 0.9/runs of its memory); each gets SIGINT at
a moment drawn uniformly from [low, high] s after the start, so the signals land in start-up,
compile, training, evaluation and saving. The record says, per run, the exit status, the
seconds from the signal to the exit, what was saved, and what the run printed.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import shlex
import signal
import subprocess
import time
from pathlib import Path

from agents import processes


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.stop_signals", description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="hopper")
    parser.add_argument("--train-args", default="--agent ppo --impl warp")
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--low", type=float, default=3.0)
    parser.add_argument("--high", type=float, default=90.0)
    parser.add_argument("--out", default="runs/stop-signals")
    parser.add_argument("--wait", type=float, default=600.0, help="seconds to wait for each run's exit after its signal")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args(argv)
    root = Path(args.out) / args.env
    root.mkdir(parents=True, exist_ok=True)
    draw = random.Random(f"{args.env}-{args.runs}")
    env = {**os.environ, "XLA_PYTHON_CLIENT_MEM_FRACTION": f"{0.9 / args.runs:.3f}"}
    runs = []
    for i in range(args.runs):
        out, log = root / f"run{i}", root / f"run{i}.log"
        command = [*processes.MJXSUITE, "train",
                   "--env", args.env, *shlex.split(args.train_args), "--out", str(out), "--overwrite"]
        process = subprocess.Popen(command, env=env, stdout=open(log, "w"), stderr=subprocess.STDOUT)
        runs.append({"process": process, "at_s": round(draw.uniform(args.low, args.high), 1), "out": out, "log": log})
    start = time.monotonic()
    for run in sorted(runs, key=lambda r: r["at_s"]):
        time.sleep(max(0.0, start + run["at_s"] - time.monotonic()))
        run["process"].send_signal(signal.SIGINT)
        run["sent"] = time.monotonic()
    # Poll every run, so that each exit time is the moment it exited, not when its turn to be waited on came.
    deadline = {id(run): run["sent"] + args.wait for run in runs}
    while any("exited" not in run for run in runs):
        for run in runs:
            if "exited" in run:
                continue
            if run["process"].poll() is not None:
                run["exited"] = time.monotonic()
            elif time.monotonic() > deadline[id(run)]:
                run["process"].kill()
                run["process"].wait()
                run["exited"] = None
        time.sleep(0.2)
    results = []
    for run in runs:
        status = run["process"].returncode if run["exited"] is not None else None
        text = run["log"].read_text(errors="replace").replace("\r", "\n")
        said = [line for line in text.splitlines() if "stopped by" in line or "Traceback" in line or "free()" in line]
        progress = run["out"] / "progress.json"
        results.append({"signal_at_s": run["at_s"], "status": status,
                        "exit_after_signal_s": None if status is None else round(run["exited"] - run["sent"], 1),
                        "saved": json.loads(progress.read_text()) if progress.is_file() else None,
                        "clean": status == 130 and "Traceback" not in text and "free()" not in text, "said": said[-2:]})
    summary = {"kind": "stop-signals", "env": args.env, "train_args": args.train_args, "runs": args.runs,
               "clean_exits": sum(r["clean"] for r in results), "results": results}
    print(json.dumps({k: v for k, v in summary.items() if k != "results"}))
    for r in results:
        print(r)
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
