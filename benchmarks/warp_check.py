"""MuJoCo Warp beside MJX's JAX implementation, and what randomised physics costs (issue #18).

On a GPU with warp-lang (`pip install 'mjxsuite[warp]'`):

1. `impl="warp"` against `impl="jax"`: `cartpole-mjx` and `acrobot-mjx` stepped 100 times from
   the same starts with the same random actions; the max abs difference of qpos and qvel.
2. env-steps/s of both implementations (random actions, auto-reset, as `benchmarks.env_throughput`).
3. env-steps/s of `cartpole-mjx` with `--randomize body_mass:pole=0.05:0.5` (the training
   range, which recomputes mj_setConst's fields at every reset) against the plain task.

    python -m benchmarks.warp_check [--sizes 4096 131072] [--steps N] [--json FILE]

It runs on the CPU too (`--sizes 4 --steps 5` is a smoke test); without a CUDA GPU or
warp-lang the Warp rows say why they were skipped.
"""

from __future__ import annotations

import argparse
import json
import statistics

import jax
import jax.numpy as jnp
import numpy as np

import envs
from benchmarks.env_throughput import device_name, rollout_fn, steps_for, time_side_by_side

TASKS = ("cartpole-mjx", "acrobot-mjx")
RANDOMIZED = {"randomize": {"body_mass:pole": [0.05, 0.5]}}  # DQN's training range (issue #18)


def warp_missing() -> str | None:
    """Why `impl="warp"` cannot run here, or None."""
    try:
        envs.make(TASKS[0], impl="warp")
    except RuntimeError as err:
        return str(err)
    return None


def max_difference(env_name: str, num_envs: int = 64, steps: int = 100) -> float:
    """Max abs difference of qpos and qvel between impl="warp" and impl="jax" over `steps`
    steps from the same starts under the same random actions (no auto-reset)."""

    def trajectory(env):
        def run(keys, actions):
            state = jax.vmap(env.reset)(keys)

            def body(state, action):
                state = jax.vmap(env.step)(state, action)
                return state, jnp.concatenate([state.pipeline_state.qpos, state.pipeline_state.qvel], axis=-1)

            return jax.lax.scan(body, state, actions)[1]

        return jax.jit(run)

    ours = envs.make(env_name)
    keys = jax.random.split(jax.random.PRNGKey(0), num_envs)
    actions = jax.random.randint(jax.random.PRNGKey(1), (steps, num_envs), 0, ours.num_actions)
    reference = trajectory(ours)(keys, actions)
    warp = trajectory(envs.make(env_name, impl="warp"))(keys, actions)  # the same keys: the same starts
    return float(jnp.abs(np.asarray(warp) - np.asarray(reference)).max())


def throughput(env_name: str, num_envs: int, steps: int, env_options: dict, repeats: int) -> float:
    run = rollout_fn(env_name, num_envs, steps, env_options)
    compiled = run.lower(jax.random.PRNGKey(0)).compile()
    jax.block_until_ready(compiled(jax.random.PRNGKey(0)))  # warm-up
    return num_envs * steps / statistics.median(time_side_by_side([compiled], repeats)[0])


def records(sizes: list[int], steps: int | None = None, repeats: int = 3) -> list[dict]:
    missing = warp_missing()
    found = []
    for env_name in TASKS:
        record = {"kind": "warp-vs-jax", "env": env_name, "steps": 100, "device": device_name()}
        found.append({**record, "skipped": missing} if missing else {**record, "max_abs_diff": max_difference(env_name)})
    jobs = [(f"{env_name} impl={impl}", env_name, {"impl": impl}) for env_name in TASKS for impl in ("jax", "warp")]
    jobs += [("cartpole-mjx randomized", "cartpole-mjx", RANDOMIZED)]
    for num_envs in sizes:
        for label, env_name, options in jobs:
            n_steps = steps or steps_for(num_envs, mjx=True)
            record = {"kind": "warp-throughput", "label": label, "env": env_name, "env_options": options,
                      "num_envs": num_envs, "steps": n_steps, "device": device_name()}
            if options.get("impl") == "warp" and missing:
                found.append({**record, "skipped": missing})
                continue
            found.append({**record, "steps_per_s": throughput(env_name, num_envs, n_steps, options, repeats)})
    return found


def table(found: list[dict]) -> str:
    lines = []
    for r in found:
        if r["kind"] == "warp-vs-jax":
            what = f"max |warp - jax| over 100 steps: {r['max_abs_diff']:.2e}" if "max_abs_diff" in r else "skipped"
            lines.append(f"{r['env']:<28} {what}")
    by_size: dict[int, dict[str, float | None]] = {}
    for r in found:
        if r["kind"] == "warp-throughput":
            by_size.setdefault(r["num_envs"], {})[r["label"]] = r.get("steps_per_s")
    for num_envs, row in by_size.items():
        for label, rate in row.items():
            lines.append(f"{label:<28} {num_envs:>8} envs  " + (f"{rate:.3g} env-steps/s" if rate else "skipped"))
        plain, randomized = row.get("cartpole-mjx impl=jax"), row.get("cartpole-mjx randomized")
        if plain and randomized:
            lines.append(f"{'randomized / plain cost':<28} {num_envs:>8} envs  {plain / randomized:.2f}x per step")
    if any("skipped" in r for r in found):
        lines.append("skipped: " + next(r["skipped"] for r in found if "skipped" in r))
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.warp_check", description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[4096, 131072], help="numbers of envs")
    parser.add_argument("--steps", type=int, help="scan length per timed run (default: by batch size)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", metavar="FILE", help="write the records as JSON")
    args = parser.parse_args(argv)
    found = records(args.sizes, args.steps, args.repeats)
    print(f"device: {device_name()}\n" + table(found))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(found, f, indent=2)


if __name__ == "__main__":
    main()
