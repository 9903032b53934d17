"""MuJoCo Warp's kernel launches in one env step of a task under impl="warp": what each control step
asks of Warp, counted from Warp's own reports (`warp.config.print_launches`, to a
`warp.ScopedLogger`) while the step's compiled program runs. It runs wherever Warp does, a CPU
with Warp's kernels included (a GPU may choose some kernels otherwise). XLA's own kernels and
copies are not counted: on a GPU `benchmarks.dmc_speed --profile` counts every launch.

    python -m benchmarks.warp_launches [--tasks dmc-pendulum-swingup dmc-walker-walk] [--envs 4] [--json FILE]

Needs warp-lang and mujoco-warp (`pip install -e '.[warp]'`); on a machine without a CUDA GPU the
check that `envs.make(..., impl="warp")` makes for one is lifted here.
"""

from __future__ import annotations

import argparse
import datetime
import json

import jax
import jax.numpy as jnp

import envs
from envs import mjx_env
from envs.wrappers import VmapWrapper

STEPS = 3  # steps counted, after one that compiles the program and loads Warp's modules


class LaunchCounter:
    """A Warp logger (`warp.ScopedLogger`) that counts the kernel launches Warp reports
    (`warp.config.print_launches`) and drops every other message."""

    def __init__(self):
        self.launches = 0

    def info(self, message: str) -> None:
        self.launches += message.startswith("kernel: ")

    def debug(self, message: str) -> None:
        pass

    def warning(self, message: str, category=None, stacklevel: int = 1) -> None:
        pass

    def error(self, message: str) -> None:
        pass


def launches_per_step(task: str, num_envs: int) -> tuple[float, int]:
    """Warp's kernel launches per env step of `num_envs` envs of `task` (zero actions), and the
    env-steps counted on which Warp ran out of a buffer (`info["overflow"]`: not physics)."""
    import warp

    env = VmapWrapper(envs.make(task, impl="warp"), num_envs)
    step = jax.jit(env.step)
    action = jnp.zeros((num_envs, env.action_size))
    state = jax.block_until_ready(step(jax.jit(env.reset)(jax.random.PRNGKey(0)), action))
    counter, overflowed = LaunchCounter(), 0
    with warp.ScopedLogger(counter):
        warp.config.print_launches = True
        try:
            for _ in range(STEPS):
                state = step(state, action)
                overflowed += int((state.info["overflow"] != 0).sum())
        finally:
            warp.config.print_launches = False
    return counter.launches / STEPS, overflowed


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=["dmc-pendulum-swingup", "dmc-point-mass-easy",
                                                       "dmc-cartpole-swingup", "dmc-acrobot-swingup", "dmc-walker-walk"])
    parser.add_argument("--envs", type=int, default=4)
    parser.add_argument("--json", help="also write the records to this file")
    args = parser.parse_args(argv)
    if jax.default_backend() != "gpu":
        mjx_env.require_warp = lambda: None  # Warp's kernels run on the CPU too
    records = []
    for task in args.tasks:
        count, overflowed = launches_per_step(task, args.envs)
        print(f"{task:28s} {count:8.1f} Warp kernel launches per env step ({overflowed} env-steps overflowed)", flush=True)
        records.append({"kind": "warp-launches", "env": task, "num_envs": args.envs, "launches_per_step": count,
                        "overflow_steps": overflowed, "device": jax.default_backend(),
                        "date": f"{datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC"})
    if args.json:
        with open(args.json, "w") as out:
            json.dump(records, out, indent=1)


if __name__ == "__main__":
    main()
