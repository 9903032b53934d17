"""DQN speed: steps/s, updates/s, compile time and wall-clock time-to-solve CartPole-v1.

    python -m benchmarks.dqn [--quick] [--json FILE]

Rows:
- `dqn-solve`: default config, training stops once every seed's greedy evaluation
  reached 475; time-to-solve with and without compile (wall time from the start of
  `train_run`). One seed: `SOLVE_SEEDS` separate runs (seeds 0, 1, ...), their median
  and range, since one seed's solve step is a lottery (4k to 25k steps); 16 seeds
  (as `train_run` runs them on the device): one run, until the last of them solved.
- `dqn-throughput`: env steps/s and updates/s of 1 and 16 seeds over a few chunks after
  the first, compile excluded, no solving (training only, with its per-chunk greedy
  evaluation). 16 seeds run as `train_run` runs them on the device (`seed_axis`:
  vmapped on accelerators, mapped on the CPU), and on the CPU vmapped as well.
- `dqn-seed-scaling`: from those, 16 seeds' env steps/s over one seed's, and the time 16
  seeds take for 16 times the work, as a multiple of one seed's time.
- `article`: the seed-article setup (1 env, MLP 64-64-64, batch 32, buffer 512,
  gamma 0.9, hard target copy every 10 updates, lr 1e-3, 20,000 steps; plain DQN: no
  double Q, no gradient clipping, as published) on our agent,
  steps/s with compile excluded.
- replay add/sample latency against flashbax, when flashbax is installed.

`--quick`: time-to-solve of seed 0 on both backends, throughput on the analytic CartPole only.
"""

from __future__ import annotations

import argparse
import json

import jax
import numpy as np

from benchmarks.replay import bench_replay, format_table
from agents.dqn import PRESETS, DQNConfig
from agents.device_options import default_seed_axis
from agents.run import train_run

ARTICLE = DQNConfig(
    total_steps=20_000, num_envs=1, hidden=(64, 64, 64), batch_size=32, buffer_size=512, gamma=0.9,
    target_update="hard", target_period=10, learning_rate=1e-3, max_grad_norm=None, double_dqn=False,
    eval_every=20_000,
)


SOLVE_SEEDS = 5  # one-seed time-to-solve: median over this many runs


def solve_record(env: str, seeds: int, config: DQNConfig, runs: int = 1, preset: str = "default") -> dict:
    """Time-to-solve of `seeds` seeds trained together; with `runs` > 1, of that many separate runs
    (seed 0, 1, ...), reporting the median and every run."""
    results = [train_run(env, config, seeds=seeds, seed=seed, progress=False, stop_when_solved=True)
               for seed in range(runs)]
    solve_times = [max(r.solve_wall_s) if None not in r.solve_wall_s else None for r in results]
    solved = [t for t in solve_times if t is not None]
    excl = [t - r.compile_s for t, r in zip(solve_times, results) if t is not None]
    solve_steps = [s for r in results for s in (r.solve_step or []) if s is not None]
    return {
        "lib": "mjxsuite", "kind": "dqn-solve", "env": env, "seeds": seeds, "runs": runs, "preset": preset,
        "device": jax.devices()[0].device_kind,
        "compile_s": float(np.median([r.compile_s for r in results])),
        "solved": f"{sum(len([s for s in r.solve_wall_s if s is not None]) for r in results)}/{seeds * runs}",
        "time_to_solve_s": float(np.median(solved)) if len(solved) == runs else None,  # compile included
        "time_to_solve_excl_compile_s": float(np.median(excl)) if len(solved) == runs else None,
        "time_to_solve_runs_s": solve_times,
        "median_solve_step": float(np.median(solve_steps)) if solve_steps else None,
        "final_mean_return": float(np.mean([np.mean(r.mean_return) for r in results if r.mean_return])),
    }


# The first second (issue 44): one seed solves CartPole-v1 (the run's own judge: greedy mean >= 475
# over 64 episodes) within these seconds of training and judging after compile, and with compile.
FIRST_SECOND_S, FIRST_SECOND_WITH_COMPILE_S = 1.0, 3.5


def first_second_record(preset: str = "quick", runs: int = SOLVE_SEEDS) -> dict:
    """`solve_record` of one seed on the analytic CartPole with `preset`, `runs` separate runs
    (seeds 0, 1, ...), as the row "dqn-first-second" with the targets beside the medians."""
    record = solve_record("cartpole", 1, PRESETS[preset], runs=runs, preset=preset)
    record.update(kind="dqn-first-second", target_s=FIRST_SECOND_S, target_with_compile_s=FIRST_SECOND_WITH_COMPILE_S)
    record["met"] = (record["time_to_solve_excl_compile_s"] is not None
                     and record["time_to_solve_excl_compile_s"] <= FIRST_SECOND_S
                     and record["time_to_solve_s"] <= FIRST_SECOND_WITH_COMPILE_S)
    return record


