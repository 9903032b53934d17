"""How much of dm_control's cart-pole swing-up return any policy can earn: its first `--steps` control steps
trajectory-optimized, then replayed on dm_control's own env.

The return of an episode is at most the best sum of its first T rewards plus 1,000 - T (a reward is at most 1).
The best sum is searched by gradient ascent through MJX's differentiable step (`jax.grad` of the summed
rewards over open-loop actions tanh(logits); Adam; `--restarts` random starts), from states our reset draws
(dm_control's distribution). MJX's constraint solver loops while unconverged, which reverse-mode differentiation
refuses, so the search runs with constraints off (the rail's limits at +-1.8 m): a relaxation, whose best sum is
at least the constrained one's. The best actions are then replayed on dm_control's env (C MuJoCo, float64,
constraints on) from the same state, and dm_control's own rewards are summed. A local search: its figures are
evidence of the ceiling, not a bound proven. `--action_repeat K` holds each action for K control steps, as a policy
acting every K steps does (the pixel swing-up's 8).

    python -m benchmarks.swingup_ceiling [--steps 200] [--restarts 16] [--iterations 800] [--resets 2]
        [--action_repeat 1] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

TASK, EPISODE = "dmc-cartpole-swingup", 1000


def best_actions(env, state, steps: int, restarts: int, iterations: int, key: jax.Array, repeat: int = 1):
    """Gradient ascent on the sum of `steps` rewards from `state` over open-loop actions, each held `repeat`
    steps: every restart's final sum and (per-step) actions, and each restart's sum at every iteration."""
    import optax

    def summed(logits):
        def step(state, logit):
            state = env.step(state, jnp.tanh(logit))
            return state, state.reward
        return jax.lax.scan(step, state, jnp.repeat(logits, repeat, axis=0))[1].sum()

    optimizer = optax.chain(optax.clip_by_global_norm(10.0), optax.adam(0.05))

    def ascend(logits):
        def iteration(carry, _):
            logits, opt_state = carry
            value, grad = jax.value_and_grad(summed)(logits)
            updates, opt_state = optimizer.update(jax.tree.map(jnp.negative, grad), opt_state, logits)
            return (optax.apply_updates(logits, updates), opt_state), value
        (logits, _), values = jax.lax.scan(iteration, (logits, optimizer.init(logits)), None, iterations)
        return summed(logits), jnp.tanh(jnp.repeat(logits, repeat, axis=0)), values

    starts = jax.random.normal(key, (restarts, steps // repeat, env.action_size))
    return jax.jit(jax.vmap(ascend))(starts)


def dm_control_sum(state, actions: np.ndarray) -> float:
    """dm_control's own rewards summed over `actions`, from `state`'s positions and velocities."""
    import envs

    dm_env = envs.load_dm_control("cartpole", "swingup")
    dm_env.reset()
    physics = dm_env.physics
    with physics.reset_context():
        physics.data.qpos[:] = np.asarray(state.pipeline_state.qpos, np.float64)
        physics.data.qvel[:] = np.asarray(state.pipeline_state.qvel, np.float64)
    return float(sum(dm_env.step(action).reward for action in actions))


def measure(steps: int, restarts: int, iterations: int, resets: int, repeat: int = 1) -> dict:
    import mujoco

    import envs

    relaxed = envs.make(TASK, opt={"disableflags": int(mujoco.mjtDisableBit.mjDSBL_CONSTRAINT)}).unwrapped
    found = []
    for reset in range(resets):
        start = time.perf_counter()
        state = jax.jit(relaxed.reset)(jax.random.PRNGKey(reset))
        sums, actions, curve = jax.device_get(best_actions(relaxed, state, steps, restarts, iterations,
                                                           jax.random.PRNGKey(1000 + reset), repeat))
        best = int(np.argmax(sums))
        found.append({"reset_key": reset, "best_sum": float(sums[best]), "restart_sums": sorted(map(float, sums)),
                      "dm_control_sum": dm_control_sum(state, actions[best]),
                      "best_curve": [float(v) for v in curve[best, ::max(iterations // 10, 1)]],
                      "seconds": time.perf_counter() - start})
        print(json.dumps(found[-1]), flush=True)
    # An episode's return is at most this if the search found the best first `steps` (it may not have).
    bound = max(max(f["best_sum"], f["dm_control_sum"]) for f in found) + EPISODE - steps
    return {"kind": "swingup-ceiling", "env": TASK, "steps": steps, "action_repeat": repeat, "restarts": restarts,
            "iterations": iterations, "resets": found, "return_bound_if_search_optimal": bound, "jax": jax.__version__,
            "device": jax.devices()[0].device_kind}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.swingup_ceiling", description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="control steps optimized (the episode has 1,000)")
    parser.add_argument("--restarts", type=int, default=16)
    parser.add_argument("--iterations", type=int, default=800)
    parser.add_argument("--resets", type=int, default=2, help="initial states, drawn by reset keys 0, 1, ...")
    parser.add_argument("--action_repeat", type=int, default=1, help="control steps each action is held")
    parser.add_argument("--json", metavar="FILE", help="append the record to FILE (a JSON list)")
    args = parser.parse_args(argv)
    if not 0 < args.steps <= EPISODE:
        parser.error(f"--steps {args.steps}: optimize between 1 and {EPISODE} control steps")
    if args.action_repeat < 1 or args.steps % args.action_repeat:
        parser.error(f"--action_repeat {args.action_repeat}: give a divisor of --steps ({args.steps}), 1 or more")
    record = measure(args.steps, args.restarts, args.iterations, args.resets, args.action_repeat)
    print(json.dumps(record, indent=1), flush=True)
    if args.json:
        from benchmarks.suite import append_record

        append_record(args.json, record)


if __name__ == "__main__":
    main()
