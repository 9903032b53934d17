"""How close the DQN's network programs are to their memory-traffic floor (issue #14).

For one of `benchmarks.dqn_peer.MATCHED`'s configs (default: PureJaxRL's own, 10 envs per
agent, 120-84 network, batch 128) and `--agents` vmapped agents on one device, each
network program of one training iteration is compiled and timed alone:

- `act forward`: Q-values of the `num_envs` current observations;
- `target forward`: the target network on the replayed batch's next observations;
- `update forward+backward`: the gradient of the loss on the replayed batch;
- `adam`: Adam's direction from those gradients, applied to the parameters.

Each is timed as 20 calls chained in one jitted program (Python's dispatch left out), and
for comparison one call at a time.
Beside each time: XLA's own count of the bytes its compiled program reads and writes
(`cost_analysis()["bytes accessed"]`, the operands and outputs of every kernel) and
those bytes at the device's streaming bandwidth (`x * 2 + 1` over `--stream-mib`, measured
in the same run). The compiled program cannot run faster than that floor; a faster one
has to move fewer bytes (for the network: keep the activations on chip). Where the
update runs `agents.fused_mlp`'s kernels (`fused_network`), XLA cannot see inside them
and its count leaves their own traffic out.

    python -m benchmarks.network_traffic [--config "10 envs"] [--agents 2048] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import jax
import jax.numpy as jnp

import envs
from agents.dqn import DQN, Transition
from benchmarks.dqn_peer import MATCHED
from benchmarks.env_throughput import device_name
from benchmarks.replay import median_time


def median_us(fn, *args, calls: int = 30, repeats: int = 5) -> float:
    """Median over `repeats` of the mean time of `calls` back-to-back calls, after a warm-up."""

    def back_to_back():
        for _ in range(calls):
            out = fn(*args)
        jax.block_until_ready(out)

    return median_time(back_to_back, repeats) / calls * 1e6


def chained_us(fn, next_args, args, calls: int = 20) -> float:
    """Device time of one call of `fn`: `calls` calls in one jitted program, each one's
    arguments `next_args(args, output, zero)` of the one before (`zero` is a traced 0, so
    no call can be hoisted or merged with another; `next_args` puts what changes through an
    optimization barrier, so XLA cannot fuse one call's kernels into the next's) and every
    output returned (so none can be dropped), so Python's dispatch of each call is not timed."""

    @jax.jit
    def run(args, zero):
        outputs = []
        for _ in range(calls):
            outputs.append(fn(*args))
            args = next_args(args, outputs[-1], zero)
        return outputs

    return median_us(run, args, jnp.zeros((), jnp.float32), calls=3) / calls


def bytes_and_flops(compiled) -> tuple[float, float]:
    cost = compiled.cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost  # a list of one in older JAX
    return float(cost["bytes accessed"]), float(cost.get("flops", float("nan")))


