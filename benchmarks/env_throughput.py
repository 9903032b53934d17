"""Env throughput: env-steps/s of our CartPoles and of their peers, at several batch sizes.

Every library runs the same loop: `num_envs` auto-resetting envs under uniformly
random actions, `steps` steps as one `lax.scan` inside one `jit`. Compile time is
measured separately (`lower(...).compile()`), every run is synchronised with
`block_until_ready`, and the figure is the median of `repeats` runs after a warm-up.
Our env and its peer are timed side by side at each batch size, their runs
alternating, so their ratio is not skewed by a change in the machine's speed.

Pairs compared: our analytic `cartpole` with gymnax `CartPole-v1`, our
`cartpole-mjx` with MuJoCo Playground `CartpoleBalance` (impl="jax"); see
`benchmarks.peers`. Any other registered env runs alone (`--envs half-cheetah`; a
continuous env under uniform actions in [-1, 1]; `benchmarks.gym_mujoco` sets Gymnasium's
MuJoCo tasks beside Brax and Gymnasium). The batch sizes depend on the device (`batch_sizes`).

    python -m benchmarks.env_throughput [--quick] [--envs cartpole cartpole-mjx] [--peers gymnax playground]
                         [--batch 1 256 4096] [--json FILE]

`mjxsuite bench` runs this together with the DQN and logging figures.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax
import jax.numpy as jnp

import envs
from benchmarks import peers as peer_libs
from benchmarks.peers import random_actions

OURS = ("cartpole", "cartpole-mjx")
PEER_OF = {"cartpole": "gymnax", "cartpole-mjx": "playground"}  # the like-for-like comparison


def platform() -> str:
    return jax.devices()[0].platform  # "cpu" or "gpu"


def device_name() -> str:
    return jax.devices()[0].device_kind


def batch_sizes(env_name: str, quick: bool = False, on: str | None = None) -> list[int]:
    """Batch sizes from 1 up to about the largest that fits and is worth timing on this device.

    CPU: up to 16,384 (throughput is flat from about 4,096). GPU: up to 2**20 for the analytic
    CartPole and 2**18 for MJX (both flat or falling at the top on an H100; an out-of-memory
    size is recorded as skipped and ends the series).
    """
    on = on or platform()
    mjx = is_mjx(env_name)
    if on == "cpu":
        return [1, 4096] if quick else [1, 16, 256, 1024, 4096, 16384]
    largest = 2**18 if mjx else 2**20
    sizes = [1, 256, 4096, 32768, 131072] + ([262144] if mjx else [1048576])
    sizes = [n for n in sizes if n <= largest]
    return [1, 4096, 131072] + ([] if mjx else [1048576]) if quick else sizes


def is_mjx(env_name: str) -> bool:
    """Whether `env_name` (one of ours, a peer library or a peer's env) steps MJX physics."""
    if env_name in ("playground", "CartpoleBalance"):
        return True
    return env_name in envs.names() and isinstance(envs.make(env_name).unwrapped, envs.MjxEnv)


def random_env_actions(key: jax.Array, env: envs.Env, num_envs: int) -> jax.Array:
    """Uniform random actions of a batch: action indices, or continuous actions in [-1, 1]."""
    if env.num_actions:
        return random_actions(key, num_envs, env.num_actions)
    return jax.random.uniform(key, (num_envs, env.action_size), minval=-1.0, maxval=1.0)


def steps_for(num_envs: int, mjx: bool = False, on: str | None = None) -> int:
    """Scan length: enough env steps per run (a fraction of a second or more) that dispatch
    and timer noise do not matter, few enough that a CPU run stays short."""
    on = on or platform()
    if on == "cpu":
        target, low = (2**18, 20) if mjx else (2**21, 50)
    else:
        target, low = (2**27, 100) if mjx else (2**30, 200)
    return max(low, min(10_000, target // num_envs))


def rollout_fn(env_name: str, num_envs: int, steps: int, env_options: dict | None = None):
    """`run(key) -> (total reward, final observations, overflowed env-steps)` of `steps` steps
    of `num_envs` envs (made with `env_options`) with random actions. The last counts the
    env-steps on which MuJoCo Warp ran out of a buffer (`info["overflow"]`, always 0 under
    impl="jax"): such a step is no physics, so a Warp figure counts only beside a zero.

    The work is that of the peers' loops: auto-reset with fresh episodes, no episode
    statistics (gymnax keeps none; `wrap_for_training(..., episode_stats=False)`), and the
    final observations computed from the final physics state after the loop, as gymnax's
    `get_obs`, which keeps XLA from dropping the physics (CartPole's reward is a constant 1,
    so the total alone needs no state). Nothing reads an observation inside the loop, so
    XLA leaves `obs` and `info["final_obs"]` out of it on both sides."""
    base = envs.make(env_name, **(env_options or {}))
    env = envs.wrap_for_training(base, num_envs, episode_stats=False)

    def body(carry, _):
        state, key, total, overflowed = carry
        key, action_key = jax.random.split(key)
        action = random_env_actions(action_key, env, num_envs)
        state = env.step(state, action)
        if "overflow" in state.info:  # MJX tasks only
            overflowed += (state.info["overflow"] > 0).sum()
        return (state, key, total + state.reward.sum(), overflowed), None

    @jax.jit
    def run(key):
        key, reset_key = jax.random.split(key)
        start = (env.reset(reset_key), key, jnp.zeros(()), jnp.zeros((), jnp.int32))
        (state, _, total, overflowed), _ = jax.lax.scan(body, start, None, steps)
        return total, jax.vmap(base.unwrapped.observation)(state.pipeline_state), overflowed

    return run


def _out_of_memory(err: Exception) -> bool:
    return "RESOURCE_EXHAUSTED" in str(err) or "out of memory" in str(err).lower()


def _record(lib: str, env_name: str, num_envs: int, steps: int, repeats: int) -> dict:
    return {"kind": "env-throughput", "lib": lib, "env": env_name, "num_envs": num_envs, "steps": steps,
            "repeats": repeats, "device": device_name(), "steps_per_s": None, "compile_s": None}


def overflow_steps(output) -> int | None:
    """The overflowed env-steps a run of `rollout_fn` returned (None for a peer's run, which has no count)."""
    return int(output[2]) if len(output) > 2 else None


def overflow_note(record: dict) -> str:
    """What a row says when MuJoCo Warp ran out of a buffer in it: its figure is not physics."""
    found = record.get("overflow_steps")
    return f"  (NOT PHYSICS: {found:,} env-steps overflowed Warp's buffers)" if found else ""


def _compile(lib: str, env_name: str, num_envs: int, steps: int):
    """(compiled run, compile seconds, overflowed env-steps of its warm-up run or None), or
    (None, None, why it cannot run)."""
    try:
        run = rollout_fn(env_name, num_envs, steps) if lib == "mjxsuite" else peer_libs.ROLLOUTS[lib](num_envs, steps)
        key = jax.random.PRNGKey(0)
        start = time.perf_counter()
        compiled = run.lower(key).compile()
        compile_s = time.perf_counter() - start
        warm_up = jax.block_until_ready(compiled(key))  # also first-touch allocations
        return compiled, compile_s, overflow_steps(warm_up)
    except peer_libs.PeerMissing as missing:
        return None, None, str(missing)
    except Exception as err:  # out of memory at a large batch: record it, the caller stops growing
        if not _out_of_memory(err):
            raise
        return None, None, f"out of memory at {num_envs} envs: {str(err).splitlines()[0]}"


def time_side_by_side(compiled: list, repeats: int) -> list[list[float]]:
    """Seconds of `repeats` runs of each compiled rollout, their runs alternating (A B A B ...)
    so that a change in the machine's speed (other load, clocks) hits every library alike."""
    times = [[] for _ in compiled]
    for i in range(repeats):
        key = jax.random.PRNGKey(i + 1)
        for run, spent in zip(compiled, times):
            start = time.perf_counter()
            jax.block_until_ready(run(key))
            spent.append(time.perf_counter() - start)
    return times


def measure(jobs: list[tuple[str, str]], num_envs: int, steps: int | None = None, repeats: int = 5) -> list[dict]:
    """Throughput records of several (lib, env) at one batch size, timed side by side; one that
    cannot run (peer missing, out of memory) is recorded as skipped, with the reason."""
    records, compiled = [], []
    for lib, env_name in jobs:
        n_steps = steps or steps_for(num_envs, mjx=is_mjx(env_name))
        run, compile_s, found = _compile(lib, env_name, num_envs, n_steps)
        record = _record(lib, env_name, num_envs, n_steps, repeats)
        if run is None:
            records.append({**record, "skipped": found})
        else:
            # Counted in the warm-up run (the timed runs return nothing read): None for a peer.
            records.append({**record, "compile_s": compile_s, "overflow_steps": found})
            compiled.append((run, records[-1]))
    try:
        times = time_side_by_side([run for run, _ in compiled], repeats)
    except Exception as err:
        if not _out_of_memory(err):
            raise
        for _, record in compiled:
            record["skipped"] = f"out of memory at {num_envs} envs: {str(err).splitlines()[0]}"
        return records
    for (_, record), spent in zip(compiled, times):
        record["steps_per_s"] = num_envs * record["steps"] / statistics.median(spent)
        record["run_s"] = spent
    return records


def throughput_records(ours=OURS, peers=("gymnax", "playground"), batch=None, quick=False, repeats=None,
                       print_rows=True) -> list[dict]:
    """Each of our envs beside its peer (`PEER_OF`) at each batch size, timed side by side; a
    peer listed without its counterpart runs alone. A lib skipped once (missing, out of memory)
    is not tried at larger sizes."""
    repeats = repeats or (3 if quick else 5)
    groups = [[("mjxsuite", name)] + ([(PEER_OF[name], peer_libs.PEER_ENVS[PEER_OF[name]])]
                                      if PEER_OF.get(name) in peers else []) for name in ours]
    paired = {PEER_OF.get(name) for name in ours}
    groups += [[(peer, peer_libs.PEER_ENVS[peer])] for peer in peers if peer not in paired]
    records = []
    if print_rows:
        print(f"{'lib':<11}{'env':<17}{'num_envs':>9}{'env-steps/s':>15}{'compile s':>11}")
    for group in groups:
        lib, env_name = group[0]
        sizes = batch or batch_sizes(env_name if lib == "mjxsuite" else lib, quick)
        for num_envs in sizes:
            skipped = {(r["lib"], r["env"]) for r in records if r.get("skipped")}
            group = [job for job in group if job not in skipped]
            if not group:
                break  # missing, or out of memory: larger sizes will not do better
            for r in measure(group, num_envs, repeats=repeats):
                records.append(r)
                if print_rows:
                    if r["steps_per_s"] is None:
                        print(f"{r['lib']:<11}{r['env']:<17}{num_envs:>9}   skipped: {r['skipped']}", flush=True)
                    else:
                        print(f"{r['lib']:<11}{r['env']:<17}{num_envs:>9}{r['steps_per_s']:>15,.0f}"
                              f"{r['compile_s']:>11.2f}{overflow_note(r)}", flush=True)
    return records


def ratio_records(records: list[dict]) -> list[dict]:
    """Ours / peer env-steps/s at each batch size both ran (> 1: ours is faster)."""
    speed = {(r["lib"], r["num_envs"]): r["steps_per_s"] for r in records
             if r.get("kind") == "env-throughput" and r["steps_per_s"]}
    speed_ours = {(r["env"], r["num_envs"]): r["steps_per_s"] for r in records
                  if r.get("kind") == "env-throughput" and r["lib"] == "mjxsuite" and r["steps_per_s"]}
    rows = []
    for (env_name, num_envs), ours in sorted(speed_ours.items()):
        peer = PEER_OF.get(env_name)
        theirs = speed.get((peer, num_envs))
        if theirs:
            rows.append({"kind": "env-ratio", "env": env_name, "peer": peer, "peer_env": peer_libs.PEER_ENVS[peer],
                         "num_envs": num_envs, "ratio": ours / theirs, "device": device_name()})
    return rows


def step_hlo_counts(env_name: str, num_envs: int) -> dict:
    """Op counts of one compiled batched step (`wrap_for_training(env).step`, optimised HLO,
    fused computations included): `fusion` kernels, `copy`s, `while` loops (threefry runs as a
    rolled loop on the CPU), `conditional`s, `custom-call`s (LAPACK in MJX's dense mass-matrix
    solve), for spotting work that should not be there."""
    import collections
    import re

    env = envs.wrap_for_training(envs.make(env_name), num_envs)
    state = env.reset(jax.random.PRNGKey(0))
    action = jnp.zeros((num_envs,), jnp.int32)
    text = jax.jit(env.step).lower(state, action).compile().as_text()
    ops = collections.Counter(re.findall(r"=\s*(?:\([^=]*?\)|\S+)\s+([a-z][a-z0-9\-]*)\(", text))
    ignore = ("parameter", "constant", "get-tuple-element", "tuple", "bitcast")
    return {"kind": "env-hlo", "lib": "mjxsuite", "env": env_name, "num_envs": num_envs, "device": device_name(),
            "total_ops": sum(n for op, n in ops.items() if op not in ignore),
            "ops": {op: n for op, n in ops.most_common() if op not in ignore}}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer batch sizes and repeats")
    parser.add_argument("--envs", nargs="+", default=list(OURS), choices=envs.names())
    parser.add_argument("--peers", nargs="*", default=["gymnax", "playground"], choices=list(peer_libs.ROLLOUTS))
    parser.add_argument("--batch", nargs="+", type=int, help="batch sizes (default: by device)")
    parser.add_argument("--repeats", type=int)
    parser.add_argument("--json", help="also write the records to this file")
    parser.add_argument("--hlo", type=int, metavar="N", help="print op counts of the compiled step at N envs instead")
    args = parser.parse_args(argv)
    if args.hlo:
        for name in args.envs:
            r = step_hlo_counts(name, args.hlo)
            print(f"{name} at {args.hlo} envs: {r['total_ops']} ops: {r['ops']}")
        return
    records = throughput_records(args.envs, args.peers, args.batch, args.quick, args.repeats)
    ratios = ratio_records(records)
    for r in ratios:
        print(f"{r['env']} / {r['peer']} {r['peer_env']} at {r['num_envs']} envs: {r['ratio']:.2f}x")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records + ratios, f, indent=2)


if __name__ == "__main__":
    main()
