"""Env-steps/s of the DeepMind Control Suite's tasks: ours (dm_control's models and physics, proven
equal to dm_control) beside MuJoCo Playground's look-alikes of the same tasks at Playground's own
settings, and beside dm_control's own env on every core of the host, in one run on one device.

- ours: `envs.make("dmc-<task>", impl=...)` stepped as `benchmarks.gym_mujoco` steps Gymnasium's
  tasks (`wrap_for_training`, uniform random actions, one `lax.scan` in one `jit`), with the
  env-steps on which MuJoCo Warp ran out of a buffer counted (`overflow_steps`);
- Playground 0.2.0's look-alike (`registry.load(PLAYGROUND_NAMES[task])`, its `impl` set, its
  own timestep, solver iterations, contact buffers), in Playground's Brax training wrapper,
  stepped by the same loop; its overflow counted from MuJoCo Warp's per-world flags;
- dm_control's `suite.load(domain, task)` (C MuJoCo, float64), one process per core, random actions.

Every figure is one control step (dm_control's control timestep for ours and dm_control's,
Playground's own for its look-alike; each record gives `control_timestep`), so a ratio is
control steps per second, what an agent waits for. Compile time is kept apart; our run and
Playground's alternate at each size and the figure is the median after a warm-up.

    python -m benchmarks.dmc_speed [--tasks cheetah-run walker-walk humanoid-walk]
        [--sizes 4096 32768] [--impls warp jax] [--no-dm-control] [--repeats 3] [--json FILE]

On a CPU it is a smoke test (`--sizes 4 --steps 3 --impls jax`).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import envs
from benchmarks import env_throughput, gym_mujoco
from benchmarks.peers import PeerMissing, version

# Playground 0.2.0's look-alike of each task (its own XML, timestep and solver settings).
PLAYGROUND_NAMES = {"cheetah-run": "CheetahRun", "walker-walk": "WalkerWalk", "walker-run": "WalkerRun",
                    "humanoid-walk": "HumanoidWalk", "hopper-hop": "HopperHop", "cartpole-swingup": "CartpoleSwingup",
                    "finger-spin": "FingerSpin", "reacher-easy": "ReacherEasy", "ball-in-cup-catch": "BallInCup",
                    "acrobot-swingup": "AcrobotSwingup", "pendulum-swingup": "PendulumSwingup"}
# MuJoCo Warp's overflow bits that mean dropped contacts or constraint rows (`envs.mjx_warp`).
_DROPPED = envs.mjx_warp.CONTACT_OVERFLOW | envs.mjx_warp.CONSTRAINT_OVERFLOW


def playground_rollout(task: str, impl: str, num_envs: int, steps: int):
    """`run(key) -> (total reward, final observations, overflowed env-steps)` of Playground's look-alike."""
    try:
        from mujoco_playground import registry, wrapper
    except ImportError as err:
        raise PeerMissing(f"mujoco_playground is not installed ({err}); pip install playground==0.2.0") from err
    name = PLAYGROUND_NAMES[task]
    config = registry.get_default_config(name)
    env = registry.load(name, config_overrides={"impl": impl})
    if impl == "warp":  # Warp's overflow printing off, as ours has it; overflow is counted below instead
        env._mjx_model = env.mjx_model.tree_replace({"opt._impl.warn_overflow": 0})
    wrapped = wrapper.wrap_for_brax_training(env, episode_length=int(config.episode_length))

    def body(carry, _):
        state, key, total, overflowed = carry
        key, action_key = jax.random.split(key)
        action = jax.random.uniform(action_key, (num_envs, env.action_size), minval=-1.0, maxval=1.0)
        state = wrapped.step(state, action)
        if impl == "warp":
            overflowed += ((state.data._impl.overflow & _DROPPED) != 0).sum()
        return (state, key, total + state.reward.sum(), overflowed), None

    @jax.jit
    def run(key):
        key, reset_key = jax.random.split(key)
        start = (wrapped.reset(jax.random.split(reset_key, num_envs)), key, jnp.zeros(()), jnp.zeros((), jnp.int32))
        (state, _, total, overflowed), _ = jax.lax.scan(body, start, None, steps)
        return total, state.obs, overflowed

    return run, {"control_timestep": float(config.ctrl_dt), "sim_dt": float(config.sim_dt),
                 "solver": gym_mujoco.solver_options(env.mj_model.opt), "playground_env": name}


def our_rollout(task: str, impl: str, num_envs: int, steps: int):
    name = f"dmc-{task}"
    unwrapped = envs.make(name).unwrapped
    return env_throughput.rollout_fn(name, num_envs, steps, {"impl": impl}), {
        "control_timestep": float(unwrapped.dt), "solver": gym_mujoco.solver_options(unwrapped.mj_model.opt)}


