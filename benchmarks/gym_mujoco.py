"""Env-steps/s of Gymnasium's MuJoCo tasks, ours beside the alternatives, in one run on one device:

- ours (`envs.make(name, impl=...)`, "jax" and, where MuJoCo Warp imports and a CUDA GPU is
  there, "warp"), stepped as `env_throughput` steps every env: `wrap_for_training` (auto-reset,
  no episode statistics), uniform random actions in [-1, 1], one `lax.scan` in one `jit`;
- Brax's look-alikes of the same task (`brax.envs.get_environment(..., backend="mjx")` in Brax's
  own training wrappers, stepped by the same loop) twice: at Brax's solver options (4 solver
  iterations, Euler) and at the Gymnasium task's (the MJCF's `solver`, `iterations`,
  `ls_iterations`, `tolerance`, `integrator` put into Brax's model), each record naming them;
- Gymnasium's own vector env of the task (C MuJoCo, float64): `gymnasium.make_vec(id,
  num_envs=os.cpu_count(), vectorization_mode="async")`, one process per core (spawned), random
  actions.

Compile time is kept apart; runs of ours and Brax's at one batch size alternate (A B A B ...) and
the figure is the median after a warm-up. Each of our records counts the env-steps of its warm-up
run on which MuJoCo Warp ran out of a buffer (`overflow_steps`, always 0 under impl="jax"): a
Warp figure with overflows is no physics figure, and its rows say so. Records are JSON (`--json FILE`), kind "gym-mujoco",
plus "gym-mujoco-ratio" records: each of ours against Gymnasium's vector env and against Brax at
equal solver options. On a CPU it is a smoke test (`--sizes 4 --steps 5 --gymnasium-steps 20`).

    python -m benchmarks.gym_mujoco [--tasks half-cheetah hopper ...] [--sizes [4096 32768 ...]]
        [--impls jax warp] [--no-brax] [--no-gymnasium] [--steps N] [--gymnasium-steps N]
        [--repeats R] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import envs
from benchmarks import env_throughput
from benchmarks.peers import PeerMissing, version

# Brax's environments that copy a Gymnasium task (with their own models and solver options).
BRAX_NAMES = {"half-cheetah": "halfcheetah", "hopper": "hopper", "walker2d": "walker2d", "ant": "ant",
              "humanoid": "humanoid"}
# The MJCF options that set how much work a physics step does, recorded with every figure.
SOLVER_FIELDS = ("solver", "iterations", "ls_iterations", "tolerance", "integrator")
EPISODE_LENGTH = 1000  # every task here: Gymnasium's max_episode_steps, and Brax's default


def gymnasium_tasks() -> list[str]:
    """The registered names of Gymnasium's MuJoCo tasks (a task that names its `gymnasium_id`)."""
    return [name for name in envs.names() if getattr(envs.make(name).unwrapped, "gymnasium_id", None)]


def solver_options(opt) -> dict:
    """The solver options of an `mjx.Model.opt` or `mujoco.MjModel.opt`, as plain numbers."""
    # The tolerance to 6 digits: Brax keeps it as a float32 (1e-8 reads back as 9.99999994e-09).
    return {field: float(f"{float(getattr(opt, field)):.6g}") if field == "tolerance" else int(getattr(opt, field))
            for field in SOLVER_FIELDS}


def warp_available() -> bool:
    try:
        envs.mjx_env.require_warp()
        return True
    except (RuntimeError, ImportError):
        return False


