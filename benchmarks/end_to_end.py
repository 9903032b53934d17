"""What a user waits for, end to end: our whole `mjxsuite train` process against PureJaxRL's whole
process, for the same work, back to back on one device, in both orders.

The work is PureJaxRL's own DQN config (`benchmarks.dqn_peer.MATCHED["10 envs"]`: 10 envs per
agent, one update per 10 env steps, batch 128, buffer 10k, 120-84 network, lr 2.5e-4, a hard
target copy every 500 env steps, no gradient clipping, plain DQN) for `--seeds` agents and
`--steps` env steps each. Each side is one fresh process, timed from its start to its exit:

- ours: `mjxsuite train --env cartpole` with PureJaxRL's settings and otherwise the command's
  defaults, as a user runs it: `--out` (checkpoints, metrics, eval.json), the default greedy
  judge and save clocks, the final evaluation, and the persistent compilation cache on, in a
  fresh empty directory (a user's first run). Its last line's breakdown is kept;
- PureJaxRL's: a process that loads the peer file by path (`--peer`; never part of this
  package) and does what the file's own `main()` does: `jax.jit(jax.vmap(make_train(config)))`
  over `NUM_SEEDS` keys, waited for (its `main()` fixes `NUM_SEEDS` to 1, so the config is
  passed in rather than edited into a copy). It has no cache and no evaluation, as in the file.

`ratio` is PureJaxRL's process seconds over ours (> 1: ours finishes first), per order and over
both (the sums). With warm-ups (the default) an untimed process imports jax, Flax and Optax and
runs a small program on the device before every timed process, ours and the peer's alike, so
neither pays a freshly started machine's cold libraries and first GPU start; `--no-warm-up`
runs none.

On a GPU, the issue's comparison (2,048 agents, 500k steps each; a few minutes):

    python -m benchmarks.end_to_end --peer /path/to/purejaxrl_dqn.py --json e2e.json

On a CPU, the same at a tiny size (2 agents, 2,000 steps each): add `--tiny`.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from agents import processes
from agents.dqn import DQNConfig
from benchmarks.dqn_peer import MATCHED

OURS, PEER = MATCHED["10 envs"]
CHUNK_STEPS = DQNConfig().eval_every  # our command's default chunk: --steps must hold one
ROOT = Path(__file__).resolve().parents[1]
# --tiny: seeds, steps per agent, learning starts and exploration steps (the rest as PureJaxRL's).
TINY = {"seeds": 2, "steps": 2_000, "learning_starts": 200, "exploration_steps": 200}
ORDERS = {"ours first": ("ours", "peer"), "peer first": ("peer", "ours")}

# The peer's process: what its main() does, for the config given; one JSON line of its own timings.
_PEER_PROGRAM = """
import json, sys, time
start = time.perf_counter()
import jax
from benchmarks.dqn_peer import load_peer
config = json.loads(sys.argv[2])
make_train = load_peer(sys.argv[1])
rngs = jax.random.split(jax.random.PRNGKey(config["SEED"]), config["NUM_SEEDS"])
tick = time.perf_counter()
outs = jax.block_until_ready(jax.jit(jax.vmap(make_train(config)))(rngs))
done = time.perf_counter()
print(json.dumps({"startup_s": tick - start, "make_train_s": done - tick, "device": jax.devices()[0].device_kind}))
"""

# The untimed warm-up: the libraries both sides load, and a first program on the device.
_WARM_UP_PROGRAM = """
import jax, jax.numpy as jnp, flax, optax
x = jnp.ones((256, 256))
jax.block_until_ready(jax.jit(lambda a: jnp.maximum(a @ a, 0.0).sum())(x))
"""


def our_command(seeds: int, steps: int, learning_starts: int, exploration_steps: int, out: str | Path) -> list[str]:
    """`mjxsuite train` with PureJaxRL's settings, the command's defaults otherwise, and `--out`."""
    c = OURS
    return ["train", "--env", "cartpole", "--seeds", str(seeds), "--steps", str(steps),
            "--num_envs", str(c.num_envs), "--batch_size", str(c.batch_size), "--buffer_size", str(c.buffer_size),
            "--hidden", ",".join(map(str, c.hidden)), "--learning_rate", str(c.learning_rate),
            "--learning_starts", str(learning_starts), "--exploration_steps", str(exploration_steps),
            "--target_update", c.target_update, "--target_period", str(c.target_period), "--max_grad_norm", "none",
            "--double_dqn", "false", "--out", str(out), "--overwrite"]


def peer_config(seeds: int, steps: int, learning_starts: int, exploration_steps: int) -> dict:
    """The peer's config for the same work: its TARGET_UPDATE_INTERVAL counts env steps,
    our target_period updates (one per num_envs env steps)."""
    return {**PEER, "TOTAL_TIMESTEPS": steps, "NUM_SEEDS": seeds, "LEARNING_STARTS": learning_starts,
            "EPSILON_ANNEAL_TIME": exploration_steps,
            "TARGET_UPDATE_INTERVAL": OURS.target_period * OURS.num_envs * OURS.train_every}


def _environment(cache: Path | None = None) -> dict:
    """This checkout first on the path; ours gets `cache` as its compilation cache (fresh and empty)."""
    environ = {k: v for k, v in os.environ.items() if k not in ("JAX_COMPILATION_CACHE_DIR", "MJXSUITE_COMPILE_CACHE")}
    if cache is not None:
        environ["MJXSUITE_COMPILE_CACHE"] = str(cache)
    environ["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    return environ


def _run(command: list[str], timeout: float, environ: dict | None = None) -> tuple[subprocess.CompletedProcess, float]:
    start = time.perf_counter()
    done = subprocess.run(command, env=environ or _environment(), capture_output=True, text=True, timeout=timeout,
                          cwd=ROOT)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command[:4])} ... exited {done.returncode}:\n{done.stderr[-3000:]}")
    return done, wall


def wall_parts(last_line: str) -> dict[str, float]:
    """The breakdown of our command's last line: "wall 12.3s = start-up 1.0 + compile 4.0 + ... s; wrote DIR"."""
    return {name: float(seconds) for name, seconds in re.findall(r"([a-z-]+) ([0-9.]+)(?= \+| s)", last_line)}


