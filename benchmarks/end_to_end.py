"""What a user waits for, end to end: our whole `mjxsuite train` process against PureJaxRL's
whole `make_train`, compile included, for the same work, back to back on one device.

The work is PureJaxRL's own DQN config (`benchmarks.dqn_peer.MATCHED["10 envs"]`: 10 envs per
agent, one update per 10 env steps, batch 128, buffer 10k, 120-84 network, lr 2.5e-4, a hard
target copy every 500 env steps, no gradient clipping, plain DQN) for `--seeds` agents and
`--steps` env steps each. Both sides run in fresh processes with no persistent compilation
cache:

- ours: `python -m agents.cli train --env cartpole ... --no-compile-cache`, the wall time of
  the whole process (start-up, compiles, training with a greedy evaluation every
  `--eval-every` steps, the final evaluation), and the breakdown its last line prints;
- the peer: a process that loads `make_train` from `--peer` (never part of this package) and
  times `jax.jit(jax.vmap(make_train(config)))` from the jit to the trained state (trace,
  compile and run, as PureJaxRL's own `main()` does), and its process's wall time too.

`ratio` is the peer's `make_train` time over our process's wall time (> 1: we finish first).
First, untimed, a warm-up process imports jax, Flax and Optax and runs a small program on the
device: the first process on a freshly started machine reads the libraries from disk and
starts the GPU for the first time, which cost whichever side ran first a few seconds more (our
start-up and compile took 3.9 and 9.2 s when ours ran first on a freshly started H100, 2.0 and
6.9 s when it ran second on another). `--no-warm-up` skips it.

On a GPU, the issue's run (about 2 minutes for both):

    python -m benchmarks.end_to_end --peer /path/to/purejaxrl_dqn.py --json e2e.json

A smoke test on the CPU: `--seeds 2 --steps 400 --eval-every 200 --learning-starts 200
--exploration-steps 200`.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.dqn_peer import MATCHED

OURS, PEER = MATCHED["10 envs"]
ROOT = Path(__file__).resolve().parents[1]

# The peer's process: load make_train by path, time it whole, print one JSON line.
_PEER_PROGRAM = """
import json, sys, time
start = time.perf_counter()
import jax
from benchmarks.dqn_peer import load_peer
config = json.loads(sys.argv[2])
make_train = load_peer(sys.argv[1])
keys = jax.random.split(jax.random.PRNGKey(config["SEED"]), config["NUM_SEEDS"])
jax.block_until_ready(keys)
tick = time.perf_counter()
train = jax.jit(jax.vmap(make_train(dict(config))))
compiled = train.lower(keys).compile()
compiled_at = time.perf_counter()
jax.block_until_ready(compiled(keys))
done = time.perf_counter()
print(json.dumps({"make_train_s": done - tick, "compile_s": compiled_at - tick, "run_s": done - compiled_at,
                  "startup_s": tick - start, "device": jax.devices()[0].device_kind}))
