"""What convolutions' gradients in a loop cost XLA:CPU, with JAX's own and with `agents.networks.canonical_conv`
(TD3's and PPO's choice on the CPU: `agents.device_options.canonical_conv_gradients`), both in one process: gradient
steps in a `lax.scan` of DrQ-v2's encoder and of PPO's vision value network (Brax's, through
`agents.networks.canonical_convs`), and TD3's update from camera images (its `num_updates` steps are a scan).

    python -m benchmarks.conv_gradients [--json FILE]
"""

from __future__ import annotations

import argparse
import json

import jax
import jax.numpy as jnp

from benchmarks.suite import append_record, timed_program

STEPS = 4  # gradient steps in the scan
TASK, IMAGE = "dmc-cartpole-balance", 32  # the update's env: dm_control's pixels at IMAGE x IMAGE
UPDATE = dict(num_envs=16, batch_size=128, num_updates=4, actor_hidden=(256, 256), critic_hidden=(256, 256),
              compute_dtype="float32", max_replay_size=50_000, min_replay_size=512)


def _timed(program, *args) -> dict:
    first, seconds = timed_program(program, *args)
    return {"compile_and_first_s": first, "seconds": seconds}


def _gradient_steps(loss, params) -> dict:
    """`STEPS` plain gradient steps on `loss` in a `lax.scan`, timed."""
    step = lambda p, _: (jax.tree.map(lambda w, g: w - 1e-3 * g, p, jax.grad(loss)(p)), None)
    return _timed(jax.jit(lambda p: jax.lax.scan(step, p, None, length=STEPS)[0]), params)


def encoder_steps(canonical: bool, batch: int, size: int) -> dict:
    from agents.td3_inputs import Encoder
    encoder = Encoder(canonical_gradients=canonical)
    frames = jax.random.randint(jax.random.PRNGKey(0), (batch, size, size, 9), 0, 256).astype(jnp.uint8)
    params = encoder.init(jax.random.PRNGKey(1), frames)
    return _gradient_steps(lambda p: jnp.square(encoder.apply(p, frames)).mean(), params)


def ppo_value_steps(canonical: bool, batch: int, size: int) -> dict:
    from agents.ppo import PPOConfig, make_vision_networks
    value = make_vision_networks((size, size, 3), 1, PPOConfig(), canonical).value_network
    frames = jax.random.randint(jax.random.PRNGKey(0), (batch, size, size, 3), 0, 256).astype(jnp.uint8)
    return _gradient_steps(lambda p: jnp.square(value.apply(None, p, frames)).mean(), value.init(jax.random.PRNGKey(1)))


def td3_updates() -> dict:
    """One TD3 update from camera images both ways, from one train state."""
    import envs
    from agents import brax_defaults, device_options
    from agents.td3 import TD3, TD3Config
    config = TD3Config(**{**brax_defaults.settings(TASK, "td3", "pixels"), **UPDATE})
    env = envs.make(TASK, observation="pixels", width=IMAGE, height=IMAGE)
    chosen, timed, ts = device_options.canonical_conv_gradients, {}, None
    try:
        for canonical in (False, True):
            device_options.canonical_conv_gradients = lambda platform=None, canonical=canonical: canonical
            td3 = TD3(config, env)
            ts = jax.jit(td3.init)(jax.random.PRNGKey(0)) if ts is None else ts
            timed[canonical] = _timed(jax.jit(td3.update), ts, jax.random.PRNGKey(1), jnp.int32(0))
    finally:
        device_options.canonical_conv_gradients = chosen
    return timed


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(prog="python -m benchmarks.conv_gradients", description=__doc__.splitlines()[0])
    parser.add_argument("--json", metavar="FILE", help="append the record to FILE (a JSON list)")
    args = parser.parse_args(argv)
    parts = {f"encoder, {STEPS} steps, batch {b} of {s}x{s}x9": {c: encoder_steps(c, b, s) for c in (False, True)}
             for b, s in ((128, 32), (32, 84))}
    ppo = {canonical: ppo_value_steps(canonical, 256, 64) for canonical in (False, True)}
    parts[f"PPO value network, {STEPS} steps, batch 256 of 64x64x3"] = ppo
    parts[f"TD3 update ({UPDATE['num_updates']} steps), {TASK} {IMAGE}x{IMAGE} pixels"] = td3_updates()
    record = {"kind": "conv-gradients", "device": jax.devices()[0].device_kind, "jax": jax.__version__,
              "parts": {name: {"jax_s": t[False]["seconds"], "canonical_s": t[True]["seconds"],
                               "speedup": t[False]["seconds"] / t[True]["seconds"],
                               "compile_and_first_s": {"jax": t[False]["compile_and_first_s"],
                                                       "canonical": t[True]["compile_and_first_s"]}}
                        for name, t in parts.items()}}
    print(json.dumps(record, indent=1), flush=True)
    if args.json:
        append_record(args.json, record)


if __name__ == "__main__":
    main()
