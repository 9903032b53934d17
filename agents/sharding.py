"""Spreading a run's agents (seeds, a sweep's configs times seeds) over devices and hosts: a 1-D mesh over
the agent axis, each device running its share by `shard_map`, with no collectives (agents never talk).
Across hosts `to_host` gathers the agents and process 0 alone writes (`is_writer`).
"""

from __future__ import annotations

import os
import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "agents"
DISTRIBUTED_ENV = "MJXSUITE_DISTRIBUTED"


def initialize_distributed() -> None:
    """Join a multi-host run (before any JAX computation); beside what JAX reads or detects itself,
    JAX_NUM_PROCESSES and JAX_PROCESS_ID give the count and index."""
    count, index = os.environ.get("JAX_NUM_PROCESSES"), os.environ.get("JAX_PROCESS_ID")
    try:
        jax.distributed.initialize(num_processes=int(count) if count else None,
                                   process_id=int(index) if index else None)
    except ValueError as err:
        raise ValueError(f"--distributed: jax.distributed.initialize failed ({err}); set JAX_COORDINATOR_ADDRESS "
                         "(host:port of process 0), JAX_NUM_PROCESSES and JAX_PROCESS_ID on every process, "
                         "or run under a cluster manager JAX detects (SLURM, Open MPI)") from err


def is_writer() -> bool:
    """Whether this process writes files and progress: process 0, or the only process."""
    return jax.process_index() == 0


# XLA's GPU compiler segfaults on a batched MJX step under shard_map over GPUs (docs/upstream-two-gpu-mjx.md),
# so `mjxsuite train` spreads an MJX task's seeds as one process per GPU (`agents.processes`).
MJX_OVER_GPUS = ("an MJX task's step, spread over several GPUs in one program, crashes XLA's GPU compiler "
                 "(a segmentation fault; docs/scaling.md), so an MJX task takes one GPU per process: "
                 "`mjxsuite train` starts one process per GPU")


def choose_devices(seeds: int, devices: int | None = None, configs: int = 1, mjx_task: str | None = None) -> list:
    """The devices for `configs` x `seeds` agents: every device of every process in a multi-host run;
    on one host `devices` local ones (None: the most that split the agents evenly). ValueError when
    they do not split, naming the --seeds that would. An MJX task (`mjx_task`, its name) stays on one
    GPU (`MJX_OVER_GPUS`): with a warning by default, refused when asked for more."""
    multi_host = jax.process_count() > 1
    available = jax.devices() if multi_host else jax.local_devices()
    agents = configs * seeds
    if mjx_task and len(available) > 1 and available[0].platform == "gpu":
        if multi_host or (devices or 1) > 1:
            asked = "a multi-host run" if multi_host else f"--devices {devices}"
            raise ValueError(f"{asked}: {MJX_OVER_GPUS}; {mjx_task} trains on one GPU per process: use "
                             "--devices 1, or `mjxsuite train` (not sweep) for one process per GPU")
        if devices is None:
            warnings.warn(f"{mjx_task}: training on 1 of {len(available)} GPUs: {MJX_OVER_GPUS} (a sweep, or "
                          "train_run called directly, runs in this one)", stacklevel=2)
            devices = 1

    def splitting(count: int) -> list[int]:  # device counts up to `count` that split the agents evenly
        return [k for k in range(1, count + 1) if agents % k == 0]

    if devices is None:
        devices = len(available) if multi_host else max(splitting(len(available)))
    elif multi_host and devices != len(available):
        raise ValueError(f"--devices {devices}: a multi-host run uses every device of every process "
                         f"({len(available)}); drop --devices")
    elif not 1 <= devices <= len(available):
        raise ValueError(f"--devices must be between 1 and the {len(available)} local devices, got {devices}")
    if agents % devices:
        what = f"{seeds} seeds" if configs == 1 else f"{configs} configs x {seeds} seeds"
        fix = seeds_that_split(seeds, devices, configs)
        if not multi_host:
            fix += f", or --devices {max(splitting(devices))}"
        raise ValueError(f"{what} do not split evenly over {devices} devices: use {fix}")
    return available[:devices]


def seeds_that_split(seeds: int, parts: int, configs: int = 1) -> str:
    """The two --seeds nearest `seeds` whose agents split evenly into `parts`, e.g. "--seeds 4 or 8"."""
    fitting = [n for n in range(1, 2 * seeds + parts + 1) if configs * n % parts == 0]
    near = sorted(fitting, key=lambda n: abs(n - seeds))[:2]
    return f"--seeds {' or '.join(map(str, sorted(near)))}"


class Placement:
    """Where a run's agents live: on one device `mesh` is None and every method leaves programs and
    arrays as they are; on several, a 1-D mesh over the agent axis."""

    def __init__(self, devices: list):
        self.devices = list(devices)
        self.mesh = Mesh(np.asarray(self.devices), (AXIS,)) if len(self.devices) > 1 else None
        self.sharding = None if self.mesh is None else NamedSharding(self.mesh, PartitionSpec(AXIS))  # agent axis split

    @property
    def count(self) -> int:
        return len(self.devices)

    def spread(self, fn: Callable) -> Callable:
        """`fn` (over a leading agent axis, for `agents / count` agents) run on every device's share."""
        if self.mesh is None:
            return fn
        spec = PartitionSpec(AXIS)
        # check_vma off: everything is split along the agent axis, nothing replicated, nothing to check
        return jax.shard_map(fn, mesh=self.mesh, in_specs=spec, out_specs=spec, check_vma=False)

    def abstract(self, tree: Any) -> Any:
        """`tree`'s shapes and dtypes (weak types kept), split as `put` splits arrays: what a program
        is compiled for before its arrays exist."""
        return jax.tree.map(lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype, weak_type=jax.typeof(x).weak_type,
                                                           sharding=self.sharding), tree)

    def put(self, tree: Any) -> Any:
        """Host arrays with a leading agent axis, split over the mesh (each process places its own slices)."""
        if self.mesh is None:
            return tree
        leaves, treedef = jax.tree.flatten(tree)
        leaves = [np.asarray(x) for x in leaves]
        slices = [self.sharding.addressable_devices_indices_map(x.shape) for x in leaves]
        local = list(slices[0]) if leaves else []

        def place_on(device):  # every leaf's slice for one device
            return [jax.device_put(x[where[device]], device) for x, where in zip(leaves, slices)]

        # One thread per device: the first placement reserves each GPU's memory, at once this way
        # (docs/bench-gpu.json, "first-placement").
        with ThreadPoolExecutor(max_workers=max(1, len(local)), thread_name_prefix="mjxsuite-put") as pool:
            on_device = list(pool.map(place_on, local))
        return jax.tree.unflatten(treedef, [
            jax.make_array_from_single_device_arrays(x.shape, self.sharding, [placed[i] for placed in on_device])
            for i, x in enumerate(leaves)])

    def to_host(self, tree: Any) -> Any:
        """Numpy arrays of every agent, on every process (a collective in a multi-host run)."""
        if jax.process_count() > 1:
            from jax.experimental import multihost_utils

            return multihost_utils.process_allgather(tree, tiled=True)
        return jax.device_get(tree)

    def same_on_every_process(self, decision: bool) -> bool:
        """Process 0's `decision` on every process (e.g. whether to save now, by each host's clock):
        a multi-host run's processes must gather at the same chunks."""
        if jax.process_count() == 1:
            return decision
        from jax.experimental import multihost_utils

        return bool(multihost_utils.broadcast_one_to_all(np.int32(decision)))
