"""Where a policy of a dm_control task succeeds, by how its episode starts: each seed of a run judged on
dm_control's own env as `mjxsuite eval` judges it, its episodes split by one joint of the reset state.

    python -m benchmarks.reset_split --run DIR [--joint rooty] [--episodes 24] [--first-seed 2000]
        [--success 500] [--json FILE]

For hopper stand the joint is `rooty`, the free rotation that dm_control's reset draws uniformly, so its sign says
which side the hopper starts to fall to. Each seed's episodes below 0 and at or above it are counted, and those of
each that return over `--success` (hopper stand: about 930 where it gets up, under 20 where it does not). A seed
that gets up from one side only succeeds in about half of its episodes, whatever its training took.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from benchmarks.suite import append_record


def split_returns(run: str, joint: str, episodes: int, first_seed: int):
    """Yields (seed index, [(the joint at reset, the episode's return)] over `episodes` dm_control episodes, seeds
    `first_seed` on): each episode is the judge's (`envs.returns_on_dm_control`), its reset read from dm_control's
    env loaded with the same seed."""
    import agents
    import envs
    from agents import checkpoint
    from envs.pixels import PIXEL_OPTIONS

    saved = checkpoint.load_config(run)  # a pixel run's env, so the judge shows dm_control's pictures as it does
    env = envs.make(saved.env, **{k: v for k, v in saved.env_options.items() if k in PIXEL_OPTIONS})
    task = env.unwrapped
    if not hasattr(task, "domain"):
        raise SystemExit(f"reset_split: {run} trained {saved.env!r}, not a dm_control task")
    starts = [joint_at_reset(envs.load_dm_control(task.domain, task.task, first_seed + episode), joint)
              for episode in range(episodes)]
    for seed in range(saved.seeds):
        policy = agents.load_policy(run, seed_index=seed)
        returns = [envs.returns_on_dm_control(policy, env, 1, first_seed + episode)[0] for episode in range(episodes)]
        yield seed, list(zip(starts, returns))


def joint_at_reset(theirs, joint: str) -> float:
    """The coordinate of hinge or slide `joint` in the state `theirs.reset()` draws."""
    theirs.reset()
    model, qpos = theirs.physics.model, theirs.physics.named.data.qpos
    scalar = [name for name in (model.id2name(i, "joint") for i in range(model.njnt)) if np.size(qpos[name]) == 1]
    if joint not in scalar:
        raise SystemExit(f"reset_split: --joint {joint!r}: give a hinge or slide joint of the model, one of "
                         f"{', '.join(scalar)}")
    return float(np.ravel(qpos[joint])[0])


def tally(episodes: list[tuple[float, float]], success: float) -> dict:
    """The episodes starting below 0 and at or above it: how many, and how many returned over `success`."""
    below = [total for start, total in episodes if start < 0]
    above = [total for start, total in episodes if start >= 0]
    return {"below_0": len(below), "succeeded_below_0": sum(t > success for t in below),
            "at_or_above_0": len(above), "succeeded_at_or_above_0": sum(t > success for t in above)}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.reset_split", description=__doc__.splitlines()[0])
    parser.add_argument("--run", required=True, help="a run directory of a dm_control task (from pixels: "
                        "set MUJOCO_GL=egl, as the judge needs)")
    parser.add_argument("--joint", default="rooty", help="the joint of the reset state to split by (hopper: rooty)")
    parser.add_argument("--episodes", type=int, default=24)
    parser.add_argument("--first-seed", type=int, default=2000, help="dm_control's seed of the first episode "
                        "(the judge's are 1,000 on: these are other episodes)")
    parser.add_argument("--success", type=float, default=500.0, help="a return over this counts as a success")
    parser.add_argument("--json", metavar="FILE", help="append the record to FILE (a JSON list)")
    args = parser.parse_args(argv)
    if args.episodes < 1:
        parser.error(f"--episodes {args.episodes}: give at least 1")
    record = {"kind": "reset-split", "run": args.run, "joint": args.joint, "episodes": args.episodes,
              "first_seed": args.first_seed, "success": args.success, "seeds": []}
    for seed, episodes in split_returns(args.run, args.joint, args.episodes, args.first_seed):
        counts = tally(episodes, args.success)
        record["seeds"].append({"seed": seed, **counts, "episodes": [[round(s, 4), round(t, 1)] for s, t in episodes]})
        print(json.dumps({"seed": seed, **counts}), flush=True)
    if args.json:
        append_record(args.json, record)


if __name__ == "__main__":
    main()
