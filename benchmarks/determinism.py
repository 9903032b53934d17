"""Do two runs with the same seed give the same parameters? (issue #42; docs/reliability.md)

For each job and each of plain / `--deterministic`, two `mjxsuite train` runs of the same seed
and config run at once on one device, both judging every chunk (`--judge-every 1`: the default
cadence reads the clock); then their saved best parameters are compared leaf by leaf, bit for bit,
with their final returns and training seconds.

    python -m benchmarks.determinism --impl jax,warp [--json FILE] \\
        [--job "dqn cartpole-mjx --steps 50000"] [--job "ppo hopper --steps 2000000 --num_evals 3"]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np

DEFAULT_JOBS = ("dqn cartpole-mjx --steps 50000", "ppo hopper --steps 2000000 --num_evals 3")


def best_params_leaves(run_dir: Path) -> list[np.ndarray]:
    """The arrays of a run directory's best parameters, in order."""
    from agents import checkpoint

    return checkpoint.read_leaves(run_dir / checkpoint.POLICY_FILE, "best_params")[1]


def compare(a: Path, b: Path) -> dict:
    try:
        la, lb = (best_params_leaves(d) for d in (a, b))
    except FileNotFoundError:
        return {"error": "a run failed: " + (a.parent / f"{a.name}.log").read_text(errors="replace")[-400:]}
    diffs = [float(np.max(np.abs(x.astype(np.float64) - y.astype(np.float64)), initial=0.0))
             for x, y in zip(la, lb) if x.dtype.kind == "f"]
    ea, eb = (json.loads((d / "eval.json").read_text()) for d in (a, b))
    return {"params_equal": all(np.array_equal(x, y) for x, y in zip(la, lb)), "params_max_abs_diff": max(diffs),
            "returns": [ea["mean_return"], eb["mean_return"]],
            "train_s": [round(e["wall_parts_s"]["train"], 2) for e in (ea, eb)]}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.determinism", description=__doc__.splitlines()[0])
    parser.add_argument("--impl", default="jax", help="comma-separated: jax, warp")
    parser.add_argument("--job", dest="jobs", action="append", help='"AGENT ENV [TRAIN ARGS]", repeatable')
    parser.add_argument("--modes", default="plain,deterministic", help="comma-separated: plain, deterministic")
    parser.add_argument("--out", default="runs/determinism")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args(argv)
    root = Path(args.out)
    root.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "XLA_PYTHON_CLIENT_MEM_FRACTION": "0.4"}
    records = []
    for impl in args.impl.split(","):
        for job in args.jobs or DEFAULT_JOBS:
            agent, task, *extra = shlex.split(job)
            for mode in args.modes.split(","):
                name = f"{agent}-{task}-{impl}-{mode}"
                dirs = [root / f"{name}-{rep}" for rep in "ab"]
                runs = [subprocess.Popen([sys.executable, "-m", "agents.cli", "train", "--env", task, "--agent", agent,
                                          "--impl", impl, *(["--deterministic"] if mode == "deterministic" else []),
                                          *extra, "--out", str(d), "--overwrite", "--checkpoint-seconds", "1e9",
                                          "--judge-every", "1"],
                                         env=env, stdout=open(root / f"{d.name}.log", "w"), stderr=subprocess.STDOUT)
                        for d in dirs]
                for run in runs:
                    run.wait()
                record = {"kind": "determinism", "agent": agent, "env": task, "impl": impl, "mode": mode,
                          "train_args": extra, **compare(*dirs)}
                records.append(record)
                print(json.dumps(record), flush=True)
                if args.json:
                    Path(args.json).write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
