"""Env-steps/s of Gymnasium's vector API on our envs (issue 45), three loops at one batch size, on
one machine:

- `torch`: `gymnasium.make_vec("mjxsuite/Hopper-v5", num_envs=N)` in Gymnasium's `JaxToTorch`,
  a PyTorch MLP policy (two hidden layers of 256, tanh) computing every step's actions from the
  observations, as a PyTorch training loop collects data: one Python-level step per vector step,
  arrays handed between JAX and PyTorch through DLPack on the device (needs torch);
- `jax`: our pure JAX loop at the same size (`benchmarks.env_throughput.rollout_fn`: random
  actions, auto-reset, one `lax.scan` in one `jit`), the ceiling of the first;
- `gymnasium`: Gymnasium's own vector env of the task (C MuJoCo, float64), `AsyncVectorEnv`
  with one process per core of the machine (`benchmarks.gym_mujoco.gymnasium_vector_speed`).

Records (kind "gym-vector") carry `steps_per_s`, and a "gym-vector-ratio" record the two ratios
the issue asks for: torch / jax (at least 0.5) and torch / gymnasium (at least 30). Compile time
and a warm-up are kept out of the timed runs; each figure is the median of `--repeats` runs.

    python -m benchmarks.gym_vector [--id mjxsuite/Hopper-v5] [--num-envs 4096] [--steps 200]
        [--repeats 5] [--gymnasium-steps 300] [--no-gymnasium] [--impl jax|warp] [--json FILE]
    mjxsuite bench --sections gym-vector [--batch 4096] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import jax

from benchmarks import env_throughput, gym_mujoco


def _record(loop: str, gymnasium_id: str, num_envs: int, steps: int, **extra) -> dict:
    return {"kind": "gym-vector", "lib": "mjxsuite" if loop != "gymnasium" else "gymnasium", "loop": loop,
            "env": gymnasium_id, "num_envs": num_envs, "steps": steps, "device": env_throughput.device_name(),
            "steps_per_s": None, **extra}


def torch_loop_speed(gymnasium_id: str, num_envs: int, steps: int, repeats: int, hidden: int = 256,
                     env_options: dict | None = None) -> dict:
    """make_vec + JaxToTorch + a torch MLP's forward pass every step (its actions drive the envs)."""
    try:
        import torch
        from gymnasium.wrappers.vector import JaxToTorch
    except ImportError as err:
        return _record("torch", gymnasium_id, num_envs, steps, skipped=f"torch is not installed ({err}); "
                       'pip install -e ".[torch]"')
    import gymnasium

    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    vector = JaxToTorch(gymnasium.make_vec(gymnasium_id, num_envs=num_envs, **(env_options or {})), device=device)
    obs_size, action_size = vector.single_observation_space.shape[0], vector.single_action_space.shape[0]
    low = torch.as_tensor(vector.single_action_space.low, device=device)
    high = torch.as_tensor(vector.single_action_space.high, device=device)
    policy = torch.nn.Sequential(torch.nn.Linear(obs_size, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, hidden),
                                 torch.nn.Tanh(), torch.nn.Linear(hidden, action_size)).to(device)

    def run(count: int) -> float:
        obs, _ = vector.reset(seed=0)
        torch.cuda.synchronize() if device.type == "cuda" else None
        start = time.perf_counter()
        with torch.no_grad():
            for _ in range(count):
                action = torch.clamp(policy(obs) + 0.1 * torch.randn(num_envs, action_size, device=device), low, high)
                obs, reward, terminated, truncated, _ = vector.step(action)
        float(reward.sum())  # waits for the last step
        return time.perf_counter() - start

    compile_start = time.perf_counter()
    run(3)  # compiles reset and step
    compile_s = time.perf_counter() - compile_start
    run(min(steps, 20))  # warm-up
    spent = [run(steps) for _ in range(repeats)]
    return _record("torch", gymnasium_id, num_envs, steps, steps_per_s=num_envs * steps / statistics.median(spent),
                   run_s=spent, compile_s=compile_s, torch=torch.__version__, torch_device=str(device),
                   policy=f"MLP {obs_size}-{hidden}-{hidden}-{action_size} tanh")


