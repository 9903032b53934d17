"""Agent-steps/s on one device against all local devices, in one process (issue #16's GPU figures).

    python -m benchmarks.scaling                        # 2048 seeds; 64 configs x 32 seeds
    python -m benchmarks.scaling --json scaling.json    # also write the records
    python -m benchmarks.scaling --devices 1,2,4        # other device counts (default: 1 and all)

Two workloads, each trained by `agents.run.train_run` on every device count asked for:
`--seeds` seeds of the default config (any `--FIELD VALUE` of DQNConfig changes it), and a
sweep of `--sweep-configs` configs (a square grid of learning rates x Polyak taus) times
`--sweep-seeds` seeds, both on `--env` (default cartpole-mjx). A figure is the median of the
`--chunks` chunks after the first (which the first call's compile and warm-up distort) of
agent env-steps/s: env steps summed over every agent, per second of wall time. The ratio is
each device count's figure over one device's.

`--whole-process` times what a user waits for instead: the whole `mjxsuite train` process
(start-up, compile, training, the judge, the saves, the final evaluation) with `--out`, its
defaults and a fresh compilation cache (`--warm-cache`: the one an untimed first process of the
same command filled, as a user's second run finds it), once per device count, the run given by
`--train`:

    python -m benchmarks.scaling --whole-process --devices 1,2,4 --train "--env cartpole --seeds 8192"
    python -m benchmarks.scaling --whole-process --devices 1,2 --train "--env hopper --agent ppo --impl warp --seeds 8"

The ratio is one device's process seconds over each count's; `linear_share` is that ratio over
the count (1.0: linear). `--shares` also times one device training each count's share of the
seeds alone (a half for two devices): each device of a K-device run trains that share, so one
device's seconds over it (`best_ratio`) are the most K devices can give, and `of_best` says how
close the run came.

Smoke test on a CPU (forced host devices share the cores, so the ratio says nothing there):

    XLA_FLAGS=--xla_force_host_platform_device_count=2 python -m benchmarks.scaling --env cartpole \\
        --seeds 4 --sweep-configs 4 --sweep-seeds 2 --chunks 1 --total_steps 400 --eval_every 200 \\
        --learning_starts 64 --batch_size 32 --buffer_size 256 --eval_episodes 2
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
import tempfile
from pathlib import Path

import jax
import numpy as np

from agents import checkpoint, processes
from agents.cli import add_config_fields, config_fields, config_from_args
from agents.dqn import DQNConfig
from agents.run import train_run
from benchmarks.end_to_end import _environment, _run, wall_parts


def sweep_grid(configs: int) -> dict[str, list[float]]:
    """A square grid of `configs` (a square number) learning rates x Polyak taus around the defaults."""
    side = math.isqrt(configs)
    if side * side != configs:
        raise SystemExit(f"--sweep-configs must be a square number (a grid of learning rates x taus), got {configs}")
    return {"learning_rate": np.geomspace(2.5e-4, 4e-3, side).tolist(),
            "polyak_tau": np.geomspace(0.0025, 0.04, side).tolist()}


def throughput(env: str, config: DQNConfig, seeds: int, devices: int, chunks: int, sweep: dict | None = None) -> dict:
    result = train_run(env, config, seeds=seeds, devices=devices, sweep=sweep, progress=False,
                       stop_after_chunks=chunks + 1)
    agents = seeds * (math.prod(len(v) for v in sweep.values()) if sweep else 1)
    return {"lib": "mjxsuite", "kind": "dqn-device-scaling", "workload": "sweep" if sweep else "seeds", "env": env,
            "agents": agents, "seeds": seeds, "configs": agents // seeds, "devices": result.devices,
            "device": jax.devices()[0].device_kind, "chunks": chunks, "compile_s": result.compile_s,
            "agent_steps_per_s": float(np.median([h["steps_per_s"] for h in result.history[1:]]))}


def whole_process(train_args: str, devices: int, timeout: float, warm_cache: bool = False) -> dict:
    """`mjxsuite train TRAIN_ARGS --devices K --out D` as one fresh process, timed from start to exit,
    with a fresh compilation cache, or (`warm_cache`) the one an untimed identical process filled: a
    user's second run of the same command. A run trained in processes (one per GPU) also records each
    process's own wall time and breakdown."""
    with tempfile.TemporaryDirectory(prefix="scaling-") as tmp:
        command = ["train", *shlex.split(train_args), "--devices", str(devices), "--out", f"{tmp}/run", "--overwrite"]
        program = [*processes.MJXSUITE, *command]
        environ = _environment(cache=Path(tmp) / "jax-cache")
        if warm_cache:
            _run(program, timeout, environ)
        done, wall = _run(program, timeout, environ)
        summary = json.loads((Path(tmp) / "run" / "eval.json").read_text())
        record = {"lib": "mjxsuite", "kind": "whole-process-scaling", "command": "mjxsuite " + " ".join(command[:-3]),
                  "devices": devices, "compile_cache": "warm" if warm_cache else "fresh", "process_s": wall,
                  "parts_s": wall_parts(done.stdout.strip().splitlines()[-1]),
                  "agents": len(summary["mean_return"]), "median_return": float(np.median(summary["mean_return"]))}
        run_dirs = [Path(tmp) / "run"]
        if summary.get("processes"):
            run_dirs = [directory for directory, _ in checkpoint.process_dirs(Path(tmp) / "run")]
            children = [json.loads((directory / "eval.json").read_text()) for directory in run_dirs]
            record["processes_parts_s"] = [{"wall": child["wall_s"], **child["wall_parts_s"]} for child in children]
        record["most_overflowed_steps"] = most_overflowed_steps(run_dirs)
    return record


