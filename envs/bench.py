"""Env throughput: env-steps/s of both CartPoles at several batch sizes.

Random actions, auto-reset on, `lax.scan` of `--steps` steps inside one jit;
compile time is measured separately, runs are synchronised with
`block_until_ready`, and the figure is the median of `--repeats` runs.

    python -m envs.bench [--envs cartpole cartpole-mjx] [--batch 1 16 256 4096] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax

import envs


def rollout_fn(env_name: str, num_envs: int, steps: int):
    env = envs.wrap_for_training(envs.make(env_name), num_envs)

    def body(carry, _):
        state, key = carry
        key, action_key = jax.random.split(key)
        action = jax.random.randint(action_key, (num_envs,), 0, env.num_actions)
        return (env.step(state, action), key), None

    @jax.jit
    def run(key):
        (state, _), _ = jax.lax.scan(body, (env.reset(key), key), None, steps)
        return state.obs

    return run


def measure(env_name: str, num_envs: int, steps: int, repeats: int) -> dict:
    run = rollout_fn(env_name, num_envs, steps)
    key = jax.random.PRNGKey(0)
    start = time.perf_counter()
    compiled = run.lower(key).compile()
    compile_s = time.perf_counter() - start
    compiled(key).block_until_ready()  # warm-up
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        compiled(jax.random.PRNGKey(i)).block_until_ready()
        times.append(time.perf_counter() - start)
    seconds = statistics.median(times)
    return {
        "lib": "mjxsuite", "env": env_name, "num_envs": num_envs, "steps_per_s": num_envs * steps / seconds,
        "compile_s": compile_s, "device": jax.devices()[0].device_kind,
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", nargs="+", default=["cartpole", "cartpole-mjx"])
    parser.add_argument("--batch", nargs="+", type=int, default=[1, 16, 256, 4096])
    parser.add_argument("--steps", type=int, default=1000, help="scan length per run")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", help="also write the records to this file")
    args = parser.parse_args(argv)
    records = []
    print(f"{'env':<14}{'num_envs':>10}{'env-steps/s':>16}{'compile s':>11}   device")
    for name in args.envs:
        for num_envs in args.batch:
            r = measure(name, num_envs, args.steps, args.repeats)
            records.append(r)
            print(f"{name:<14}{num_envs:>10}{r['steps_per_s']:>16,.0f}{r['compile_s']:>11.2f}   {r['device']}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records, f, indent=2)


if __name__ == "__main__":
    main()
