"""The one place where the agents choose code and XLA options by device (JAX platform).

The CPU and accelerators want different shapes of the same computation: XLA:CPU runs
small sequential loops and one network at a time fastest, while on a GPU every loop
iteration launches kernels anew, so there one batched kernel beats a loop. The replay
choice computes the same values bit for bit either way; the optimizer, matmul and loop
choices round differently (`tests/test_dqn.py` says how). Why each choice, with the
measurements: docs/results.md, "DQN on the GPU".
"""

from __future__ import annotations

import functools
from typing import Any

import jax
import jax.numpy as jnp


def on_cpu(platform: str | None = None) -> bool:
    """Whether `platform` (default: JAX's default backend) is the CPU."""
    return (platform or jax.default_backend()) == "cpu"


def default_seed_axis(platform: str | None = None) -> str:
    """How `train_run` batches seeds (`agents.run.seed_batched`): one after another with
    `lax.map` on the CPU, vmapped elsewhere."""
    return "map" if on_cpu(platform) else "vmap"


def vectorized_replay(platform: str | None = None) -> bool:
    """Replay buffers read, write and update priorities with gathers and scatters
    (`agents.replay`'s `vectorized`) everywhere but on the CPU, which runs the loops faster."""
    return not on_cpu(platform)


def flat_optimizer(platform: str | None = None) -> bool:
    """Adam over the parameters flattened into one vector (`ravel_pytree`) on the CPU, where
    a few large elementwise kernels beat several small ones per leaf; per leaf elsewhere,
    where flattening the gradients costs two slow concatenation kernels per update."""
    return on_cpu(platform)


def batch_skips_idle_target_copies(platform: str | None = None) -> bool:
    """Whether a vmapped batch of agents with hard target updates skips the update's target
    select when no agent of the batch copies on it (`agents.dqn.copy_where`): elsewhere than
    on the CPU. The select reads and writes every agent's target network on every update, a
    fifth of the update's Adam fusion on a GPU (docs/bench-gpu.json, "dqn-target-copy"), to change
    it once in `target_period` updates; XLA:CPU runs a `lax.cond` slower than the select."""
    return not on_cpu(platform)


def unrolled_inner_loops(platform: str | None = None) -> bool:
    """Whether a training iteration's few env steps and gradient steps are unrolled rather
    than looped inside the chunk's loop: a GPU sat idle most of the time between looped
    updates, and unrolled they train faster (docs/results.md, "DQN on the GPU: what the profile
    showed"); the CPU keeps its loops (smaller programs)."""
    return not on_cpu(platform)


# Fewer agents than this on one device keep XLA's network: the fused kernels run one program
# per agent, so a few agents leave most of a GPU's multiprocessors idle: one agent ran slower fused,
# 16 the same, hundreds and thousands faster (docs/results.md, "DQN on the GPU").
FUSED_MIN_AGENTS = 128


def fused_q_network(platform: str | None = None, agents: int = 1) -> bool:
    """Whether the DQN update runs its Q-network as one Pallas kernel forward and one
    backward (`agents.fused_mlp`) rather than as XLA's per-layer matmuls: on a GPU, for
    `agents` vmapped on one device, at least `FUSED_MIN_AGENTS` of them; the activations
    then stay on chip (docs/results.md, "DQN on the GPU"). The CPU keeps XLA's program."""
    return not on_cpu(platform) and agents >= FUSED_MIN_AGENTS


def transposed_kernel_gradient(platform: str | None = None) -> bool:
    """The Q-network's Dense layers take their kernel gradient from an explicitly
    transposed input (`agents.networks`) on the CPU, whose XLA then uses its fast matmul;
    elsewhere the plain product."""
    return on_cpu(platform)


# XLA's default command buffers (CUDA graphs) cover runs of plain kernels, not the
# `while` loops and conditionals a training chunk is made of (its scan, the greedy
# evaluation episode), so on a GPU every iteration launched its small kernels one by
# one. WHILE and CONDITIONAL are added to XLA's default list: DQN then trains faster, and
# many seeds cost less beside one, to the same parameters (docs/bench-gpu.json,
# "dqn-command-buffers"). Set per program: env rollouts, which these loops would slow down,
# keep XLA's defaults.
GPU_COMMAND_BUFFERS = "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,DYNAMIC_SLICE_FUSION,WHILE,CONDITIONAL"