def measure(task: str, num_envs: int, impls, playground: bool, steps: int, repeats: int) -> list[dict]:
    """Ours and Playground's at one batch size and each impl, their timed runs alternating."""
    jobs = [(lib, impl, maker) for impl in impls for lib, maker in
            [("mjxsuite", our_rollout), ("playground", playground_rollout)] if lib == "mjxsuite" or playground]
    records, runs = [], []
    for lib, impl, maker in jobs:
        record = {"kind": "dmc-speed", "lib": lib, "env": f"dmc-{task}", "impl": impl, "num_envs": num_envs,
                  "steps": steps, "repeats": repeats, "device": env_throughput.device_name(),
                  "steps_per_s": None, "compile_s": None}
        if lib == "playground":
            record["version"] = version("playground")
        result = gym_mujoco._compiled(lambda: maker(task, impl, num_envs, steps))
        if isinstance(result, str):
            record["skipped"] = result
        else:
            run, settings, record["compile_s"], record["overflow_steps"] = result
            record.update(settings)
            runs.append((run, record))
        records.append(record)
    for (_, record), spent in zip(runs, env_throughput.time_side_by_side([run for run, _ in runs], repeats)):
        record["steps_per_s"] = num_envs * steps / statistics.median(spent)
        record["run_s"] = spent
    return records


def _dm_control_worker(args) -> float:
    domain, task, steps, seed = args
    env = envs.load_dm_control(domain, task, seed=seed)
    spec = env.action_spec()
    rng = np.random.default_rng(seed)
    env.reset()
    start = time.perf_counter()
    for _ in range(steps):
        if env.step(rng.uniform(spec.minimum, spec.maximum)).last():
            env.reset()
    return steps / (time.perf_counter() - start)


def dm_control_speed(task: str, steps: int = 1000) -> dict:
    """Env-steps/s of dm_control's own env, one process per core (spawned), summed over the cores."""
    domain, _, name = task.replace("ball-in-cup", "ball_in_cup").partition("-")
    cores = os.cpu_count()
    with multiprocessing.get_context("spawn").Pool(cores) as pool:
        rates = pool.map(_dm_control_worker, [(domain, name.replace("-", "_"), steps, i) for i in range(cores)])
    return {"kind": "dmc-speed", "lib": "dm_control", "env": f"dmc-{task}", "num_envs": cores, "steps": steps,
            "steps_per_s": float(sum(rates)), "cpu_count": cores, "note": "one process per core, C MuJoCo"}


def ratios(records: list[dict]) -> list[dict]:
    """Ours against Playground's look-alike (same impl and size) and against dm_control's own env."""
    found = []
    for ours in (r for r in records if r["lib"] == "mjxsuite" and r["steps_per_s"]):
        for peer in (r for r in records if r["lib"] != "mjxsuite" and r["steps_per_s"] and r["env"] == ours["env"]):
            if peer["lib"] == "playground" and (peer["impl"], peer["num_envs"]) != (ours["impl"], ours["num_envs"]):
                continue
            found.append({"kind": "dmc-speed-ratio", "env": ours["env"], "impl": ours["impl"],
                          "num_envs": ours["num_envs"], "peer": peer["lib"], "ratio": ours["steps_per_s"] / peer["steps_per_s"],
                          "overflow_steps": ours.get("overflow_steps"), "peer_overflow_steps": peer.get("overflow_steps")})
    return found


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=["cheetah-run", "walker-walk", "humanoid-walk"],
                        choices=sorted(PLAYGROUND_NAMES))
    parser.add_argument("--sizes", nargs="+", type=int, default=[4096, 32768])
    parser.add_argument("--impls", nargs="+", default=["warp", "jax"], choices=envs.mjx_env.IMPLS)
    parser.add_argument("--steps", type=int, help="scan length of a timed run (default: about 1M env steps)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-playground", action="store_true")
    parser.add_argument("--no-dm-control", action="store_true")
    parser.add_argument("--json", help="also write the records to this file")
    args = parser.parse_args(argv)
    records = []
    for task in args.tasks:
        found = [dm_control_speed(task)] if not args.no_dm_control else []
        for num_envs in args.sizes:
            found += measure(task, num_envs, args.impls, not args.no_playground,
                             args.steps or gym_mujoco.steps_for(num_envs), args.repeats)
        records += found + ratios(found)
        for r in found:
            figure = f"{r['steps_per_s']:>14,.0f}" if r["steps_per_s"] else f"  skipped: {r.get('skipped')}"
            print(f"{r['lib']:<11}{r['env']:<20}{r.get('impl', 'C'):<6}{r['num_envs']:>7}{figure}"
                  f"{env_throughput.overflow_note(r)}", flush=True)
        for r in ratios(found):
            print(f"{r['env']} impl={r['impl']} {r['num_envs']} envs / {r['peer']}: {r['ratio']:.2f}x", flush=True)
        if args.json:  # after every task: a run stopped part-way keeps what it measured
            with open(args.json, "w") as f:
                json.dump(records, f, indent=1)

if __name__ == "__main__":
    main()
