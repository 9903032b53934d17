"""The one place where the agents choose code and XLA options by device (JAX platform): XLA:CPU runs
small loops fastest, a GPU one batched kernel. The replay choice gives the same values bit for bit;
the others round differently (`tests/test_dqn.py`). Measurements: docs/results.md, "DQN on the GPU"."""

from __future__ import annotations

import functools
import os
from typing import Any

import jax
import jax.numpy as jnp


def on_cpu(platform: str | None = None) -> bool:
    """Whether `platform` (default: JAX's default backend) is the CPU."""
    return (platform or jax.default_backend()) == "cpu"


def learns_from_images(learner: Any) -> bool:
    """Whether `learner` (an agent, or None) acts through image networks: a camera image's shape is set."""
    return getattr(learner, "image_shape", None) is not None


def default_seed_axis(platform: str | None = None, learner: Any = None) -> str:
    """Seeds vmapped, but mapped on the CPU and for image networks, whose vmapped convolutions a GPU groups slowly."""
    return "map" if on_cpu(platform) or learns_from_images(learner) else "vmap"


def judge_seed_axis(seed_axis: str, platform: str | None = None, learner: Any = None) -> str:
    """The judge's seeds: batched off the CPU even where image networks map the training's (`default_seed_axis`), so
    every seed's episodes step as one batch of envs, and the networks act one seed after another (`PPO.evaluate`)."""
    return "vmap" if learns_from_images(learner) and not on_cpu(platform) else seed_axis


def vectorized_replay(platform: str | None = None) -> bool:
    """Replay buffers use gathers and scatters (`agents.replay`'s `vectorized`) but on the CPU, which loops faster."""
    return not on_cpu(platform)


def flat_optimizer(platform: str | None = None) -> bool:
    """Adam over the parameters flattened into one vector on the CPU (fewer kernels); per leaf elsewhere."""
    return on_cpu(platform)


def batch_skips_idle_target_copies(platform: str | None = None) -> bool:
    """Whether vmapped agents skip the hard target update's select when none copies (`agents.dqn.copy_where`):
    not on the CPU, which runs a `lax.cond` slower (docs/bench-gpu.json, "dqn-target-copy")."""
    return not on_cpu(platform)


def unrolled_inner_loops(platform: str | None = None) -> bool:
    """Whether an iteration's few env and gradient steps are unrolled in the chunk's loop: not on the CPU."""
    return not on_cpu(platform)


# Fewer agents than this on one device keep XLA's network: the fused kernels run one program per
# agent, so a few agents leave most of a GPU idle (docs/results.md, "DQN on the GPU").
FUSED_MIN_AGENTS = 128


def fused_q_network(platform: str | None = None, agents: int = 1) -> bool:
    """Whether DQN's Q-network runs as Pallas kernels (`agents.fused_mlp`): on a GPU, for many vmapped agents."""
    return not on_cpu(platform) and agents >= FUSED_MIN_AGENTS


def transposed_kernel_gradient(platform: str | None = None) -> bool:
    """Dense kernel gradients from an explicitly transposed input on the CPU, for XLA's fast matmul."""
    return on_cpu(platform)


def canonical_conv_gradients(platform: str | None = None) -> bool:
    """Convolutions' gradients as canonical convolutions on the CPU (`agents.networks.canonical_conv`), for XLA's
    fast path inside loops; a GPU's convolution rewriter matches JAX's own."""
    return on_cpu(platform)


# XLA's default command buffers (CUDA graphs) plus WHILE and CONDITIONAL, for the training programs'
# loops only: env rollouts keep XLA's defaults (docs/bench-gpu.json, "dqn-command-buffers").
GPU_COMMAND_BUFFERS = "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,DYNAMIC_SLICE_FUSION,WHILE,CONDITIONAL"

# Independent kernels inside those graphs run at once, small as most are (docs/results.md, "Concurrent kernels").
GPU_COMMAND_BUFFER_SCHEDULING = "CONCURRENT"


# XLA:CPU's classic fusion emitters compile the training programs faster (docs/results.md, "Compile
# time on the CPU"); newer XLA has retired them (openxla/xla#48001), hence `known_cpu_options`.
CPU_COMPILER_OPTIONS = {"xla_cpu_use_fusion_emitters": False}


@functools.cache
def cpu_accepts(option: str, value: bool | int) -> bool:
    """Whether this jaxlib's XLA:CPU knows compile option `option` (a trivial program compiled with it)."""
    try:
        jax.jit(lambda x: x + 1).lower(jax.ShapeDtypeStruct((), jnp.float32)).compile({option: value})
    except Exception as err:  # jax's XlaRuntimeError: INVALID_ARGUMENT: No such compile option
        if "No such compile option" not in str(err):
            raise
        return False
    return True


def known_cpu_options(options: dict) -> dict:
    """`options` less those this XLA:CPU does not know."""
    return {name: value for name, value in options.items() if cpu_accepts(name, value)}


def init_compiler_options(platform: str | None = None) -> dict:
    """XLA options for the init program, which runs once: a quicker compile, to the same values."""
    platform = platform or jax.default_backend()
    if platform == "cpu":
        return known_cpu_options({"xla_backend_optimization_level": 1})
    return {"xla_gpu_autotune_level": 0} if platform == "gpu" else {}


def training_compiler_options(platform: str | None = None, env: Any = None) -> dict:
    """XLA options for the training programs: CUDA graphs of loops on a GPU (GEMM autotuning stays on: it
    buys speed), but XLA's defaults for an env that renders with MuJoCo Warp (docs/mjx.md, "MuJoCo Warp
    and CUDA graphs"); `CPU_COMPILER_OPTIONS` on the CPU."""
    platform = platform or jax.default_backend()
    if platform == "cpu":
        return known_cpu_options(CPU_COMPILER_OPTIONS)
    if platform != "gpu" or getattr(env, "warp_renders", False):
        return {}
    return {"xla_gpu_enable_command_buffer": GPU_COMMAND_BUFFERS,
            "xla_gpu_command_buffer_scheduling_mode": GPU_COMMAND_BUFFER_SCHEDULING}


# Fixes the order of XLA's GPU reductions from run to run (XLA:CPU's is fixed already).
DETERMINISTIC_XLA_FLAG = "--xla_gpu_deterministic_ops=true"


def make_deterministic() -> None:
    """XLA's deterministic GPU ops (`--deterministic`), before JAX starts its backends; impl="warp" stays
    non-deterministic (docs/reliability.md, "Determinism")."""
    from jax._src import xla_bridge

    if xla_bridge.backends_are_initialized():
        raise RuntimeError("make_deterministic() must run before JAX starts its backends (before the first "
                           "JAX computation); call it first, or set XLA_FLAGS=" + DETERMINISTIC_XLA_FLAG)
    flags = os.environ.get("XLA_FLAGS", "")
    if DETERMINISTIC_XLA_FLAG.split("=")[0] not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {DETERMINISTIC_XLA_FLAG}".strip()
