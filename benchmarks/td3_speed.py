"""Where a TD3 chunk's time goes: env-steps/s of acting alone, updates/s of learning alone, and the
whole chunk, for a task's TD3 recipe (`agents/brax_defaults.py`) with `--seeds` seeds vmapped, or one after
another (`--seed-axis map`, as `mjxsuite train` runs image networks' seeds on a GPU). Compile time is kept
apart; each program is timed after a warm-up, as the median of `--repeats` runs, `jax.block_until_ready` on
the whole output.

    python -m benchmarks.td3_speed --env hopper --seeds 8 [--set batch_size=8192 ...] [--json FILE]
    python -m benchmarks.td3_speed --env dmc-cartpole-swingup --preset pixels --env-opt observation=pixels \
        --env-opt impl=warp --parts act,learn   # dm_control's pixels: 84x84, 3 frames, action repeat 2 by default
    python -m benchmarks.td3_speed ... --parts none   # XLA's count of an update's flops alone, from shapes (no init)
    python -m benchmarks.td3_speed ... --trace DIR    # then one more run of each part under jax.profiler, by kernel
    python -m benchmarks.td3_speed ... --seeds 4 --seed-axis map   # 4 seeds one after another (vmap: batched)
    python -m benchmarks.td3_speed ... --seeds 4 --parts learn,learn_mapped   # vmapped and mapped, one train state
"""

from __future__ import annotations

import argparse
import ast
import json
import time
from functools import partial

import jax
import jax.numpy as jnp

from benchmarks import gpu_profile
from benchmarks.suite import append_record, timed_program


def project_by_hat(probs, reward, discount, support):
    """C51's projection as a dense contraction: each atom i takes sum_j p_j * max(0, 1 - |b_j - i|),
    b_j the shifted atom j's position in atom units (the scatter-free form, for comparison)."""
    v_min, v_max, atoms = support[0], support[-1], support.shape[0]
    shifted = jnp.clip(reward[:, None] + discount[:, None] * support[None, :], v_min, v_max)
    position = (shifted - v_min) / ((v_max - v_min) / (atoms - 1))
    weights = jnp.clip(1.0 - jnp.abs(position[:, :, None] - jnp.arange(atoms, dtype=position.dtype)), 0.0, 1.0)
    return jnp.einsum("bj,bji->bi", probs, weights)


PARTS = ("act", "learn", "learn_hat", "learn_mapped", "chunk")  # the programs `measure` times