"""

# The untimed warm-up: the libraries both sides load, and a first program on the device.
_WARM_UP_PROGRAM = """
import jax, jax.numpy as jnp, flax, optax
x = jnp.ones((256, 256))
jax.block_until_ready(jax.jit(lambda a: jnp.maximum(a @ a, 0.0).sum())(x))
"""


def our_command(seeds: int, steps: int, eval_every: int, learning_starts: int, exploration_steps: int) -> list[str]:
    """`mjxsuite train` with PureJaxRL's settings (the issue's command at the default sizes)."""
    c = OURS
    return ["train", "--env", "cartpole", "--seeds", str(seeds), "--steps", str(steps),
            "--num_envs", str(c.num_envs), "--batch_size", str(c.batch_size), "--buffer_size", str(c.buffer_size),
            "--hidden", ",".join(map(str, c.hidden)), "--learning_rate", str(c.learning_rate),
            "--learning_starts", str(learning_starts), "--exploration_steps", str(exploration_steps),
            "--target_update", c.target_update, "--target_period", str(c.target_period), "--max_grad_norm", "none",
            "--double_dqn", "false", "--eval_every", str(eval_every), "--no-compile-cache"]


def peer_config(seeds: int, steps: int, learning_starts: int, exploration_steps: int) -> dict:
    """The peer's config for the same work: its TARGET_UPDATE_INTERVAL counts env steps,
    our target_period updates (one per num_envs env steps)."""
    return {**PEER, "TOTAL_TIMESTEPS": steps, "NUM_SEEDS": seeds, "LEARNING_STARTS": learning_starts,
            "EPSILON_ANNEAL_TIME": exploration_steps,
            "TARGET_UPDATE_INTERVAL": OURS.target_period * OURS.num_envs * OURS.train_every}


def _environment() -> dict:
    """Fresh processes: no persistent compilation cache on either side; this checkout first on the path."""
    environ = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"}
    environ["MJXSUITE_COMPILE_CACHE"] = "0"
    environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    return environ


def _run(command: list[str], timeout: float) -> tuple[subprocess.CompletedProcess, float]:
    start = time.perf_counter()
    done = subprocess.run(command, env=_environment(), capture_output=True, text=True, timeout=timeout, cwd=ROOT)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command[:4])} ... exited {done.returncode}:\n{done.stderr[-3000:]}")
    return done, wall


def run_ours(args) -> dict:
    command = our_command(args.seeds, args.steps, args.eval_every, args.learning_starts, args.exploration_steps)
    done, wall = _run([sys.executable, "-m", "agents.cli", *command], args.timeout)
    returns = [float(m) for m in re.findall(r"greedy mean return (\S+) over", done.stdout)]
    last = done.stdout.strip().splitlines()[-1]  # "wall 12.3s = start-up 1.0 + compile 4.0 + ... s"
    parts = {name: float(seconds) for name, seconds in re.findall(r"([a-z-]+) ([0-9.]+)(?= \+| s)", last)}
    return {"lib": "mjxsuite", "command": "mjxsuite " + " ".join(command), "process_s": wall, "parts_s": parts,
            "solved": sum(r >= OURS.solve_return for r in returns), "agents": len(returns)}


def run_peer(args) -> dict:
    config = peer_config(args.seeds, args.steps, args.learning_starts, args.exploration_steps)
    done, wall = _run([sys.executable, "-c", _PEER_PROGRAM, str(args.peer), json.dumps(config)], args.timeout)
    return {"lib": "purejaxrl", "config": config, "process_s": wall, **json.loads(done.stdout.strip().splitlines()[-1])}


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--peer", required=True, type=Path, help="PureJaxRL's dqn.py (its make_train)")
    parser.add_argument("--seeds", type=int, default=2048)
    parser.add_argument("--steps", type=int, default=OURS.total_steps, help="env steps per agent")
    parser.add_argument("--eval-every", type=int, default=50_000)
    parser.add_argument("--learning-starts", type=int, default=OURS.learning_starts)
    parser.add_argument("--exploration-steps", type=int, default=OURS.exploration_steps)
    parser.add_argument("--peer-first", action="store_true", help="run the peer before ours")
    parser.add_argument("--no-warm-up", dest="warm_up", action="store_false",
                        help="skip the untimed warm-up process (libraries read and the device started once)")
    parser.add_argument("--timeout", type=float, default=540.0, help="seconds allowed to each process")
    parser.add_argument("--json", type=Path, help="also write the record here")
    args = parser.parse_args(argv)
    if not args.peer.is_file():
        parser.error(f"--peer {args.peer}: no such file (PureJaxRL's dqn.py, e.g. shared/peers/purejaxrl_dqn.py)")
    for name in ("seeds", "steps", "eval_every"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} {getattr(args, name)}: must be at least 1")
    if args.warm_up:
        _run([sys.executable, "-c", _WARM_UP_PROGRAM], args.timeout)
    runs = [run_peer, run_ours] if args.peer_first else [run_ours, run_peer]
    results = {run.__name__: run(args) for run in runs}
    ours, peer = results["run_ours"], results["run_peer"]
    record = {"kind": "end-to-end", "device": peer["device"], "seeds": args.seeds, "steps": args.steps,
              "ours": ours, "peer": peer, "ratio": peer["make_train_s"] / ours["process_s"],
              "order": "peer first" if args.peer_first else "ours first", "warm_up": args.warm_up}
    print(json.dumps(record, indent=1))
    if args.json:
        args.json.write_text(json.dumps(record, indent=1) + "\n")
    return record


if __name__ == "__main__":
    main()
