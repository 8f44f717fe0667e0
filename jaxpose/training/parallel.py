"""Data parallelism over devices and hosts with JAX's own runtime (one global-view `jax.jit`).

The devices form a one-axis mesh, `data`.  The train state is replicated on every device (`P()`);
every leaf of a `MultiViewBatch` (the `Cameras` fields included) is split over the mesh along its
leading sample axis (`P("data")`).  The pure `train_step` is jitted once with these shardings and
XLA partitions it: each device runs the lifter on its samples, and every reduction over the batch
becomes a cross-device all-reduce.  In particular BatchNorm's `jnp.mean`/`jnp.var` over the batch
axis are reductions over the GLOBAL batch, so a run on N devices computes the same statistics,
losses, gradients, dropout masks (random bits are drawn for the global array) and updates as one
device fed the whole batch, up to the order of floating-point sums.

Several processes (hosts) run the same program (SPMD): `initialize` connects them, each process
gathers only the samples its own devices hold (`local_rows`, read by
`jaxpose.training.stream.TrainingStream`), and
`jax.make_array_from_process_local_data` joins the pieces into one global array.  A single device
is the one-device mesh of the same code path.
"""

from __future__ import annotations

import os
from typing import Any, TypeVar

import jax
import numpy as np
from jax.sharding import AxisType, Mesh, NamedSharding, PartitionSpec

from jaxpose.data.batch import MultiViewBatch

DATA_AXIS = "data"

# Task counts set by the launchers whose environment `jax.distributed.initialize()` reads by itself.
_LAUNCHER_TASK_COUNTS = ("SLURM_NTASKS", "OMPI_COMM_WORLD_SIZE")

Tree = TypeVar("Tree")


def initialize(
    coordinator_address: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> bool:
    """Join a multi-process run; must run before anything touches a JAX device.  True if joined.

    Given any of the arguments, calls `jax.distributed.initialize` with them (JAX fills in the
    rest from the cluster environment).  Given none, joins only when launched as one of several
    SLURM (`srun`) or Open MPI tasks, leaving the coordinator, process count and id to JAX's
    auto-detection; a plain single process (or `num_processes=1`) does nothing.  Idempotent.
    Cross-process collectives on CPU use gloo, JAX's default (as of 0.10), so nothing else is set.
    """
    if jax.distributed.is_initialized():
        return True
    given = any(value is not None for value in (coordinator_address, num_processes, process_id))
    launched = any(int(os.environ.get(name, "1")) > 1 for name in _LAUNCHER_TASK_COUNTS)
    if num_processes == 1 or not (given or launched):
        return False
    jax.distributed.initialize(coordinator_address, num_processes, process_id)
    return True


def data_mesh(num_devices: int = -1) -> Mesh:
    """A 1-D mesh named `data` over the first `num_devices` devices of all processes (-1 = all)."""
    available = jax.device_count()
    count = available if num_devices == -1 else num_devices
    if not 1 <= count <= available:
        raise ValueError(f"data parallelism over {num_devices} devices: expected -1 or 1..{available}")
    if jax.process_count() > 1 and count != available:
        raise ValueError(
            f"a {jax.process_count()}-process run must put all {available} devices on the data axis"
            f" (--parallel.data -1), got {num_devices}"
        )
    # Auto axes: the compiler propagates the shardings through the model, whose code stays
    # sharding-agnostic (explicit axes would demand an out-sharding on every batch reshape).
    return jax.make_mesh((count,), (DATA_AXIS,), (AxisType.Auto,), devices=jax.devices()[:count])


def replicated(mesh: Mesh) -> NamedSharding:
    """A full copy on every device of the mesh (the train state, keys, metrics)."""
    return NamedSharding(mesh, PartitionSpec())


def batch_sharding(mesh: Mesh) -> NamedSharding:
    """Split along the leading (sample) axis over the `data` axis; applies to every batch leaf."""
    return NamedSharding(mesh, PartitionSpec(DATA_AXIS))


def replicate(tree: Tree, mesh: Mesh) -> Tree:
    """Copy a pytree that every process holds identically onto all devices of the mesh.

    Each process supplies the whole value, so nothing is communicated (unlike `jax.device_put`,
    which in a multi-process run compares the value across processes leaf by leaf).
    """
    sharding = replicated(mesh)

    def put(leaf):
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):  # keys travel as their raw bits
            return jax.random.wrap_key_data(put(jax.random.key_data(leaf)), impl=jax.random.key_impl(leaf))
        return jax.make_array_from_process_local_data(sharding, np.asarray(leaf))

    return jax.tree.map(put, tree)


def local_rows(mesh: Mesh, batch_size: int) -> np.ndarray:
    """Positions in a global batch of `batch_size` samples that this process's devices hold.

    Raises ValueError unless `batch_size` divides evenly over the data axis.
    """
    devices = mesh.shape[DATA_AXIS]
    if batch_size % devices:
        raise ValueError(
            f"global batch size {batch_size} does not split evenly over {devices} devices; use a multiple of"
            f" {devices} (--train.batch-size) or fewer devices (--parallel.data)"
        )
    held = batch_sharding(mesh).addressable_devices_indices_map((batch_size,)).values()
    blocks = sorted({index[0].indices(batch_size)[:2] for index in held})
    # make_array_from_process_local_data fills this process's blocks from its rows in this order.
    return np.concatenate([np.arange(start, stop) for start, stop in blocks])


def global_batch(local: MultiViewBatch, mesh: Mesh, batch_size: int) -> MultiViewBatch:
    """Join every process's `local` rows (`local_rows` of the global batch) into global arrays."""
    sharding = batch_sharding(mesh)
    return jax.tree.map(
        lambda leaf: jax.make_array_from_process_local_data(sharding, leaf, (batch_size, *leaf.shape[1:])), local
    )


def local_replica(tree: Tree) -> Tree:
    """This process's copy of a replicated pytree, on one local device (for host-local work such
    as evaluation, which then needs no cross-process communication)."""

    def first_shard(leaf: Any) -> Any:
        if not leaf.is_fully_replicated:
            raise ValueError(f"local_replica: a leaf of shape {leaf.shape} is not replicated ({leaf.sharding})")
        return leaf.addressable_data(0)

    return jax.tree.map(first_shard, tree)
