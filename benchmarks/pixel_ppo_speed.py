"""Where a pixel PPO training step's time goes, and what batching seeds costs it: PPO's unrolls
alone (`collect`: render, physics and the policy's CNN) and its whole training step (the unrolls,
then `num_updates_per_batch` passes of minibatch SGD through both CNNs), for a task's "pixels"
recipe (`agents/brax_defaults.py`) and its camera defaults, with seeds vmapped or one after another
(`lax.map`, as `mjxsuite train --seeds N` runs image networks' seeds since this benchmark measured it:
`agents.device_options.default_seed_axis`).

Vmapping a CNN over the seeds' parameters turns each convolution, and each of its gradients, into a
grouped one (`feature_group_count` = seeds); each record counts them in the training step's HLO
beside its time. Compile time is kept apart; each program is timed
after its first run, as the median of `--repeats` runs.

    python -m benchmarks.pixel_ppo_speed --env dmc-cartpole-swingup --impl warp --seeds 1 4 --json FILE

On the CPU it is a smoke test of some minutes (the ray-cast camera compiles slowly): `--impl jax
--seeds 1 --env-opt width=16 --env-opt height=16 --set num_envs=4 --set batch_size=4 --set
num_minibatches=2 --set unroll_length=2 --set cnn_kernel_size=(3,3,3) --set cnn_stride=(2,1,1)
--repeats 1`.
"""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import jax
import jax.numpy as jnp

from agents.checkpoint import atomic_write
from benchmarks.suite import timed_program
from benchmarks.td3_speed import _parse_set


def grouped_convolutions(hlo: str) -> dict[str, int]:
    """How many convolutions of the StableHLO text are grouped over features or over the batch."""
    counts = {}
    for kind in ("feature_group_count", "batch_group_count"):
        counts[kind] = sum(int(n) > 1 for n in re.findall(kind + r" = (\d+)", hlo))
    return counts


def measure(env_name: str, impl: str, seeds: int, seed_axis: str, env_options: dict, overrides: dict,
            repeats: int, save=lambda record: None) -> dict:
    """One record: the unrolls' and the whole training step's seconds and env-steps/s over all seeds;
    `save` gets it after each part, so a run stopped early keeps what it measured."""
    import envs
    from agents import brax_defaults
    from agents.ppo import PPO, PPOConfig
    from agents.run import seed_batched

    config = PPOConfig(**{**brax_defaults.settings(env_name, "ppo", "pixels"), **overrides})
    ppo = PPO(config, envs.make(env_name, observation="pixels", impl=impl, **env_options))
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    ts = jax.block_until_ready(jax.jit(jax.vmap(ppo.init))(keys))  # as train_run: init vmapped

    def unrolls(t):
        env_state, data = ppo.collect(t, t.key)
        return env_state, jnp.sum(data.reward)  # the frames stay inside the program

    programs = {"collect": jax.jit(seed_batched(unrolls, seeds, seed_axis)),
                "training_step": jax.jit(seed_batched(ppo.training_step, seeds, seed_axis))}
    record = {"kind": "pixel-ppo-speed", "env": env_name, "impl": impl, "seeds": seeds, "seed_axis": seed_axis,
              "env_options": env_options, "overrides": overrides, "jax": jax.__version__,
              "device": jax.devices()[0].device_kind, "env_steps_per_training_step": config.env_steps_per_training_step,
              **grouped_convolutions(programs["training_step"].lower(ts).as_text())}
    save(record)
    for part, program in programs.items():
        first, seconds = timed_program(program, ts, repeats=repeats)
        record.update({f"{part}_compile_and_first_s": first, f"{part}_s": seconds,
                       f"{part}_env_steps_per_s": seeds * config.env_steps_per_training_step / seconds})
        save(record)
        print(json.dumps({k: record[k] for k in ("env", "seeds", "seed_axis", f"{part}_s", f"{part}_env_steps_per_s")}),
              flush=True)
    return record


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.pixel_ppo_speed", description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="dmc-cartpole-swingup")
    parser.add_argument("--impl", default="jax", choices=["jax", "warp"])
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 4])
    parser.add_argument("--seed-axes", nargs="+", default=["vmap", "map"], choices=["vmap", "map"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--env-opt", dest="env_opts", action="append", default=[], metavar="KEY=VALUE",
                        help="an envs.make option over the task's pixel defaults; repeatable")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="FIELD=VALUE",
                        help="a PPOConfig field over the task's pixels recipe; repeatable")
    parser.add_argument("--json", metavar="FILE", help="write the records here (a JSON list)")
    args = parser.parse_args(argv)
    env_options, overrides = dict(map(_parse_set, args.env_opts)), dict(map(_parse_set, args.sets))
    records = []

    def save(record):
        if args.json:
            atomic_write(Path(args.json), json.dumps(records + [record], indent=1).encode())

    for seeds in args.seeds:
        for seed_axis in args.seed_axes if seeds > 1 else ["vmap"]:  # one seed runs unbatched either way
            records.append(measure(args.env, args.impl, seeds, seed_axis, env_options, overrides, args.repeats, save))


if __name__ == "__main__":
    main()