def measure(env_name: str, seeds: int, overrides: dict, iterations: int, repeats: int,
            parts=("act", "learn", "learn_hat", "chunk"), env_options: dict | None = None, preset: str = "default",
            trace: str | None = None, seed_axis: str = "vmap") -> dict:
    """Acting alone, learning alone (C51's projection by scatter, `learn`, and as a dense
    contraction, `learn_hat`) and a whole chunk, seeds vmapped or mapped (`seed_axis`, as `agents.run.seed_batched`),
    all from one train state; with `trace`, each part's kernels (`gpu_profile.kernels_of`)."""
    import envs
    from agents import brax_defaults
    from agents import td3 as td3_module
    from agents.run import seed_batched, seeds_init
    from agents.td3 import TD3, TD3Config

    config = TD3Config(**{**brax_defaults.settings(env_name, "td3", preset), **overrides})
    td3 = TD3(config, envs.make(env_name, **(env_options or {})))
    # XLA's count of one seed's update (the actor's step included: both branches of its cond), from shapes alone
    one_seed, key = jax.eval_shape(td3.init, jax.random.PRNGKey(0)), jax.random.PRNGKey(1)
    batch = jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape[1:], x.dtype), jax.eval_shape(td3.sample, one_seed, key)[0])
    cost = jax.jit(td3.learn).lower(one_seed, batch, key, jnp.bool_(True)).cost_analysis()
    cost = cost[0] if isinstance(cost, list) else cost
    gflop = cost["flops"] / 1e9 if cost else None  # XLA:GPU gives no count
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    start = time.perf_counter()
    ts = jax.block_until_ready(jax.jit(seeds_init(td3, seeds))(keys)) if parts else None  # as `train_run`'s
    init_s = time.perf_counter() - start
    steps = jax.random.split(jax.random.PRNGKey(1), (seeds, iterations))

    over_seeds = partial(seed_batched, seeds=seeds, seed_axis=seed_axis)  # fn(state, ...) -> (state, *outputs)

    @jax.jit
    def act(ts):
        return over_seeds(lambda t, k: (jax.lax.scan(td3.collect, t, k)[0],))(ts, steps)

    def learn(ts, axis=seed_axis):
        def body(t, inputs):
            return td3.update(t, *inputs)[0], None
        scanned = lambda t, k: (jax.lax.scan(body, t, (k, jnp.arange(iterations)))[0],)
        return seed_batched(scanned, seeds, axis)(ts, steps)

    def learn_hat(ts):
        projection = td3_module.project
        td3_module.project = project_by_hat  # read when the program is traced
        try:
            return learn(ts)
        finally:
            td3_module.project = projection

    @jax.jit
    def chunk(ts):
        return over_seeds(lambda t: td3.train_steps(t)[:2])(ts)

    programs = {"act": act, "learn": jax.jit(learn), "learn_hat": jax.jit(learn_hat), "chunk": chunk,
                "learn_mapped": jax.jit(partial(learn, axis="map"))}
    timed = {}
    for part in parts:  # each printed as it is done: a run stopped early keeps what it measured
        timed[part] = timed_program(programs[part], ts, repeats=repeats)
        print(f"{part}: compile and first run {timed[part][0]:.1f} s, then {timed[part][1]:.4f} s", flush=True)
    kernels = gpu_profile.kernels_of({part: partial(programs[part], ts) for part in parts}, trace) if trace else {}
    record = {"kind": "td3-speed", "env": env_name, "env_options": env_options or {}, "preset": preset,
              "seeds": seeds, "seed_axis": seed_axis, "overrides": overrides,
              "projection": td3_module.project.__name__, "jax": jax.__version__,
              "device": jax.devices()[0].device_kind, "iterations": iterations, "init_s": init_s,
              "learn_gflop_per_update": gflop,
              "compile_and_first_s": {part: first for part, (first, _) in timed.items()},
              "seconds": {part: seconds for part, (_, seconds) in timed.items()}, **kernels}
    if "act" in timed:
        record["act_env_steps_per_s_per_seed"] = iterations * config.num_envs / timed["act"][1]
    for part in ("learn", "learn_hat", "learn_mapped"):
        if part in timed:
            record[f"{part}_updates_per_s_per_seed"] = iterations * config.num_updates / timed[part][1]
    if "learn" in timed and gflop is not None:
        record["learn_tflop_per_s"] = gflop * seeds * record["learn_updates_per_s_per_seed"] / 1e3
    if "chunk" in timed:
        chunk_s = timed["chunk"][1]
        record.update(chunk_iterations=config.iterations_per_chunk,
                      chunk_env_steps_per_s_per_seed=config.iterations_per_chunk * config.num_envs / chunk_s,
                      chunk_updates_per_s_per_seed=config.iterations_per_chunk * config.num_updates / chunk_s)
    return record


def _parse_set(text: str) -> tuple[str, object]:
    name, _, value = text.partition("=")
    try:
        return name, ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return name, value


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.td3_speed", description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="hopper")
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--iterations", type=int, default=50, help="iterations of acting alone and learning alone")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="FIELD=VALUE",
                        help="a TD3Config field over the task's recipe; repeatable")
    parser.add_argument("--parts", default="act,learn,learn_hat,chunk",
                        help="which programs to time, comma-separated (learn_hat: C51's projection as a "
                             "dense contraction; learn_mapped: seeds mapped whatever --seed-axis; none: only XLA's "
                             "count of an update's flops)")
    parser.add_argument("--env-opt", dest="env_opts", action="append", default=[], metavar="KEY=VALUE",
                        help="an envs.make option (observation=pixels, width=84, ...); repeatable")
    parser.add_argument("--preset", default="default", help="the task's TD3 recipe (e.g. pixels)")
    parser.add_argument("--json", metavar="FILE", help="append the record to FILE (a JSON list)")
    parser.add_argument("--trace", metavar="DIR", help="trace one more run of each part there; kernels in the record")
    parser.add_argument("--seed-axis", choices=("vmap", "map"), default="vmap",
                        help="seeds batched or one after another (`mjxsuite train` maps image networks' on a GPU)")
    args = parser.parse_args(argv)
    parts = tuple(part for part in args.parts.split(",") if part not in ("", "none"))
    if unknown := sorted(set(parts) - set(PARTS)):
        parser.error(f"--parts {args.parts}: no part {', '.join(unknown)}; the parts are {','.join(PARTS)} (or none)")
    record = measure(args.env, args.seeds, dict(_parse_set(s) for s in args.sets), args.iterations, args.repeats,
                     parts, dict(_parse_set(s) for s in args.env_opts), args.preset, args.trace, args.seed_axis)
    print(json.dumps(record, indent=1), flush=True)
    if args.json:
        append_record(args.json, record)


if __name__ == "__main__":
    main()
