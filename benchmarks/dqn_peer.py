"""Our DQN beside a PureJaxRL-style DQN, in one process, at matched configs.

    mjxsuite bench --sections dqn --peer-dqn ../shared/peers/purejaxrl_dqn.py

The peer is loaded from the file given (its `make_train(config)`; it is never part of
this package) and needs gymnax and flashbax. Two matched configs, each for 1, 16, 256
and 2048 seeds:

- `1 env`: one env per agent and one update per env step, our default `DQNConfig`; the
  peer with the same buffer (50k), batch (64), learning rate, Polyak tau (0.01, every
  step) and epsilon schedule, and its own 120-84 network.
- `10 envs`: PureJaxRL's own config (10 envs per agent, one update per 10 env steps,
  batch 128, buffer 10k, 120-84 network, lr 2.5e-4, hard target copy every 500 env
  steps, no gradient clipping, plain DQN), and ours set the same way. Ours evaluates
  every 10,000 env steps (64 greedy episodes), the peer never.

Throughput, compile excluded, both synchronised with `block_until_ready`: ours from
training chunks after the first (the median of `chunks`, as `train_run` runs them, with
their greedy evaluation); the peer from whole runs (median of 3) with learning from its
first sampleable step, so the run is all steady state, like our chunks after the first.
The two alternate config by config and seed count by seed count.
"""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import jax
import numpy as np

from benchmarks.dqn import throughput_record
from agents.device_options import default_seed_axis
from agents.dqn import DQNConfig

SEEDS = (1, 16, 256, 2048)

_PEER_COMMON = {"EPSILON_START": 1.0, "EPSILON_FINISH": 0.05, "GAMMA": 0.99, "LR_LINEAR_DECAY": False,
                "ENV_NAME": "CartPole-v1", "SEED": 0, "WANDB_MODE": "disabled", "ENTITY": "", "PROJECT": "",
                "LEARNING_STARTS": 0}
MATCHED = {
    "1 env": (
        DQNConfig(),
        {**_PEER_COMMON, "NUM_ENVS": 1, "TRAINING_INTERVAL": 1, "BUFFER_SIZE": 50_000, "BUFFER_BATCH_SIZE": 64,
         "EPSILON_ANNEAL_TIME": 5_000, "TARGET_UPDATE_INTERVAL": 1, "TAU": 0.01, "LR": DQNConfig().learning_rate},
    ),
    "10 envs": (
        DQNConfig(num_envs=10, batch_size=128, buffer_size=10_000, hidden=(120, 84), learning_rate=2.5e-4,
                  learning_starts=10_000, exploration_steps=250_000, target_update="hard", target_period=50,
                  max_grad_norm=None, double_dqn=False, eval_every=10_000, total_steps=500_000),
        {**_PEER_COMMON, "NUM_ENVS": 10, "TRAINING_INTERVAL": 10, "BUFFER_SIZE": 10_000, "BUFFER_BATCH_SIZE": 128,
         "EPSILON_ANNEAL_TIME": 250_000, "TARGET_UPDATE_INTERVAL": 500, "TAU": 1.0, "LR": 2.5e-4},
    ),
}


def peer_seeds(quick: bool) -> tuple[int, ...]:
    """Seed counts to compare: all of `SEEDS` on accelerators; 1 and 16 on the CPU (one with --quick)."""
    if quick:
        return (1,)
    return SEEDS if default_seed_axis() == "vmap" else (1, 16)


def load_peer(path: str | Path):
    """`make_train` from a PureJaxRL-style file; ImportError (with the reason) if it cannot load."""
    path = Path(path)
    if not path.is_file():
        raise ImportError(f"--peer-dqn {path}: no such file")
    spec = importlib.util.spec_from_file_location("peer_dqn", path)
    module = importlib.util.module_from_spec(spec)
    try:
        spec.loader.exec_module(module)
    except ImportError as err:
        raise ImportError(f"the peer {path.name} needs {err.name or err} (pip install gymnax==1.0.1 flashbax==0.1.3 six)")
    if not hasattr(module, "make_train"):
        raise ImportError(f"{path} defines no make_train(config)")
    return module.make_train


def peer_record(make_train, name: str, config: dict, seeds: int, iterations: int, repeats: int = 3) -> dict:
    config = {**config, "TOTAL_TIMESTEPS": iterations * config["NUM_ENVS"], "NUM_SEEDS": seeds}
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    start = time.perf_counter()
    train = jax.jit(jax.vmap(make_train(dict(config)))).lower(keys).compile()
    compile_s = time.perf_counter() - start
    jax.block_until_ready(train(keys))
    times = []
    for _ in range(repeats):
        tick = time.perf_counter()
        jax.block_until_ready(train(keys))
        times.append(time.perf_counter() - tick)
    steps_per_s = iterations * config["NUM_ENVS"] * seeds / float(np.median(times))
    return {"lib": "purejaxrl", "kind": "dqn-peer", "config": name, "env": "gymnax CartPole-v1", "seeds": seeds,
            "device": jax.devices()[0].device_kind, "compile_s": compile_s, "steps_per_s": steps_per_s,
            "updates_per_s": steps_per_s / config["TRAINING_INTERVAL"]}


def peer_dqn_records(peer_path: str | Path | None, seeds=SEEDS, configs=tuple(MATCHED), chunks: int = 3,
                     print_rows: bool = True) -> list[dict]:
    """Ours and the peer's throughput rows, then one ratio row per config and seed count.
    Without `peer_path`, or when the peer cannot load, one skipped record says why."""
    try:
        if peer_path is None:
            raise ImportError("no --peer-dqn FILE given (a PureJaxRL-style dqn.py with make_train)")
        make_train = load_peer(peer_path)
    except ImportError as err:
        if print_rows:
            print(f"   peer DQN skipped: {err}")
        return [{"kind": "dqn-peer", "lib": "purejaxrl", "skipped": str(err)}]
    records = []
    for name in configs:
        ours_config, peer_config = MATCHED[name]
        for n in seeds:
            ours = throughput_record("cartpole", n, ours_config, chunks=chunks)
            ours.update(kind="dqn-peer", config=name)
            peer = peer_record(make_train, name, peer_config, n, iterations=ours_config.iterations_per_chunk * 2)
            ratio = {"lib": "mjxsuite", "kind": "dqn-peer-ratio", "config": name, "seeds": n, "device": ours["device"],
                     "ratio": ours["steps_per_s"] / peer["steps_per_s"]}
            records += [ours, peer, ratio]
            if print_rows:
                print(f"   {name:>7}, {n:>4} seeds: ours {ours['steps_per_s']:>12,.0f} env-steps/s, PureJaxRL "
                      f"{peer['steps_per_s']:>12,.0f}: {ratio['ratio']:.2f}x", flush=True)
    return records

