"""DQN speed: steps/s, updates/s, compile time and wall-clock time-to-solve CartPole-v1.

    python -m agents.bench [--quick] [--json FILE]

Rows:
- `dqn-solve`: one seed and 16 vmapped seeds on each backend, default config, training
  stops once every seed's greedy evaluation reached 475; time-to-solve with and
  without compile (wall time from the start of `train_run`).
- `dqn-throughput` (with `--quick`, for 16 seeds): env steps/s and updates/s over
  a few chunks, compile excluded, no solving.
- `dqn-seed-scaling`: env steps/s of 16 vmapped seeds over that of one seed.
- `article`: the seed-article setup (1 env, MLP 64-64-64, batch 32, buffer 512,
  gamma 0.9, hard target copy every 10 updates, lr 1e-3, 20,000 steps; plain DQN: no
  double Q, no gradient clipping, as published) on our agent,
  steps/s with compile excluded.
- replay add/sample latency against flashbax, when flashbax is installed.
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np

from agents.bench_replay import bench_replay, format_table
from agents.dqn import DQNConfig
from agents.run import train_run

ARTICLE = DQNConfig(
    total_steps=20_000, num_envs=1, hidden=(64, 64, 64), batch_size=32, buffer_size=512, gamma=0.9,
    target_update="hard", target_period=10, learning_rate=1e-3, max_grad_norm=None, double_dqn=False,
    eval_every=20_000,
)


def solve_record(env: str, seeds: int, config: DQNConfig) -> dict:
    result = train_run(env, config, seeds=seeds, progress=False, stop_when_solved=True)
    steps = len(result.history) * config.eval_every
    run_s = result.wall_s - result.compile_s
    solved = [s for s in result.solve_wall_s if s is not None]
    solve_steps = [s for s in (result.solve_step or []) if s is not None]
    return {
        "lib": "mjxsuite", "kind": "dqn-solve", "env": env, "seeds": seeds, "device": jax.devices()[0].device_kind,
        "compile_s": result.compile_s,
        "steps_per_s": steps * seeds / run_s,  # env steps over all seeds, evaluation included
        "updates_per_s": steps * seeds / config.train_every * config.gradient_steps / run_s,
        "solved": f"{len(solved)}/{seeds}",
        "time_to_solve_s": max(solved) if solved else None,  # all seeds, compile included
        "time_to_solve_excl_compile_s": max(solved) - result.compile_s if solved else None,
        "median_solve_step": float(np.median(solve_steps)) if solve_steps else None,
        "final_mean_return": float(np.mean(result.mean_return)) if result.mean_return else None,
    }


def throughput_record(env: str, seeds: int, config: DQNConfig, chunks: int = 3) -> dict:
    """Env steps/s and updates/s over `chunks` chunks after the first (compile excluded)."""
    result = train_run(env, config, seeds=seeds, progress=False, stop_after_chunks=chunks + 1)
    speeds = [h["steps_per_s"] for h in result.history[1:]]
    steps_per_s = float(np.median(speeds))
    return {
        "lib": "mjxsuite", "kind": "dqn-throughput", "env": env, "seeds": seeds, "device": jax.devices()[0].device_kind,
        "compile_s": result.compile_s, "chunks": chunks, "steps_per_s": steps_per_s,
        "updates_per_s": steps_per_s / config.train_every * config.gradient_steps,
    }


def seed_scaling_records(records: list[dict]) -> list[dict]:
    """16-seed over 1-seed env steps/s, per env (from solve or throughput rows)."""
    speed = {(r["env"], r["seeds"]): r["steps_per_s"] for r in records
             if r.get("kind") in ("dqn-solve", "dqn-throughput")}
    rows = []
    for (env, seeds), many in sorted(speed.items()):
        one = speed.get((env, 1))
        if seeds > 1 and one:
            rows.append({"lib": "mjxsuite", "kind": "dqn-seed-scaling", "env": env, "seeds": seeds,
                         "device": jax.devices()[0].device_kind, "ratio": many / one,
                         "steps_per_s_one_seed": one, "steps_per_s": many})
    return rows


def dqn_records(quick: bool = False, print_rows: bool = True, replay: bool = True) -> list[dict]:
    """The DQN figures. `quick`: time-to-solve with one seed on both backends, 16-seed throughput
    over a few chunks on the analytic CartPole; otherwise the article setup, time-to-solve with
    1 and 16 seeds on both backends, and replay vs flashbax."""
    records = [] if quick else [article_record()]
    if records and print_rows:
        r = records[0]
        print(f"article setup: {r['steps_per_s']:,.0f} env-steps/s, median of {[round(v) for v in r['steps_per_s_runs']]} "
              f"(compile {r['compile_s']:.1f}s excluded), greedy return {r['final_mean_return']:.1f}", flush=True)
    for env in ("cartpole", "cartpole-mjx"):
        for seeds in (1, 16):
            if quick and seeds > 1:
                if env != "cartpole":  # its compile alone would take a sixth of --quick's budget on 2 cores
                    continue
                r = throughput_record(env, seeds, DQNConfig(), chunks=2)
            else:
                r = solve_record(env, seeds, DQNConfig())
            records.append(r)
            if print_rows:
                print(_describe(r), flush=True)
    records += seed_scaling_records(records)
    if replay and not quick:
        try:
            replay_rows = bench_replay()
            records.extend({"kind": "replay", **row} for row in replay_rows)
            if print_rows:
                print("replay buffers, µs per op; ratio = flashbax / ours (> 1: we are faster)")
                print(format_table(replay_rows))
        except SystemExit as missing:  # flashbax is an optional benchmark dependency
            records.append({"kind": "replay", "skipped": str(missing)})
            if print_rows:
                print(missing)
    return records


def _describe(r: dict) -> str:
    speed = f"{r['steps_per_s']:,.0f} env-steps/s, {r['updates_per_s']:,.0f} updates/s (compile {r['compile_s']:.1f}s)"
    if r["kind"] == "dqn-throughput":
        return f"{r['env']:<13} seeds {r['seeds']:>2}: {speed}"
    solve = (f"time-to-solve {r['time_to_solve_s']:.1f}s with compile, {r['time_to_solve_excl_compile_s']:.1f}s without"
             if r["time_to_solve_s"] is not None else "time-to-solve n/a")
    return f"{r['env']:<13} seeds {r['seeds']:>2}: solved {r['solved']}, {solve}; median solve step " \
           f"{r['median_solve_step']}; {speed}"


def article_record(repeats: int = 3) -> dict:
    """Median over `repeats` fresh runs: this machine's run-to-run noise is tens of percent."""
    runs = [train_run("cartpole", ARTICLE, seeds=1, progress=False) for _ in range(repeats)]
    speeds = sorted(r.history[0]["steps_per_s"] for r in runs)
    return {
        "lib": "mjxsuite", "kind": "dqn-article-setup", "env": "cartpole", "seeds": 1,
        "device": jax.devices()[0].device_kind, "compile_s": float(np.median([r.compile_s for r in runs])),
        "steps_per_s": float(np.median(speeds)), "steps_per_s_runs": speeds,
        "final_mean_return": float(np.mean([r.mean_return[0] for r in runs])),
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true",
                        help="one-seed time-to-solve, 16-seed throughput only; no article setup or replay rows")
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    records = dqn_records(args.quick)
    for r in records:
        if r["kind"] == "dqn-seed-scaling":
            print(f"{r['env']}: {r['seeds']} vmapped seeds run {r['ratio']:.1f}x the env-steps/s of one seed")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records, f, indent=2)


if __name__ == "__main__":
    main()
