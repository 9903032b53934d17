"""DQN speed: steps/s, updates/s, compile time and wall-clock time-to-solve CartPole-v1.

    python -m agents.bench [--quick] [--json FILE]

Rows:
- `solve`: one seed and 16 vmapped seeds on each backend, default config, training
  stops once every seed's greedy evaluation reached 475; wall time includes compile.
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
    return {
        "lib": "mjxsuite", "kind": "dqn-solve", "env": env, "seeds": seeds, "device": jax.devices()[0].device_kind,
        "compile_s": result.compile_s,
        "steps_per_s": steps * seeds / run_s,  # env steps over all seeds, evaluation included
        "updates_per_s": steps * seeds / config.train_every * config.gradient_steps / run_s,
        "solved": f"{len(solved)}/{seeds}",
        "time_to_solve_s": max(solved) if solved else None,  # all seeds, compile included
        "median_solve_step": float(np.median([s for s in result.solve_step if s is not None])) if solved else None,
        "final_mean_return": float(np.mean(result.mean_return)),
    }


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
    parser.add_argument("--quick", action="store_true", help="one seed per backend, skip the 16-seed runs")
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    records = [article_record()]
    r = records[0]
    print(f"article setup: {r['steps_per_s']:,.0f} env-steps/s, median of {[round(v) for v in r['steps_per_s_runs']]} "
          f"(compile {r['compile_s']:.1f}s excluded), "
          f"greedy return {r['final_mean_return']:.1f}", flush=True)
    for env in ("cartpole", "cartpole-mjx"):
        for seeds in (1,) if args.quick else (1, 16):
            r = solve_record(env, seeds, DQNConfig())
            records.append(r)
            print(f"{env:<13} seeds {seeds:>2}: solved {r['solved']}, time-to-solve {r['time_to_solve_s'] or float('nan'):.1f}s "
                  f"(compile {r['compile_s']:.1f}s included); median solve step {r['median_solve_step']}; "
                  f"{r['steps_per_s']:,.0f} env-steps/s, {r['updates_per_s']:,.0f} updates/s", flush=True)
    try:
        replay_rows = bench_replay()
        records.extend(replay_rows)
        print("replay buffers, µs per op; ratio = flashbax / ours (> 1: we are faster)")
        print(format_table(replay_rows))
    except SystemExit as missing:  # flashbax is an optional benchmark dependency
        print(missing)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records, f, indent=2)


if __name__ == "__main__":
    main()