def run_ours(args, work: Path) -> dict:
    out = work / "ours"
    command = our_command(args.seeds, args.steps, args.learning_starts, args.exploration_steps, out)
    done, wall = _run([*processes.MJXSUITE, *command], args.timeout,
                      _environment(cache=Path(tempfile.mkdtemp(prefix="jax-cache-", dir=work))))
    summary = json.loads((out / "eval.json").read_text())
    parts = wall_parts(done.stdout.strip().splitlines()[-1])
    overhead = parts.get("judge", 0.0) + parts.get("saves", 0.0)
    return {"lib": "mjxsuite", "command": "mjxsuite " + " ".join(command), "process_s": wall, "parts_s": parts,
            "judge_and_saves_share": overhead / wall, "judged_chunks": summary.get("judged_chunks"),
            "chunks": summary.get("chunks"), "agents": len(summary["mean_return"]),
            "solved": sum(r >= OURS.solve_return for r in summary["mean_return"])}


def run_peer(args, work: Path) -> dict:
    config = peer_config(args.seeds, args.steps, args.learning_starts, args.exploration_steps)
    done, wall = _run([sys.executable, "-c", _PEER_PROGRAM, str(args.peer), json.dumps(config)], args.timeout)
    return {"lib": "purejaxrl", "config": config, "process_s": wall, **json.loads(done.stdout.strip().splitlines()[-1])}


def compare(args, runners: dict | None = None) -> dict:
    """Both sides in each order of `args.orders`, each timed process after its own warm-up (or none)."""
    runners = runners or {"ours": run_ours, "peer": run_peer}
    rounds = []
    with tempfile.TemporaryDirectory(prefix="end-to-end-") as tmp:
        for order in args.orders:
            found = {}
            for side in ORDERS[order]:
                if args.warm_up:
                    _run([sys.executable, "-c", _WARM_UP_PROGRAM], args.timeout)
                found[side] = runners[side](args, Path(tmp))
            rounds.append({"order": order, **found, "ratio": found["peer"]["process_s"] / found["ours"]["process_s"]})
    ours_s, peer_s = (sum(r[side]["process_s"] for r in rounds) for side in ("ours", "peer"))
    return {"kind": "end-to-end", "device": rounds[0]["peer"].get("device"), "seeds": args.seeds, "steps": args.steps,
            "tiny": args.tiny, "warm_up": "before every process" if args.warm_up else "none", "rounds": rounds,
            "ours_process_s": ours_s, "peer_process_s": peer_s, "ratio": peer_s / ours_s}


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--peer", required=True, type=Path, help="PureJaxRL's dqn.py (its make_train)")
    parser.add_argument("--tiny", action="store_true",
                        help=f"a CPU-sized run: {TINY['seeds']} agents, {TINY['steps']:,} steps each (what --seeds, "
                             "--steps, --learning-starts and --exploration-steps set, unless given)")
    parser.add_argument("--seeds", type=int, help="agents (default 2,048)")
    parser.add_argument("--steps", type=int, help=f"env steps per agent (default {OURS.total_steps:,})")
    parser.add_argument("--learning-starts", type=int, help=f"default {OURS.learning_starts:,}")
    parser.add_argument("--exploration-steps", type=int, help=f"default {OURS.exploration_steps:,}")
    parser.add_argument("--orders", nargs="+", choices=list(ORDERS), default=list(ORDERS),
                        help="which side runs first, each order a round (default: both)")
    parser.add_argument("--no-warm-up", dest="warm_up", action="store_false",
                        help="no untimed warm-up process before each timed one (default: one before every process)")
    parser.add_argument("--timeout", type=float, default=900.0, help="seconds allowed to each process")
    parser.add_argument("--json", type=Path, help="also write the record here")
    args = parser.parse_args(argv)
    full = {"seeds": 2048, "steps": OURS.total_steps, "learning_starts": OURS.learning_starts,
            "exploration_steps": OURS.exploration_steps}
    for name, value in (TINY if args.tiny else full).items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    if not args.peer.is_file():
        parser.error(f"--peer {args.peer}: no such file (PureJaxRL's dqn.py, e.g. shared/peers/purejaxrl_dqn.py)")
    for name in ("seeds", "steps"):
        if getattr(args, name) < 1:
            parser.error(f"--{name} {getattr(args, name)}: must be at least 1")
    if args.steps < CHUNK_STEPS:
        parser.error(f"--steps {args.steps}: ours trains in chunks of eval_every ({CHUNK_STEPS}) steps; "
                     f"give at least {CHUNK_STEPS}")
    return args


def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    record = compare(args)
    print(json.dumps(record, indent=1))
    if args.json:
        args.json.write_text(json.dumps(record, indent=1) + "\n")
    return record


if __name__ == "__main__":
    main()
