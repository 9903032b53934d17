"""Our PPO and SAC against Brax's own trainers at the same recipe: env-steps/s of one seed
(ours through `agents.run.train_run`, Brax's `ppo.train`/`sac.train` on `envs.to_brax`), and
ours with several seeds in one program (their total env-steps/s over one seed's).

Each side trains `--steps` env steps per seed in two chunks (Brax: two epochs after its first
evaluation); the figure is the last chunk's (epoch's) env-steps/s of training alone: compile,
the first chunk and the evaluations left out (ours: `steps_per_s` of metrics.jsonl; Brax's:
`training/sps`). Each side's whole wall time is recorded too. Ours and Brax's alternate in one
process, on one device.

    python -m benchmarks.brax_agents --env hopper --agent ppo --impl warp --steps 4000000 --seeds 1,8 \\
        [--repeats 1] [--json FILE] [--profile DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from benchmarks import gpu_profile


def recipe(env_name: str, agent: str, steps: int):
    """The task's default recipe (agents/brax_defaults.py), `steps` env steps per seed in two chunks."""
    from agents import brax_defaults, registry

    config = registry.config_class(agent)(**brax_defaults.settings(env_name, agent))
    return dataclasses.replace(config, num_timesteps=steps, num_evals=3)


def ours(env_name: str, config, seeds: int, env_options: dict) -> dict:
    from agents import train_run

    start = time.perf_counter()
    result = train_run(env_name, config, seeds=seeds, env_options=env_options, progress=False)
    return {"side": "ours", "seeds": seeds, "steps_per_s": result.history[-1]["steps_per_s"],
            "per_seed_steps_per_s": result.history[-1]["steps_per_s"] / seeds, "compile_s": result.compile_s,
            "wall_s": time.perf_counter() - start, "mean_return": result.mean_return}


def brax(env_name: str, config, env_options: dict) -> dict:
    import envs
    from benchmarks import brax_trainers

    env = envs.to_brax(envs.make(env_name, **env_options))
    seen = []
    start = time.perf_counter()
    kwargs = brax_trainers.trainer_kwargs(config)
    brax_trainers.trainer(config)(env, episode_length=env.episode_length, seed=0,
                                  progress_fn=lambda step, metrics: seen.append((time.perf_counter(), step, metrics)),
                                  **kwargs)
    sps = [float(m["training/sps"]) for _, _, m in seen if "training/sps" in m]
    return {"side": "brax", "seeds": 1, "steps_per_s": sps[-1] if sps else None,
            "per_seed_steps_per_s": sps[-1] if sps else None, "wall_s": time.perf_counter() - start,
            "mean_return": [float(seen[-1][2]["eval/episode_reward"])]}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.brax_agents", description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="hopper")
    parser.add_argument("--agent", choices=("ppo", "sac"), default="ppo")
    parser.add_argument("--impl", choices=("jax", "warp"), default="jax")
    parser.add_argument("--steps", type=int, default=4_000_000, help="env steps per seed")
    parser.add_argument("--seeds", default="1,8", help="comma-separated seed counts of our runs")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--json", metavar="FILE")
    parser.add_argument("--profile", metavar="DIR", help="trace each run with jax.profiler under DIR and add "
                        "its kernel summary to the record (benchmarks.gpu_profile)")
    args = parser.parse_args(argv)
    import jax

    options = {"impl": args.impl}
    config = recipe(args.env, args.agent, args.steps)
    records = []
    for repeat in range(args.repeats):
        for run in [("brax", 1)] + [("ours", int(s)) for s in args.seeds.split(",")]:
            trace_dir = Path(args.profile or ".") / f"{run[0]}-{run[1]}-{repeat}"
            with gpu_profile.traced(trace_dir) if args.profile else contextlib.nullcontext():
                record = brax(args.env, config, options) if run[0] == "brax" else ours(args.env, config, run[1], options)
            if args.profile:
                record["profile"] = gpu_profile.summary(trace_dir)
            record.update(kind="brax-agents", env=args.env, agent=args.agent, impl=args.impl, repeat=repeat,
                          steps_per_seed=args.steps, device=jax.devices()[0].device_kind)
            records.append(record)
            print(json.dumps(record), flush=True)
    one = np.median([r["steps_per_s"] for r in records if r["side"] == "ours" and r["seeds"] == 1])
    theirs = np.median([r["steps_per_s"] for r in records if r["side"] == "brax"])
    summary = {"kind": "brax-agents-ratio", "env": args.env, "agent": args.agent, "impl": args.impl,
               "one_seed_over_brax": float(one / theirs),
               **{f"{s}_seeds_over_one": float(np.median([r["steps_per_s"] for r in records
                                                          if r["side"] == "ours" and r["seeds"] == int(s)]) / one)
                  for s in args.seeds.split(",") if int(s) > 1}}
    records.append(summary)
    print(json.dumps(summary))
    if args.json:
        Path(args.json).write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