def throughput_record(env: str, seeds: int, config: DQNConfig, chunks: int = 3, seed_axis: str | None = None) -> dict:
    """Env steps/s and updates/s over `chunks` chunks after the first (compile excluded)."""
    seed_axis = seed_axis or default_seed_axis()
    result = train_run(env, config, seeds=seeds, progress=False, stop_after_chunks=chunks + 1, seed_axis=seed_axis)
    speeds = [h["steps_per_s"] for h in result.history[1:]]
    steps_per_s = float(np.median(speeds))
    return {
        "lib": "mjxsuite", "kind": "dqn-throughput", "env": env, "seeds": seeds,
        "seed_axis": seed_axis if seeds > 1 else "one seed", "device": jax.devices()[0].device_kind,
        "compile_s": result.compile_s, "chunks": chunks, "steps_per_s": steps_per_s,
        "updates_per_s": steps_per_s / (config.num_envs * config.train_every) * config.gradient_steps,
    }


def seed_scaling_records(records: list[dict]) -> list[dict]:
    """Many seeds' env steps/s over one seed's, per env and seed axis, from the throughput rows;
    `time_ratio` is the time the seeds take for their work, as a multiple of one seed's time
    for its share."""
    throughput = [r for r in records if r.get("kind") == "dqn-throughput"]
    one = {r["env"]: r["steps_per_s"] for r in throughput if r["seeds"] == 1}
    return [{"lib": "mjxsuite", "kind": "dqn-seed-scaling", "env": r["env"], "seeds": r["seeds"],
             "seed_axis": r["seed_axis"], "device": r["device"], "ratio": r["steps_per_s"] / one[r["env"]],
             "time_ratio": r["seeds"] * one[r["env"]] / r["steps_per_s"], "steps_per_s_one_seed": one[r["env"]],
             "steps_per_s": r["steps_per_s"]}
            for r in throughput if r["seeds"] > 1 and r["env"] in one]


def dqn_records(quick: bool = False, print_rows: bool = True, replay: bool = True) -> list[dict]:
    """The DQN figures (see the module docstring); `quick` drops the article setup, the
    16-seed solve runs, the MJX throughput rows and the replay rows, and solves seed 0 only."""
    records = [] if quick else [article_record()]
    if records and print_rows:
        r = records[0]
        print(f"article setup: {r['steps_per_s']:,.0f} env-steps/s, median of {[round(v) for v in r['steps_per_s_runs']]} "
              f"(compile {r['compile_s']:.1f}s excluded), greedy return {r['final_mean_return']:.1f}", flush=True)
    for env in ("cartpole", "cartpole-mjx"):
        rows = [solve_record(env, 1, DQNConfig(), runs=1 if quick else SOLVE_SEEDS)]
        if not quick:
            rows.append(solve_record(env, 16, DQNConfig()))
        if not quick or env == "cartpole":  # MJX's 16-seed compile alone would take a sixth of --quick's budget
            rows += [throughput_record(env, seeds, DQNConfig()) for seeds in (1, 16)]
            if default_seed_axis() != "vmap":  # the CPU maps seeds; report vmapped seeds too
                rows.append(throughput_record(env, 16, DQNConfig(), seed_axis="vmap"))
        records += rows
        if print_rows:
            for r in rows:
                print(_describe(r), flush=True)
    if not quick and default_seed_axis() == "vmap":  # accelerators: many seeds, and the many-env preset
        rows = [throughput_record(env, seeds, DQNConfig()) for env in ("cartpole", "cartpole-mjx") for seeds in (256, 2048)]
        rows += [solve_record(env, 16, PRESETS["many-envs"], preset="many-envs") for env in ("cartpole", "cartpole-mjx")]
        records += rows
        if print_rows:
            for r in rows:
                print(_describe(r), flush=True)
    scaling = seed_scaling_records(records)
    records += scaling
    if print_rows:
        for r in scaling:
            print(_describe(r), flush=True)
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
    if r["kind"] == "dqn-seed-scaling":
        return (f"{r['env']}: {r['seeds']} seeds ({r['seed_axis']}) run {r['ratio']:.1f}x the env-steps/s of one "
                f"seed ({r['time_ratio']:.2f}x its time for {r['seeds']}x the work)")
    if r["kind"] == "dqn-throughput":
        axis = f" ({r['seed_axis']})" if r["seeds"] > 1 else ""
        return (f"{r['env']:<13} seeds {r['seeds']:>2}{axis}: {r['steps_per_s']:,.0f} env-steps/s, "
                f"{r['updates_per_s']:,.0f} updates/s (compile {r['compile_s']:.1f}s excluded)")
    if r["kind"] == "dqn-first-second":
        return (_describe({**r, "kind": "dqn-solve"}) + f"; target {r['target_s']:g} s after compile, "
                f"{r['target_with_compile_s']:g} s with: {'met' if r['met'] else 'not met'}")
    runs = f" (median of {r['runs']} runs: {', '.join(f'{t:.1f}' if t else '–' for t in r['time_to_solve_runs_s'])} s)"
    solve = (f"time-to-solve {r['time_to_solve_s']:.1f}s with compile, {r['time_to_solve_excl_compile_s']:.1f}s without"
             if r["time_to_solve_s"] is not None else "time-to-solve n/a")
    preset = f" ({r['preset']} preset)" if r.get("preset", "default") != "default" else ""
    return (f"{r['env']:<13} seeds {r['seeds']:>2}{preset}: solved {r['solved']}, {solve}{runs if r['runs'] > 1 else ''}; "
            f"median solve step {r['median_solve_step']}")


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
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records, f, indent=2)


if __name__ == "__main__":
    main()