def most_overflowed_steps(run_dirs: list[Path]) -> dict[str, int]:
    """The most env steps of one agent's chunk that overflowed MuJoCo Warp's contact or constraint
    buffers, over the runs' chunks (their metrics.jsonl): 0 and 0 for a run whose figures are physics."""
    records = [json.loads(line) for run_dir in run_dirs for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    return {buffer: max([int(np.max(r.get(f"overflow_{buffer}", 0))) for r in records], default=0)
            for buffer in ("contacts", "constraints")}


def with_seeds(train_args: str, seeds: int) -> str:
    """`train_args` with `--seeds` set to `seeds`."""
    words = shlex.split(train_args)
    if "--seeds" not in words:
        raise SystemExit(f"--shares divides the run's --seeds; --train {train_args!r} gives none")
    at = words.index("--seeds") + 1
    return shlex.join([*words[:at], str(seeds), *words[at + 1:]])


def whole_process_scaling(train_args: str, counts: list[int], timeout: float, warm_cache: bool = False,
                          shares: bool = False) -> list[dict]:
    """Each count's whole process against one device's. With `shares`, also one device training each
    count's share of the seeds alone (K devices: a K-th): what K devices give at best, since each trains
    that share, whatever the sharding (GPUs that a share leaves partly idle, each process's fixed costs)."""
    records = []
    for devices in counts:
        record = whole_process(train_args, devices, timeout, warm_cache)
        one = records[0] if records else record
        record["ratio_to_one_device"] = one["process_s"] / record["process_s"]
        record["linear_share"] = record["ratio_to_one_device"] / devices
        records.append(record)
        print(f"{devices} device(s): {record['process_s']:7.1f} s whole process, {record['ratio_to_one_device']:.2f}x "
              f"one device ({record['linear_share']:.2f} of linear); {record['parts_s']}", flush=True)
        for k, parts in enumerate(record.get("processes_parts_s", [])):
            print(f"    process {k}: {parts}", flush=True)
        if shares and devices > 1:
            share = whole_process(with_seeds(train_args, one["agents"] // devices), 1, timeout, warm_cache)
            record["one_device_share"] = share
            record["best_ratio"] = one["process_s"] / share["process_s"]  # at one device's per-process cost
            record["of_best"] = share["process_s"] / record["process_s"]
            print(f"    one device, {share['agents']} seeds: {share['process_s']:7.1f} s, the best {devices} devices can "
                  f"give: {record['best_ratio']:.2f}x ({record['best_ratio'] / devices:.2f} of linear); "
                  f"{share['parts_s']}", flush=True)
    return records


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.scaling", description=__doc__.split("\n\n")[0])
    parser.add_argument("--env", default="cartpole-mjx")
    parser.add_argument("--seeds", type=int, default=2048, help="seeds of the seeds workload (default %(default)s)")
    parser.add_argument("--sweep-configs", type=int, default=64, help="configs of the sweep (a square number)")
    parser.add_argument("--sweep-seeds", type=int, default=32, help="seeds per config of the sweep")
    parser.add_argument("--devices", help="comma-separated device counts (default: 1 and all local devices)")
    parser.add_argument("--chunks", type=int, default=3, help="timed chunks after the first (default %(default)s)")
    parser.add_argument("--json", metavar="FILE", help="write the records (a JSON list) to FILE")
    parser.add_argument("--whole-process", action="store_true",
                        help="time whole `mjxsuite train --train ... --devices K --out D` processes instead")
    parser.add_argument("--train", default="--env cartpole --seeds 8192", help="the run of --whole-process")
    parser.add_argument("--timeout", type=float, default=1800.0, help="seconds allowed to each --whole-process run")
    parser.add_argument("--warm-cache", action="store_true",
                        help="--whole-process: time each count's second process, whose compilation cache the first "
                             "(untimed) filled: a user's second run of the same command")
    parser.add_argument("--shares", action="store_true",
                        help="--whole-process: also time one device training each count's share of --seeds alone, "
                             "the best that count can give")
    add_config_fields(parser, agents=("dqn",))  # --FIELD VALUE, as mjxsuite train takes them
    args = parser.parse_args(argv)
    if args.whole_process:
        counts = [int(k) for k in args.devices.split(",")] if args.devices else [1, jax.local_device_count()]
        if counts[0] != 1:
            raise SystemExit(f"--devices must start with 1 (the baseline of the ratio), got {args.devices}")
        records = whole_process_scaling(args.train, counts, args.timeout, args.warm_cache, args.shares)
        if args.json:
            Path(args.json).write_text(json.dumps(records, indent=2))
        return 0
    config = config_from_args(DQNConfig(), config_fields(args))
    counts = [int(k) for k in args.devices.split(",")] if args.devices else sorted({1, jax.local_device_count()})
    workloads = [("seeds", args.seeds, None), ("sweep", args.sweep_seeds, sweep_grid(args.sweep_configs))]
    records = []
    for name, seeds, grid in workloads:
        for devices in counts:
            record = throughput(args.env, config, seeds, devices, args.chunks, grid)
            one = next((r for r in records if r["workload"] == name and r["devices"] == 1), record)
            record["ratio_to_one_device"] = record["agent_steps_per_s"] / one["agent_steps_per_s"]
            records.append(record)
            print(f"{name:6s} {record['agents']:6d} agents on {devices} device(s): "
                  f"{record['agent_steps_per_s']:14,.0f} agent-steps/s, {record['ratio_to_one_device']:.2f}x one device "
                  f"(compile {record['compile_s']:.1f}s)", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records, f, indent=2)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