def stream_bandwidth(mib: int) -> float:
    """Bytes per second of `x * 2 + 1` over `mib` MiB of float32 (one read, one write)."""
    x = jnp.ones((mib * 2**20 // 4,), jnp.float32)
    us = median_us(jax.jit(lambda x: x * 2.0 + 1.0), x, calls=10)
    return 2 * x.nbytes / (us * 1e-6)


def programs(config_name: str, agents: int) -> tuple[DQN, dict]:
    """The DQN of `config_name` and its network programs: for each, a vmap over agents, its
    example arguments, and how the next call's arguments follow from a call's output (a
    forward's Q-values nudge its observations, the update's TD errors its replayed
    observations, each by `zero` times a value; Adam's step takes its own new state and parameters)."""
    config = MATCHED[config_name][0]
    dqn = DQN(config, envs.make("cartpole"), agents=agents)
    key = jax.random.PRNGKey(0)
    obs_size, batch = dqn.env.observation_size, config.batch_size
    params = jax.vmap(lambda k: dqn.network.init(k, jnp.zeros((1, obs_size))))(jax.random.split(key, agents))
    replayed = Transition(
        obs=jax.random.normal(key, (agents, batch, obs_size)),
        action=jax.random.randint(key, (agents, batch), 0, dqn.env.num_actions),
        reward=jnp.ones((agents, batch)),
        next_obs=jax.random.normal(jax.random.PRNGKey(1), (agents, batch, obs_size)),
        terminated=jnp.zeros((agents, batch)),
    )
    targets, weights = jnp.zeros((agents, batch)), jnp.ones((agents, batch))
    current_obs = jax.random.normal(key, (agents, config.num_envs, obs_size))
    grads = jax.vmap(jax.grad(dqn.loss, has_aux=True))(params, replayed, targets, weights)[0]

    def adam_step(grads, opt_state, params):
        direction, opt_state = dqn.optimizer.update(grads, opt_state, params)
        return jax.tree.map(lambda p, d: p + dqn.hyper.neg_learning_rate * d, params, direction), opt_state

    def nudge_obs(args, q_values, zero):
        return args[0], jax.lax.optimization_barrier(args[1] + zero * q_values[..., :1])

    def nudge_replayed_obs(args, grads_and_aux, zero):
        params, batch, targets, weights = args
        td_error = grads_and_aux[1][0]
        obs = jax.lax.optimization_barrier(batch.obs + zero * td_error[..., None])
        return params, batch._replace(obs=obs), targets, weights

    def adam_next(args, out, zero):
        params, opt_state = jax.lax.optimization_barrier(out)
        return args[0], opt_state, params

    found = {
        "act forward": (jax.vmap(dqn.q_values), (params, current_obs), nudge_obs),
        "target forward": (jax.vmap(dqn.batch_q_values), (params, replayed.next_obs), nudge_obs),
        "update forward+backward": (jax.vmap(jax.grad(dqn.loss, has_aux=True)),
                                    (params, replayed, targets, weights), nudge_replayed_obs),
        "adam": (jax.vmap(adam_step), (grads, jax.vmap(dqn.optimizer.init)(params), params), adam_next),
    }
    return dqn, found


def records(config_name: str = "10 envs", agents: int = 2048, stream_mib: int = 2048) -> list[dict]:
    bandwidth = stream_bandwidth(stream_mib)
    dqn, found = programs(config_name, agents)
    common = {"kind": "network-traffic", "lib": "mjxsuite", "device": device_name(), "config": config_name,
              "agents": agents, "hidden": list(dqn.config.hidden), "fused_network": dqn.fused_network}
    rows = [{**common, "program": "stream x * 2 + 1", "stream_mib": stream_mib, "bytes_per_s": bandwidth}]
    for name, (fn, args, next_args) in found.items():
        us = chained_us(fn, next_args, args)
        compiled = jax.jit(fn).lower(*args).compile()
        one_call_us = median_us(compiled, *args)  # dispatched from Python, call by call
        accessed, flops = bytes_and_flops(compiled)
        rows.append({**common, "program": name, "us": us, "one_call_us": one_call_us,
                     "bytes_accessed": accessed, "flops": flops,
                     "floor_us": accessed / bandwidth * 1e6})
    return rows


def table(rows: list[dict]) -> str:
    stream = next(r for r in rows if r["program"].startswith("stream"))
    lines = [f"{stream['device']}, {stream['config']} ({'-'.join(map(str, stream['hidden']))} network), "
             f"{stream['agents']:,} agents; streaming bandwidth {stream['bytes_per_s'] / 1e9:,.0f} GB/s",
             "", "| program | µs | µs, one call at a time | MB accessed (XLA) | floor at that bandwidth, µs | floor / time |",
             "|---|---:|---:|---:|---:|---:|"]
    timed = [r for r in rows if "us" in r]
    for r in timed:
        lines.append(f"| {r['program']} | {r['us']:,.0f} | {r['one_call_us']:,.0f} | {r['bytes_accessed'] / 1e6:,.0f} | "
                     f"{r['floor_us']:,.0f} | {r['floor_us'] / r['us']:.0%} |")
    lines.append(f"| all | {sum(r['us'] for r in timed):,.0f} | | {sum(r['bytes_accessed'] for r in timed) / 1e6:,.0f} | "
                 f"{sum(r['floor_us'] for r in timed):,.0f} | |")
    if stream["fused_network"]:
        lines.append("\nThe update runs agents.fused_mlp's kernels here: XLA's byte counts leave their traffic out.")
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.network_traffic", description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="10 envs", choices=tuple(MATCHED), help="a matched config of benchmarks.dqn_peer")
    parser.add_argument("--agents", type=int, default=2048, help="agents vmapped on one device")
    parser.add_argument("--stream-mib", type=int, default=2048, help="MiB streamed to measure the bandwidth")
    parser.add_argument("--json", metavar="FILE", help="write the records as JSON")
    args = parser.parse_args(argv)
    if args.agents < 1 or args.stream_mib < 1:
        parser.error(f"--agents {args.agents} / --stream-mib {args.stream_mib}: both must be at least 1")
    rows = records(args.config, args.agents, args.stream_mib)
    print(table(rows))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=2)


if __name__ == "__main__":
    main()
