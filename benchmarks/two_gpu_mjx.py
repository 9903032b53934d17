"""The reproducer of the crash behind `agents.sharding.MJX_OVER_GPUS`: a batched MJX step
under `shard_map` over two devices, compiled by `jax.jit`. Each case runs in its own process
(a segmentation fault ends only it) with faulthandler on; the report is each case's exit
status (-11: the segfault) and where Python was.

    python -m benchmarks.two_gpu_mjx [--cases bare-step env-step env-reset] [--envs 64]

Cases: `bare-step` is `mujoco.mjx.step` on assets/cartpole.xml with nothing of ours (the one
to send upstream); `env-step` our `cartpole-mjx` reset and step (seen to crash, two H200s,
jax 0.11.2); `env-reset` its reset alone (seen to compile and run). On a CPU it runs on two
host devices (`--xla_force_host_platform_device_count=2`), where every case should pass.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import textwrap

PRELUDE = """
import faulthandler; faulthandler.enable()
import jax, jax.numpy as jnp, numpy as np
from jax.sharding import Mesh, PartitionSpec as P
mesh = Mesh(np.asarray(jax.devices()[:2]), ("batch",))
spread = lambda f: jax.jit(jax.shard_map(f, mesh=mesh, in_specs=P("batch"), out_specs=P("batch")))
print("devices:", jax.devices()[:2], flush=True)
"""

CASES = {
    "bare-step": """
        import mujoco
        from mujoco import mjx
        model = mjx.put_model(mujoco.MjModel.from_xml_path("assets/cartpole.xml"))
        def run(qpos):
            data = jax.vmap(lambda q: mjx.make_data(model).replace(qpos=q))(qpos)
            return jax.vmap(mjx.step, in_axes=(None, 0))(model, data).qpos
        print(spread(run)(jnp.zeros((NUM_ENVS, model.nq))).sum())
    """,
    "env-step": """
        import envs
        env = envs.make("cartpole-mjx")
        def run(keys):
            state = jax.vmap(env.reset)(keys)
            return jax.vmap(env.step)(state, jnp.zeros(keys.shape[0], jnp.int32)).obs
        print(spread(run)(jax.random.split(jax.random.PRNGKey(0), NUM_ENVS)).sum())
    """,
    "env-reset": """
        import envs
        env = envs.make("cartpole-mjx")
        print(spread(lambda keys: jax.vmap(env.reset)(keys).obs)(jax.random.split(jax.random.PRNGKey(0), NUM_ENVS)).sum())
    """,
}


def run_case(name: str, num_envs: int, timeout: float = 300.0) -> tuple[int | str, str]:
    """(exit status or "timeout", the case's output)."""
    code = PRELUDE + textwrap.dedent(CASES[name]).replace("NUM_ENVS", str(num_envs))
    env = dict(os.environ)
    env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=2").strip()
    try:
        done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, env=env)
        return done.returncode, done.stdout + done.stderr
    except subprocess.TimeoutExpired:
        return "timeout", ""


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", nargs="+", choices=list(CASES), default=list(CASES))
    parser.add_argument("--envs", type=int, default=64, help="batch size (even: split over two devices)")
    args = parser.parse_args(argv)
    for name in args.cases:
        status, output = run_case(name, args.envs)
        kept = [line for line in output.splitlines() if line.strip() and not line.startswith("Extension modules")]
        verdict = "segmentation fault" if status == -11 else ("ok" if status == 0 else f"exit status {status}")
        print(f"== {name}: {verdict}\n" + "\n".join(kept[-15:]), flush=True)


if __name__ == "__main__":
    main()
