"""What a costly reset costs a multi-seed run, before and after it decides once for every seed.

`--seeds` vmapped batches of `--envs` auto-resetting envs (`envs.BatchedAutoReset(...,
under_vmap=True)`, as the agents build their training env), `--steps` random-action steps in one
`lax.scan` inside one `jit`, for an env whose reset runs physics (dm_control's cheetah settles for
200 steps): once with the switch over each seed's envs, which the seeds' vmap turns into a select
that resets every env on every step (what ran before), once with the switch over every seed's envs
at once (`envs.batching.folds_vmap`). Both programs give the same rewards (printed); the figure is
the median of `--repeats` runs after a warm-up, compile time apart.

    python -m benchmarks.costly_reset [--env dmc-cheetah-run] [--seeds 2] [--envs 16] [--steps 100] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax

import envs


def compiled(env, seeds: int, num_envs: int, steps: int, across_seeds: bool):
    batch = envs.BatchedAutoReset(env, num_envs, under_vmap=True)
    batch.reset_across_vmap = across_seeds and batch.reset_by_index

    def run(key):
        def body(state, step_key):
            action = jax.random.uniform(step_key, (num_envs, env.action_size), minval=-1, maxval=1)
            state = batch.step(state, action)
            return state, state.reward.sum()

        return jax.lax.scan(body, batch.reset(key), jax.random.split(key, steps))[1].sum()

    start = time.perf_counter()
    program = jax.jit(jax.vmap(run)).lower(jax.random.split(jax.random.PRNGKey(0), seeds)).compile()
    return program, time.perf_counter() - start


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="dmc-cheetah-run")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--envs", type=int, default=16)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", help="also write the record to this file")
    args = parser.parse_args(argv)
    env = envs.make(args.env)
    keys = jax.random.split(jax.random.PRNGKey(1), args.seeds)
    record = {"kind": "costly-reset", "env": args.env, "seeds": args.seeds, "num_envs": args.envs,
              "steps": args.steps, "repeats": args.repeats, "platform": jax.default_backend()}
    for name, across in (("every_env_every_step", False), ("once_for_every_seed", True)):
        program, compile_s = compiled(env, args.seeds, args.envs, args.steps, across)
        total = jax.block_until_ready(program(keys))
        spent = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            jax.block_until_ready(program(keys))
            spent.append(time.perf_counter() - start)
        record[name] = {"env_steps_per_s": args.seeds * args.envs * args.steps / statistics.median(spent),
                        "run_s": spent, "compile_s": compile_s, "rewards": [float(x) for x in total]}
        print(f"{name:<22}{record[name]['env_steps_per_s']:>12,.0f} env-steps/s  compile {compile_s:.1f} s  "
              f"rewards {record[name]['rewards']}", flush=True)
    record["ratio"] = record["once_for_every_seed"]["env_steps_per_s"] / record["every_env_every_step"]["env_steps_per_s"]
    print(f"once for every seed / every env every step: {record['ratio']:.1f}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(record, f, indent=1)


if __name__ == "__main__":
    main()