def steps_for(num_envs: int) -> int:
    """About 1M env steps per timed run (256 steps at 4,096 envs, 32 at 32,768), at least 20: a
    contact task with Gymnasium's 100 solver iterations runs a few 1e5 env-steps/s on one GPU."""
    return max(20, 2**20 // num_envs)


# ---- the rollouts: each `run(key)` -> (total reward, final observations), jitted -------------
def our_rollout(name: str, impl: str, num_envs: int, steps: int):
    run = env_throughput.rollout_fn(name, num_envs, steps, {"impl": impl})
    return run, solver_options(envs.make(name).unwrapped.mj_model.opt)


def brax_rollout(brax_name: str, num_envs: int, steps: int, solver: dict | None = None):
    """Brax's env `brax_name` (backend "mjx") with `solver` put into its model's options (None:
    Brax's own), in Brax's training wrappers (vmap, episode limit, auto-reset)."""
    try:
        from brax import envs as brax_envs
    except ImportError as err:
        raise PeerMissing(f"brax is not installed ({err}); pip install brax==0.14.2") from err
    env = brax_envs.get_environment(brax_name, backend="mjx")
    if solver:  # each value in the type Brax's model keeps it in (an enum, an int, a JAX scalar)
        opt = env.sys.opt
        like = lambda old, new: jnp.asarray(new, old.dtype) if isinstance(old, jax.Array) else type(old)(new)
        env.sys = env.sys.replace(opt=opt.replace(**{k: like(getattr(opt, k), v) for k, v in solver.items()}))
    used = solver_options(env.sys.opt)
    wrapped = brax_envs.training.wrap(env, episode_length=EPISODE_LENGTH)

    def body(carry, _):
        state, key, total = carry
        key, action_key = jax.random.split(key)
        action = jax.random.uniform(action_key, (num_envs, env.action_size), minval=-1.0, maxval=1.0)
        state = wrapped.step(state, action)
        return (state, key, total + state.reward.sum()), None

    @jax.jit
    def run(key):
        key, reset_key = jax.random.split(key)
        state = wrapped.reset(jax.random.split(reset_key, num_envs))
        (state, _, total), _ = jax.lax.scan(body, (state, key, jnp.zeros(())), None, steps)
        return total, state.obs

    return run, used


def gymnasium_vector_speed(gymnasium_id: str, steps: int, repeats: int, num_envs: int | None = None) -> dict:
    """Env-steps/s of Gymnasium's async vector env over all cores (median of `repeats` runs of
    `steps` vector steps, actions drawn beforehand, after a warm-up of 10 steps)."""
    import gymnasium

    num_envs = num_envs or os.cpu_count()
    # "spawn": forking a process that runs JAX's threads can deadlock (Python warns of it).
    vector = gymnasium.make_vec(gymnasium_id, num_envs=num_envs, vectorization_mode="async",
                                vector_kwargs={"context": "spawn"})
    try:
        vector.reset(seed=0)
        vector.action_space.seed(0)
        actions = [vector.action_space.sample() for _ in range(steps)]
        for action in actions[:10]:
            vector.step(action)
        spent = []
        for _ in range(repeats):
            start = time.perf_counter()
            for action in actions:
                vector.step(action)
            spent.append(time.perf_counter() - start)
    finally:
        vector.close()
    solver = solver_options(gymnasium.make(gymnasium_id).unwrapped.model.opt)  # what each worker loads
    return {"num_envs": num_envs, "steps": steps, "steps_per_s": num_envs * steps / statistics.median(spent),
            "run_s": spent, "solver": solver}


# ---- measuring --------------------------------------------------------------------------------
def _record(lib: str, name: str, num_envs: int, steps: int, repeats: int, **extra) -> dict:
    return {"kind": "gym-mujoco", "lib": lib, "env": name, "num_envs": num_envs, "steps": steps,
            "repeats": repeats, "device": env_throughput.device_name(), "steps_per_s": None,
            "compile_s": None, **extra}


def _compiled(make_run):
    """(compiled run, its solver options, compile seconds, overflowed env-steps of the warm-up
    run: None for Brax's), or the reason it cannot run (a missing peer, out of memory) as a string."""
    try:
        run, solver = make_run()
        key = jax.random.PRNGKey(0)
        start = time.perf_counter()
        compiled = run.lower(key).compile()
        compile_s = time.perf_counter() - start
        warm_up = jax.block_until_ready(compiled(key))
        return compiled, solver, compile_s, env_throughput.overflow_steps(warm_up)
    except PeerMissing as missing:
        return str(missing)
    except Exception as err:
        if not env_throughput._out_of_memory(err):
            raise
        return f"out of memory: {str(err).splitlines()[0]}"


def measure_task(name: str, num_envs: int, impls, brax: bool, steps: int, repeats: int) -> list[dict]:
    """Ours (each impl) and Brax's (own and equal solver options) at one batch size, side by side."""
    jobs = [(("mjxsuite", impl), lambda impl=impl: our_rollout(name, impl, num_envs, steps)) for impl in impls]
    if brax and name in BRAX_NAMES:
        # Our task's model options: Gymnasium's MJCF's, but Newton where it names PGS (humanoid), which
        # MJX lacks; Gymnasium's vector env keeps its own (each record names the solver it ran).
        gymnasium_solver = solver_options(envs.make(name).unwrapped.mj_model.opt)
        jobs.append((("brax", "own"), lambda: brax_rollout(BRAX_NAMES[name], num_envs, steps)))
        jobs.append((("brax", "gymnasium"), lambda: brax_rollout(BRAX_NAMES[name], num_envs, steps, gymnasium_solver)))
    records, runs = [], []
    for (lib, variant), make_run in jobs:
        extra = {"impl": variant} if lib == "mjxsuite" else {"brax_env": BRAX_NAMES[name], "solver_from": variant}
        record = _record(lib, name, num_envs, steps, repeats, **extra)
        result = _compiled(make_run)
        if isinstance(result, str):
            record["skipped"] = result
        else:
            run, record["solver"], record["compile_s"], record["overflow_steps"] = result
            runs.append((run, record))
        records.append(record)
    times = env_throughput.time_side_by_side([run for run, _ in runs], repeats)
    for (_, record), spent in zip(runs, times):
        record["steps_per_s"] = num_envs * steps / statistics.median(spent)
        record["run_s"] = spent
    return records


def ratio_records(records: list[dict]) -> list[dict]:
    """Ours against Gymnasium's vector env (every impl), and against Brax at the same solver options."""
    rows = []
    for ours in (r for r in records if r["lib"] == "mjxsuite" and r["steps_per_s"]):
        for peer in records:
            if peer["env"] != ours["env"] or not peer["steps_per_s"] or peer["lib"] == "mjxsuite":
                continue
            if peer["lib"] == "brax" and (peer["num_envs"] != ours["num_envs"] or peer["solver"] != ours["solver"]):
                continue
            rows.append({"kind": "gym-mujoco-ratio", "env": ours["env"], "impl": ours["impl"],
                         "num_envs": ours["num_envs"], "peer": peer["lib"], "peer_num_envs": peer["num_envs"],
                         "ratio": ours["steps_per_s"] / peer["steps_per_s"], "device": ours["device"],
                         "overflow_steps": ours.get("overflow_steps")})
    return rows


def run_benchmark(tasks, sizes, impls, brax=True, gymnasium=True, steps=None, gymnasium_steps=500,
                  repeats=3, print_rows=True) -> list[dict]:
    records = []
    show = print if print_rows else (lambda *a, **k: None)
    show(f"{'lib':<10}{'env':<26}{'impl/solver':<24}{'num_envs':>9}{'env-steps/s':>15}{'compile s':>11}")
    for name in tasks:
        if gymnasium:
            gymnasium_id = envs.make(name).unwrapped.gymnasium_id
            found = gymnasium_vector_speed(gymnasium_id, gymnasium_steps, repeats)
            records.append({**_record("gymnasium", name, found["num_envs"], found["steps"], repeats),
                            **found, "gymnasium_id": gymnasium_id, "vectorization_mode": "async",
                            "cpu_count": os.cpu_count()})
            show(f"{'gymnasium':<10}{gymnasium_id + ' (async)':<26}{'C MuJoCo':<24}{found['num_envs']:>9}"
                 f"{found['steps_per_s']:>15,.0f}", flush=True)
        for num_envs in sizes:
            for r in measure_task(name, num_envs, impls, brax, steps or steps_for(num_envs), repeats):
                records.append(r)
                label = r.get("impl") or f"{r['brax_env']}@{r['solver_from']}"
                if r["steps_per_s"] is None:
                    show(f"{r['lib']:<10}{name:<26}{label:<24}{num_envs:>9}   skipped: {r['skipped']}", flush=True)
                else:
                    show(f"{r['lib']:<10}{name:<26}{label:<24}{num_envs:>9}{r['steps_per_s']:>15,.0f}"
                         f"{r['compile_s']:>11.1f}{env_throughput.overflow_note(r)}", flush=True)
    ratios = ratio_records(records)
    for r in ratios:
        show(f"{r['env']} impl={r['impl']} at {r['num_envs']} envs / {r['peer']} ({r['peer_num_envs']} envs): "
             f"{r['ratio']:,.2f}x{env_throughput.overflow_note(r)}")
    return records + ratios


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", help="registered names (default: every Gymnasium MuJoCo task)")
    parser.add_argument("--sizes", nargs="*", type=int, default=[4096, 32768],
                        help="batch sizes of ours and Brax's (none: Gymnasium's vector env alone)")
    parser.add_argument("--impls", nargs="+", choices=envs.mjx_env.IMPLS,
                        help="MJX implementations (default: jax, and warp where it runs)")
    parser.add_argument("--no-brax", action="store_true", help="leave out Brax's envs")
    parser.add_argument("--no-gymnasium", action="store_true", help="leave out Gymnasium's vector env")
    parser.add_argument("--steps", type=int, help="scan length of a timed run (default: about 1M env steps)")
    parser.add_argument("--gymnasium-steps", type=int, default=500, help="vector steps of a timed Gymnasium run")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", help="also write the records to this file")
    args = parser.parse_args(argv)
    known = gymnasium_tasks()
    tasks = args.tasks or known
    unknown = sorted(set(tasks) - set(known))
    if unknown:
        parser.error(f"--tasks {unknown}: not Gymnasium MuJoCo tasks; choose from {known}")
    impls = args.impls or (["jax", "warp"] if warp_available() else ["jax"])
    if "warp" in impls:
        envs.mjx_env.require_warp()  # a clear error now, not after the first task's figures
    meta = {"kind": "meta", "device": env_throughput.device_name(), "platform": env_throughput.platform(),
            "jax": jax.__version__, "cpu_count": os.cpu_count(), "argv": sys.argv[1:] if argv is None else list(argv),
            "versions": {package: version(package) for package in
                         ("mujoco", "mujoco-mjx", "mujoco-warp", "warp-lang", "brax", "gymnasium")}}
    records = [meta]
    for name in tasks:  # the file is rewritten after each task: a run cut short keeps what it measured
        records += run_benchmark([name], args.sizes, impls, brax=not args.no_brax, gymnasium=not args.no_gymnasium,
                                 steps=args.steps, gymnasium_steps=args.gymnasium_steps, repeats=args.repeats)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(records, f, indent=2, default=lambda x: x.item() if isinstance(x, np.generic) else str(x))


if __name__ == "__main__":
    main()