def jax_loop_speed(task: str, gymnasium_id: str, num_envs: int, steps: int, repeats: int,
                   env_options: dict | None = None) -> dict:
    run = env_throughput.rollout_fn(task, num_envs, steps, env_options)
    key = jax.random.PRNGKey(0)
    start = time.perf_counter()
    compiled = run.lower(key).compile()
    compile_s = time.perf_counter() - start
    overflowed = env_throughput.overflow_steps(jax.block_until_ready(compiled(key)))
    spent = env_throughput.time_side_by_side([compiled], repeats)[0]
    # Under impl="warp" a figure counts only beside zero overflowed env-steps (no physics there).
    return _record("jax", gymnasium_id, num_envs, steps, steps_per_s=num_envs * steps / statistics.median(spent),
                   run_s=spent, compile_s=compile_s, task=task, overflow_steps=overflowed)


def run_benchmark(gymnasium_id: str = "mjxsuite/Hopper-v5", num_envs: int = 4096, steps: int = 200, repeats: int = 5,
                  gymnasium: bool = True, gymnasium_steps: int = 300, impl: str | None = None) -> list[dict]:
    """The three loops' records and the ratio record; `impl` ("jax" or "warp", None: the task's
    default) steps MJX in both of our loops alike."""
    import gymnasium

    # Our ids are in Gymnasium's registry (the installed package registers them): the spec names
    # our task, and the id without its namespace is Gymnasium's own env of the task.
    task = gymnasium.spec(gymnasium_id).kwargs["task"]
    local_id = gymnasium_id.split("/", 1)[-1]
    env_options = {} if impl is None else {"impl": impl}
    records = [torch_loop_speed(gymnasium_id, num_envs, steps, repeats, env_options=env_options),
               jax_loop_speed(task, gymnasium_id, num_envs, steps, repeats, env_options)]
    for r in records:
        r["impl"] = impl or "default"
    if gymnasium:
        result = gym_mujoco.gymnasium_vector_speed(local_id, gymnasium_steps, repeats)
        records.append(_record("gymnasium", local_id, result["num_envs"], gymnasium_steps,
                               steps_per_s=result["steps_per_s"], run_s=result["run_s"], solver=result["solver"]))
    speed = {r["loop"]: r["steps_per_s"] for r in records}
    ratio = {"kind": "gym-vector-ratio", "lib": "mjxsuite", "env": gymnasium_id, "num_envs": num_envs,
             "device": env_throughput.device_name(), "impl": impl or "default",
             "gymnasium_num_envs": next((r["num_envs"] for r in records if r["loop"] == "gymnasium"), None),
             "torch_over_jax": speed["torch"] / speed["jax"] if speed.get("torch") and speed.get("jax") else None,
             "torch_over_gymnasium": (speed["torch"] / speed["gymnasium"]
                                      if speed.get("torch") and speed.get("gymnasium") else None)}
    for r in records:
        figure = f"{r['steps_per_s']:,.0f} env-steps/s" if r["steps_per_s"] else f"skipped: {r.get('skipped')}"
        print(f"   {r['loop']:>9} {r['env']} x {r['num_envs']:,}: {figure}", flush=True)
    for name, need in (("torch_over_jax", 0.5), ("torch_over_gymnasium", 30.0)):
        if ratio[name] is not None:
            print(f"   {name}: {ratio[name]:.2f}x (issue 45 asks at least {need}x)", flush=True)
    print(json.dumps(ratio), flush=True)
    return records + [ratio]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--id", default="mjxsuite/Hopper-v5")
    parser.add_argument("--num-envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=200, help="vector steps per timed run of ours")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--gymnasium-steps", type=int, default=300, help="vector steps per timed run of Gymnasium's")
    parser.add_argument("--no-gymnasium", action="store_true", help="leave out Gymnasium's own vector env")
    parser.add_argument("--impl", choices=["jax", "warp"], help="MJX's implementation in both of our loops "
                        "(default: the task's, jax; warp needs the [warp] extra and an NVIDIA GPU)")
    parser.add_argument("--json", metavar="FILE")
    args = parser.parse_args(argv)
    records = run_benchmark(args.id, args.num_envs, args.steps, args.repeats, not args.no_gymnasium,
                            args.gymnasium_steps, args.impl)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(records, f, indent=1)


if __name__ == "__main__":
    main()
