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
        [--opt FIELD=VALUE ...] [--profile DIR]

`--opt` sets a solver option of ours (what dm_control's settings cost); `--profile` traces one
stepping run of each side under `jax.profiler` and adds kernel launches and kernel time per step.
On a CPU it is a smoke test (`--sizes 4 --steps 3 --impls jax`).
"""

from __future__ import annotations

import argparse
import functools
import multiprocessing
import os
import statistics
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import envs
from agents.env_options import parse_opt_field
from benchmarks import env_throughput, gpu_profile, gym_mujoco
from benchmarks.peers import PeerMissing, version
from benchmarks.suite import each_task_alone, without_options, write_records

# Playground 0.2.0's look-alike of each task (its own XML, timestep and solver settings).
# Every task of ours that Playground 0.2.0 registers a look-alike of (its dm_control_suite `_envs`).
PLAYGROUND_NAMES = {"acrobot-swingup": "AcrobotSwingup", "acrobot-swingup-sparse": "AcrobotSwingupSparse",
                    "ball-in-cup-catch": "BallInCup", "cartpole-balance": "CartpoleBalance",
                    "cartpole-balance-sparse": "CartpoleBalanceSparse", "cartpole-swingup": "CartpoleSwingup",
                    "cartpole-swingup-sparse": "CartpoleSwingupSparse", "cheetah-run": "CheetahRun",
                    "finger-spin": "FingerSpin", "finger-turn-easy": "FingerTurnEasy", "finger-turn-hard": "FingerTurnHard",
                    "fish-swim": "FishSwim", "hopper-hop": "HopperHop", "hopper-stand": "HopperStand",
                    "humanoid-stand": "HumanoidStand", "humanoid-walk": "HumanoidWalk", "humanoid-run": "HumanoidRun",
                    "pendulum-swingup": "PendulumSwingup", "point-mass-easy": "PointMass", "reacher-easy": "ReacherEasy",
                    "reacher-hard": "ReacherHard", "swimmer-swimmer6": "SwimmerSwimmer6", "walker-stand": "WalkerStand",
                    "walker-walk": "WalkerWalk", "walker-run": "WalkerRun"}
# MuJoCo Warp's overflow bits that mean dropped contacts or constraint rows (`envs.mjx_warp`).
_DROPPED = envs.mjx_warp.CONTACT_OVERFLOW | envs.mjx_warp.CONSTRAINT_OVERFLOW


# A task's episode in control steps: dm_control's 1,000 (20 s at cheetah's 0.01 s steps), and
# Playground's `episode_length` for its look-alikes. The reset runs once per episode.
EPISODE_STEPS = 1000


def _parts(env, actions, overflow, num_envs: int, steps: int):
    """(reset(key) -> state, run(state, key) -> (total reward, overflowed env-steps)), jitted: the
    reset apart, as an agent pays it once an episode; `steps` control steps from a reset state."""

    def body(carry, _):
        state, key, total, overflowed = carry
        key, action_key = jax.random.split(key)
        state = env.step(state, actions(action_key))
        return (state, key, total + state.reward.sum(), overflowed + overflow(state)), None

    def run(state, key):
        (state, _, total, overflowed), _ = jax.lax.scan(body, (state, key, jnp.zeros(()), jnp.zeros((), jnp.int32)),
                                                         None, steps)
        return total, overflowed

    return jax.jit(env.reset), jax.jit(run)


def playground_parts(task: str, impl: str, num_envs: int, steps: int):
    """`_parts` of Playground's look-alike in its Brax training wrapper, with its settings."""
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

    def actions(key):
        return jax.random.uniform(key, (num_envs, env.action_size), minval=-1.0, maxval=1.0)

    def overflow(state):
        if impl != "warp":
            return jnp.zeros((), jnp.int32)
        return ((state.data._impl.overflow & _DROPPED) != 0).sum()

    reset, run = _parts(wrapped, actions, overflow, num_envs, steps)
    return (lambda key: reset(jax.random.split(key, num_envs))), run, {
        "control_timestep": float(config.ctrl_dt), "sim_dt": float(config.sim_dt),
        "episode_steps": int(config.episode_length), "solver": gym_mujoco.solver_options(env.mj_model.opt),
        "playground_env": name}


def our_parts(task: str, impl: str, num_envs: int, steps: int, opt: dict | None = None):
    """`_parts` of ours, in the wrappers an agent trains in (no episode statistics, as the peer);
    `opt` overrides MuJoCo's solver options (`envs.mjx_options`), which makes it no longer dm_control."""
    base = envs.make(f"dmc-{task}", impl=impl, **({"opt": opt} if opt else {}))
    env = envs.wrap_for_training(base, num_envs, episode_stats=False)
    reset, run = _parts(env, lambda key: env_throughput.random_env_actions(key, env, num_envs),
                        lambda state: (state.info["overflow"] > 0).sum(), num_envs, steps)
    return reset, run, {"control_timestep": float(base.unwrapped.dt), "episode_steps": EPISODE_STEPS,
                        "solver": gym_mujoco.solver_options(base.unwrapped.mj_model.opt)}


def _timed(function, *args) -> tuple[float, object]:
    start = time.perf_counter()
    out = jax.block_until_ready(function(*args))
    return time.perf_counter() - start, out


def measure(task: str, num_envs: int, impls, playground: bool, steps: int, repeats: int,
            opt: dict | None = None, profile: str | None = None) -> list[dict]:
    """Ours and Playground's at one batch size and each impl, their timed runs alternating. Each
    record gives the reset's seconds, the steps/s of stepping alone, and `episode_steps_per_s`:
    one episode of every env, its reset included, which is what an agent waits for."""
    ours = functools.partial(our_parts, opt=opt)
    jobs = [(lib, impl, maker) for impl in impls for lib, maker in
            [("mjxsuite", ours), ("playground", playground_parts)] if lib == "mjxsuite" or playground]
    records, runs = [], []
    for lib, impl, maker in jobs:
        record = {"kind": "dmc-speed", "lib": lib, "env": f"dmc-{task}", "impl": impl, "num_envs": num_envs,
                  "steps": steps, "repeats": repeats, "device": env_throughput.device_name(),
                  "steps_per_s": None, "compile_s": None}
        if lib == "playground":
            record["version"] = version("playground")
        elif opt:
            record["opt"] = opt
        try:
            reset, run, settings = maker(task, impl, num_envs, steps)
            key = jax.random.PRNGKey(0)
            compile_s, state = _timed(reset, key)  # the first calls compile
            run_compile_s, (_, overflowed) = _timed(run, state, key)
        except PeerMissing as missing:
            record["skipped"] = str(missing)
        else:
            record.update(settings, compile_s=compile_s + run_compile_s, overflow_steps=int(overflowed))
            runs.append((reset, run, record))
        records.append(record)
    for i in range(repeats):  # A B A B ...: a change in the machine's speed hits both alike
        key = jax.random.PRNGKey(i + 1)
        for reset, run, record in runs:
            reset_s, state = _timed(reset, key)
            record.setdefault("reset_s", []).append(reset_s)
            record.setdefault("run_s", []).append(_timed(run, state, key)[0])
    for _, _, record in runs:
        record["steps_per_s"] = num_envs * steps / statistics.median(record["run_s"])
        episode = num_envs * record["episode_steps"]
        record["episode_steps_per_s"] = episode / (statistics.median(record["reset_s"]) + episode / record["steps_per_s"])
    if profile:
        _profiled(runs, profile, steps)
    return records


def _profiled(runs, directory: str, steps: int) -> None:
    """One more stepping run of each under `jax.profiler`: its kernels, summed (`gpu_profile.summary`),
    as `record["profile"]`, with kernel launches and kernel microseconds per control step."""
    key = jax.random.PRNGKey(0)
    for reset, run, record in runs:
        where = os.path.join(directory, f"{record['lib']}-{record['env']}-{record['impl']}-{record['num_envs']}")
        state = jax.block_until_ready(reset(key))
        with gpu_profile.traced(where):
            _timed(run, state, key)
        found = gpu_profile.summary(where)
        if "launches" in found:
            found |= {"launches_per_step": found["launches"] / steps, "kernel_us_per_step": found["kernel_s"] / steps * 1e6}
        record["profile"] = found


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


def _episode_speed(record: dict) -> float:
    """Env-steps/s over whole episodes, resets included (dm_control's loop resets as it goes)."""
    return record.get("episode_steps_per_s") or record["steps_per_s"]


def ratios(records: list[dict]) -> list[dict]:
    """Ours against Playground's look-alike (same impl and size) and against dm_control's own env,
    over whole episodes (`ratio`) and stepping alone (`step_ratio`)."""
    found = []
    for ours in (r for r in records if r["lib"] == "mjxsuite" and r["steps_per_s"]):
        for peer in (r for r in records if r["lib"] != "mjxsuite" and r["steps_per_s"] and r["env"] == ours["env"]):
            if peer["lib"] == "playground" and (peer["impl"], peer["num_envs"]) != (ours["impl"], ours["num_envs"]):
                continue
            found.append({"kind": "dmc-speed-ratio", "env": ours["env"], "impl": ours["impl"],
                          "num_envs": ours["num_envs"], "peer": peer["lib"],
                          "ratio": _episode_speed(ours) / _episode_speed(peer),
                          "step_ratio": ours["steps_per_s"] / peer["steps_per_s"],
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
    parser.add_argument("--opt", action="append", default=[], metavar="FIELD=VALUE",
                        help="a solver option of ours (e.g. iterations=4), to measure what dm_control's settings cost")
    parser.add_argument("--profile", metavar="DIR", help="also trace one stepping run of each under jax.profiler into DIR "
                        "and add its kernels (launches and kernel time per step, the top kernels) to the records")
    parser.add_argument("--json", help="also write the records to this file")
    args = parser.parse_args(argv)
    fields = [o.partition("=")[::2] for o in args.opt]
    opt = envs.mjx_options.check_opt({k: parse_opt_field(k, v, "--opt") for k, v in fields}, "--opt")
    if len(args.tasks) > 1:
        argv = sys.argv[1:] if argv is None else argv
        return each_task_alone("benchmarks.dmc_speed", without_options(argv, ("--tasks", "--json")), args.tasks,
                               args.json)
    task = args.tasks[0]
    found = [dm_control_speed(task)] if not args.no_dm_control else []
    _print(found, [])
    for num_envs in args.sizes:
        measured = measure(task, num_envs, args.impls, not args.no_playground,
                           args.steps or gym_mujoco.steps_for(num_envs), args.repeats, opt, args.profile)
        found += measured
        _print(measured, [r for r in ratios(found) if r["num_envs"] == num_envs])
        if args.json:  # after every size: a run stopped part-way keeps what it measured
            write_records(args.json, found + ratios(found))


def _print(records: list[dict], found_ratios: list[dict]) -> None:
    for r in records:
        figure = (f"{r['steps_per_s']:>14,.0f} stepping{_episode_speed(r):>14,.0f} over episodes"
                  if r["steps_per_s"] else f"  skipped: {r.get('skipped')}")
        print(f"{r['lib']:<11}{r['env']:<20}{r.get('impl', 'C'):<6}{r['num_envs']:>7}{figure}"
              f"{env_throughput.overflow_note(r)}", flush=True)
        if "launches_per_step" in r.get("profile", {}):
            p = r["profile"]
            print(f"{'':<11}profile: {p['launches_per_step']:.0f} kernel launches and {p['kernel_us_per_step']:.0f} us of "
                  f"kernels per step, GPU busy {p['busy']:.0%} of the span", flush=True)
    for r in found_ratios:
        print(f"{r['env']} impl={r['impl']} {r['num_envs']} envs / {r['peer']}: {r['ratio']:.2f}x over episodes,"
              f" {r['step_ratio']:.2f}x stepping", flush=True)


if __name__ == "__main__":
    main()
