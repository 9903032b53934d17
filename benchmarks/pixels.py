"""Pixel env-steps/s (issue 46): an MJX task observed through its camera, beside the same task
with its state observation, on one device.

Each run: `wrap_for_training` (auto-reset, no episode statistics) of `num_envs` envs, uniform
random actions, one `lax.scan` in one `jit`; every step reads its observation (the mean of the
frames, or of the state vector), as a policy would, so XLA keeps the render in the loop. The reset
runs in a program of its own, untimed (dm_control's cheetah settles for 200 physics steps in a
reset, which would outweigh the steps timed). Compile time is kept apart; pixel and state runs
alternate (A B A B ...) and the figure is the median.
Records (JSON, `--json FILE`) are kind "pixels": `observation` ("pixels" or "state"), `steps_per_s`,
`overflow_steps` (MuJoCo Warp's dropped contacts: a figure with overflows is no physics figure), and
kind "pixels-ratio": pixel steps/s over state steps/s at each size.

On a GPU (impl="warp", MuJoCo Warp's batch renderer):

    python -m benchmarks.pixels --impl warp --tasks cartpole-swingup-mjx half-cheetah \
        --sizes 1024 4096 16384 --json pixels-gpu.json

Under Warp each task runs in a process of its own (`benchmarks.suite.each_task_alone`).
On the CPU it is a smoke test: `python -m benchmarks.pixels --sizes 2 --steps 3 --size 8`.
"""

from __future__ import annotations

import argparse
import functools
import json
import statistics
import sys
import time

import jax
import jax.numpy as jnp

import envs
from benchmarks import gpu_profile
from benchmarks.suite import each_task_alone, without_options, write_records


def rollout_fn(task: str, num_envs: int, steps: int, options: dict):
    """`(reset, run)`: `reset(key)` the batch's first state; `run(state, key) -> (sum of the
    observations' means, overflowed env-steps)` over `steps` steps from it."""
    env = envs.wrap_for_training(envs.make(task, **options), num_envs, episode_stats=False)

    def body(carry, _):
        state, key, total, overflowed = carry
        key, action_key = jax.random.split(key)
        action = jax.random.uniform(action_key, (num_envs, env.action_size), minval=-1.0, maxval=1.0)
        state = env.step(state, action)
        seen = state.obs.astype(jnp.float32).mean()  # what a policy reads each step
        return (state, key, total + seen, overflowed + (state.info["overflow"] > 0).sum()), None

    @jax.jit
    def run(state, key):
        (_, _, total, overflowed), _ = jax.lax.scan(body, (state, key, jnp.zeros(()), jnp.zeros((), jnp.int32)),
                                                    None, steps)
        return total, overflowed

    return jax.jit(env.reset), run


def measure(tasks, sizes, impl: str, steps: int, repeats: int, size: int, depth: bool, frame_stack: int,
            action_repeat: int = 1, trace: str | None = None) -> list[dict]:
    """Each task and size: pixel and state runs timed (records as the module says); with `trace`,
    one more run of each under `jax.profiler`, its kernels in its record (`gpu_profile.kernels_of`)."""
    device = jax.devices()[0].device_kind
    records = []
    pixel_options = {"observation": "pixels", "width": size, "height": size, "depth": depth,
                     "frame_stack": frame_stack, "action_repeat": action_repeat}  # 1: the renderer's cost alone
    for task in tasks:
        for num_envs in sizes:
            runs, found = {}, {}
            for observation, options in (("pixels", pixel_options), ("state", {})):
                reset, run = rollout_fn(task, num_envs, steps, {"impl": impl, **options})
                first = jax.block_until_ready(reset(jax.random.PRNGKey(0)))
                start = time.perf_counter()
                _, overflowed = jax.block_until_ready(run(first, jax.random.PRNGKey(0)))
                runs[observation] = functools.partial(run, first)
                found[observation] = {"kind": "pixels", "env": task, "impl": impl, "observation": observation,
                                      "num_envs": num_envs, "steps": steps, "repeats": repeats, "device": device,
                                      "compile_s": time.perf_counter() - start, "overflow_steps": int(overflowed),
                                      "run_s": [], **(pixel_options if observation == "pixels" else {})}
            for r in range(repeats):  # alternate, so a slow spell of the machine hits both
                for observation, run in runs.items():
                    start = time.perf_counter()
                    jax.block_until_ready(run(jax.random.PRNGKey(r + 1)))
                    found[observation]["run_s"].append(time.perf_counter() - start)
            if trace:
                for observation, run in runs.items():
                    found[observation] |= gpu_profile.kernels_of(
                        {observation: functools.partial(run, jax.random.PRNGKey(0))}, f"{trace}/{task}-{num_envs}")
            for record in found.values():
                record["steps_per_s"] = num_envs * steps / statistics.median(record["run_s"])
                records.append(record)
                print(json.dumps({k: record[k] for k in ("env", "observation", "num_envs", "steps_per_s",
                                                          "compile_s", "overflow_steps")}), flush=True)
            ratio = found["pixels"]["steps_per_s"] / found["state"]["steps_per_s"]
            records.append({"kind": "pixels-ratio", "env": task, "impl": impl, "num_envs": num_envs,
                            "device": device, "pixels_over_state": ratio})
            print(json.dumps(records[-1]), flush=True)
    return records


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["cartpole-swingup-mjx", "half-cheetah"])
    parser.add_argument("--sizes", nargs="+", type=int, default=[1024, 4096, 16384])
    parser.add_argument("--impl", default="jax", choices=["jax", "warp"])
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--size", type=int, default=64, help="image width and height")
    parser.add_argument("--depth", action="store_true")
    parser.add_argument("--frame-stack", type=int, default=1)
    parser.add_argument("--action-repeat", type=int, default=1, help="task steps per pixel env step")
    parser.add_argument("--json", help="write the records here")
    parser.add_argument("--trace", metavar="DIR", help="trace one more run of each there; kernels in its record")
    args = parser.parse_args(argv)
    if args.impl == "warp" and len(args.tasks) > 1:
        argv = sys.argv[1:] if argv is None else argv
        each_task_alone("benchmarks.pixels", without_options(argv, ("--tasks", "--json")), args.tasks, args.json)
        return 0
    records = measure(args.tasks, args.sizes, args.impl, args.steps, args.repeats, args.size, args.depth,
                      args.frame_stack, args.action_repeat, args.trace)
    if args.json:
        write_records(args.json, records)
    return 0


if __name__ == "__main__":
    sys.exit(main())