# Inside those graphs, kernels that do not depend on each other run at the same time. XLA's
# default (LHS) keeps a single-GPU program's kernels in a row, and most of a DQN iteration's ~50
# kernels are too small to fill a GPU alone (the Adam updates and gradient norms of each layer,
# the network's padded operands, acting): CONCURRENT shortens the default config's iteration, to
# the same parameters bit for bit, more than XLA's intermediate CONCURRENT_REGIONS does
# (docs/results.md, "Concurrent kernels"; docs/bench-gpu.json, "dqn-command-buffer-scheduling").
GPU_COMMAND_BUFFER_SCHEDULING = "CONCURRENT"


# XLA:CPU's newer fusion emitters (its default in jax 0.10) took twice the compile time of its
# classic ones for the DQN's training and evaluation programs, with no faster training
# (docs/results.md, "Compile time on the CPU"). They round a few operations differently.
# XLA has since retired its classic CPU emitters (openxla/xla#48001): jax 0.11's XLA:CPU refuses the
# option ("No such compile option"), so it is passed only where this XLA knows it (`cpu_accepts`).
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
    """XLA options for a run's init program, which runs once, so its compile is all that counts:
    no GEMM autotuning on a GPU (autotuning its one forward pass was most of its compile);
    LLVM's optimisation level 1 on the CPU (the init compiles in about half the time of XLA's
    default level, to the same values, beside the training chunk's trace). The CPU keeps XLA's
    default fusion emitters here: the classic ones compiled the init slower
    (docs/results.md, "Compile time on the CPU")."""
    platform = platform or jax.default_backend()
    if platform == "cpu":
        return known_cpu_options({"xla_backend_optimization_level": 1})
    if platform != "gpu":
        return {}
    return {"xla_gpu_autotune_level": 0}


def training_compiler_options(platform: str | None = None, env: Any = None) -> dict:
    """XLA options for the training programs: on a GPU, CUDA graphs for loops whose independent
    kernels run concurrently; on the CPU, XLA:CPU's classic fusion emitters
    (`CPU_COMPILER_OPTIONS`); nothing elsewhere.

    An env that renders camera frames with MuJoCo Warp (`env.warp_renders`, `envs.pixels`) keeps
    XLA's default CUDA graphs, a precaution (docs/mjx.md, "MuJoCo Warp and CUDA graphs"). Whether
    Warp's renderer runs inside WHILE graphs is not yet tried.

    GEMM autotuning stays on: turning it off (`xla_gpu_autotune_level` 0) halved the chunk's
    compile but cost a large part of the training speed (docs/results.md, "DQN on the GPU: what
    the profile showed")."""
    platform = platform or jax.default_backend()
    if platform == "cpu":
        return known_cpu_options(CPU_COMPILER_OPTIONS)
    if platform != "gpu" or getattr(env, "warp_renders", False):
        return {}
    return {"xla_gpu_enable_command_buffer": GPU_COMMAND_BUFFERS,
            "xla_gpu_command_buffer_scheduling_mode": GPU_COMMAND_BUFFER_SCHEDULING}


# ---- determinism ------------------------------------------------------------------------------
# XLA's GPU reductions (scatter-adds, some fusions) may add in a different order from run to run;
# this flag makes them deterministic, at a cost docs/reliability.md gives. XLA:CPU is deterministic.
DETERMINISTIC_XLA_FLAG = "--xla_gpu_deterministic_ops=true"


def make_deterministic() -> None:
    """Ask for bit-for-bit repeatable programs (`mjxsuite train --deterministic`): XLA's
    deterministic GPU ops. Must run before JAX starts its backends. MuJoCo Warp offers nothing
    that works here: Warp's own `DeterministicMode.RUN_TO_RUN` fails to compile MuJoCo Warp's
    kernels (a WarpDeterminismError in `_qLD_acc`, warp-lang 1.19 with mujoco-warp 4.0), so runs
    with impl="warp" stay non-deterministic (docs/reliability.md)."""
    import os

    from jax._src import xla_bridge

    if xla_bridge.backends_are_initialized():
        raise RuntimeError("make_deterministic() must run before JAX starts its backends (before the first "
                           "JAX computation); call it first, or set XLA_FLAGS=" + DETERMINISTIC_XLA_FLAG)
    flags = os.environ.get("XLA_FLAGS", "")
    if DETERMINISTIC_XLA_FLAG.split("=")[0] not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {DETERMINISTIC_XLA_FLAG}".strip()
