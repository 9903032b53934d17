"""Our pictures against dm_control's, where a pixel policy meets the judge.

    MUJOCO_GL=egl python -m benchmarks.pixel_gap --run DIR [--episodes 2] [--seeds 0,1] [--max-steps N]
        [--ours-only] [--json FILE]

A pixel run on a dm_control task learns from our renderer's pictures (MuJoCo Warp's under impl="warp") and is
judged on dm_control's own env from dm_control's pictures (OpenGL: its textures, lights and shadows). For each
seed, this drives dm_control's env with the seed's policy as the judge does (`envs.returns_on_dm_control`, the
judge's episode seeds), twice: the policy seeing dm_control's pictures, then seeing ours of the same physics
state. Every step renders both. Per seed it reports the two returns, the mean absolute difference of the two
pictures (0-255) and of the policy's actions on the two frame stacks. dm_control's physics runs under both, so
a return that holds on our pictures and falls on dm_control's says the pictures moved it, not the physics.
Ours come from the run's renderer where this machine has it (impl="warp": a CUDA GPU), else from the JAX ray
caster, whose flat colours are far from both. Tasks whose episodes draw markers (reacher's target) are
rendered without them here. `--ours-only`, for a machine without headless OpenGL: the return seeing ours alone.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path
from typing import Callable

import numpy as np

from benchmarks.suite import append_record


def our_pictures(env) -> Callable[[object], np.ndarray]:
    """`picture(physics)`: `env`'s uint8 picture (H, W, 3) of dm_control's physics state (its qpos and qvel)."""
    import jax
    import jax.numpy as jnp

    from envs.pixels import Pixels

    pixels = env
    while not isinstance(pixels, Pixels):
        pixels = pixels.env
    task = pixels.unwrapped
    template = jax.vmap(pixels.reset)(jax.random.PRNGKey(0)[None])  # a batch of one: MuJoCo Warp's worlds

    @jax.jit
    def picture(qpos, qvel):
        def one(state, qpos, qvel):
            data = task.compute_derived(state.pipeline_state.replace(qpos=qpos, qvel=qvel))
            return pixels.frame(state.replace(pipeline_state=data))[..., :3]
        return jax.vmap(one)(template, qpos[None], qvel[None])[0]

    dtype = template.pipeline_state.qpos.dtype
    return lambda physics: np.asarray(picture(*(jnp.asarray(x, dtype) for x in (physics.data.qpos, physics.data.qvel))))


def twin_camera(env, ours: Callable, feed: str, renders: bool = True):
    """The judge's camera of `env` (`envs.DmControlCamera`: frames stacked, actions repeated as the judge does), each
    picture both dm_control's (where `renders`) and `ours`, the policy seeing `feed`'s ("theirs" or "ours"); both
    are kept per episode in `episodes`."""
    from envs import DmControlCamera

    @dataclasses.dataclass
    class TwinCamera(DmControlCamera):
        episodes: list = dataclasses.field(default_factory=list)

        def reset(self, physics):
            self.episodes.append([])
            return super().reset(physics)

        def picture(self, physics):
            pair = (super().picture(physics) if renders else None, ours(physics))
            self.episodes[-1].append(pair)
            return pair[feed == "ours"]

    camera = TwinCamera(**dataclasses.asdict(DmControlCamera.of(env)))
    camera.renders = renders
    return camera


def stacks(pictures: list[np.ndarray], frame_stack: int) -> np.ndarray:
    """The frame stack after each picture of an episode, oldest first, the first picture repeated."""
    padded = [pictures[0]] * (frame_stack - 1) + pictures
    return np.stack([np.concatenate(padded[i:i + frame_stack], -1) for i in range(len(pictures))])


def gap(policy, env, ours: Callable, episodes: int, max_steps: int | None = None, ours_only: bool = False) -> dict:
    """One policy's returns on dm_control's env seeing its pictures and `ours` (`our_pictures(env)`), and the two
    pictures' and actions' mean absolute differences over every step of both drives; `ours_only`: the return
    seeing ours alone, dm_control rendering nothing (a machine without headless OpenGL)."""
    from envs import returns_on_dm_control

    record, pairs, picture_gap, actions = {}, 0, [], []
    feeds = ("ours",) if ours_only else ("theirs", "ours")
    for feed in feeds:
        camera = twin_camera(env, ours, feed, renders=not ours_only)
        record[f"returns_seeing_{feed}"] = returns_on_dm_control(policy, env, episodes, max_steps=max_steps,
                                                                 camera=camera)
        record[f"return_seeing_{feed}"] = float(np.mean(record[f"returns_seeing_{feed}"]))
        if ours_only:
            continue
        for episode in camera.episodes:
            theirs, mine = (stacks([pair[i] for pair in episode], camera.frame_stack) for i in (0, 1))
            picture_gap.append(np.abs(theirs[..., -3:].astype(np.int16) - mine[..., -3:]).mean(axis=(1, 2, 3)))
            actions.append(np.abs(np.asarray(policy(theirs)) - np.asarray(policy(mine))).mean(-1))
            pairs += len(episode)
    if not ours_only:
        record.update(pictures=pairs, picture_abs_diff=float(np.concatenate(picture_gap).mean()),
                      action_abs_diff=float(np.concatenate(actions).mean()))
    return record


def main(argv=None) -> None:
    from agents.cli import ranged
    from envs.ranges import COUNT

    count = ranged(int, COUNT)
    parser = argparse.ArgumentParser(prog="python -m benchmarks.pixel_gap", description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, type=Path, help="a run directory of a pixel dm_control task")
    parser.add_argument("--episodes", type=count, default=2, help="episodes per seed and renderer (default 2)")
    parser.add_argument("--seeds", default=None, help="comma-separated seed indices (default: every seed)")
    parser.add_argument("--max-steps", type=count, default=None, help="control steps per episode (default: its end)")
    parser.add_argument("--ours-only", action="store_true",
                        help="only the return seeing our pictures; dm_control renders nothing (no headless OpenGL)")
    parser.add_argument("--json", metavar="FILE", help="append the record to FILE (a JSON list)")
    args = parser.parse_args(argv)
    if args.ours_only:
        os.environ.setdefault("MUJOCO_GL", "disable")  # dm_control then never looks for OpenGL

    import agents
    from agents import checkpoint

    try:
        saved = checkpoint.load_config(args.run)
    except FileNotFoundError as error:
        parser.error(f"--run: {error}")
    if saved.env_options.get("observation") != "pixels" or not saved.env.startswith("dmc-"):
        parser.error(f"--run {args.run}: a run of {saved.env} with {saved.env_options}; pixel_gap compares "
                     "pictures of a dm_control task trained with --env-opt observation=pixels")
    env = checkpoint.saved_env(args.run)[1]
    seeds = range(saved.trained_seeds) if args.seeds is None else [int(s) for s in args.seeds.split(",")]
    ours = our_pictures(env)  # compiled once, for every seed
    record = {"kind": "pixel-gap", "run": str(args.run), "env": saved.env, "env_options": saved.env_options,
              "renderer": "warp" if env.unwrapped.impl == "warp" else "jax ray caster", "episodes": args.episodes,
              "max_steps": args.max_steps, "ours_only": args.ours_only, "seeds": {}}
    for seed in seeds:
        policy = agents.load_policy(args.run, seed)
        record["seeds"][seed] = gap(policy, env, ours, args.episodes, args.max_steps, args.ours_only)
        print(seed, json.dumps(record["seeds"][seed]), flush=True)
    if args.json:
        append_record(args.json, record)


if __name__ == "__main__":
    main()
