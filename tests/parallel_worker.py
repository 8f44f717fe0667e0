"""Processes launched by tests/training/test_parallel.py, and the helpers both sides share.

    python tests/parallel_worker.py sharded OUT.npz
        5 train steps of the reference problem on a mesh over all devices (the test forces 8 CPU
        devices), saving the parameters, BatchNorm statistics, dropout patterns, and the error
        for a batch that does not split over the devices.
    python tests/parallel_worker.py process ID COUNT PORT RUN_DIR OUT.npz
        one process of a COUNT-process run on 127.0.0.1:PORT: `parallel.initialize`, then the
        experiment runner's `train` for `FIRST_STEPS`, then again on the same run directory, which
        resumes from the checkpoint, to `TOTAL_STEPS`; saves this process's final parameters.

The device count must be fixed (JAX_NUM_CPU_DEVICES) before JAX starts, hence separate processes.
"""

from __future__ import annotations

import dataclasses
import pathlib
import sys
from collections.abc import Callable

import jax
import numpy as np
from geometry_helpers import exact_batch

from experiments import synthetic
from jaxpose.training.experiment import ExperimentConfig, ParallelConfig, RunConfig, TrainConfig
from jaxpose.training.run_directory import prepare_run_dir
from jaxpose.training.loop import train
from jaxpose.training.stream import TrainingStream
from jaxpose.training import parallel, pseudo_labelling
from jaxpose.training.config import LossConfig, OptimizerConfig
from jaxpose.model import ModelConfig
from jaxpose.data.batch import MultiViewBatch
from jaxpose.synthetic import SyntheticConfig
from jaxpose.model import LifterNetwork
from jaxpose.model import normalize_views
from jaxpose.training.step import TrainState, init_train_state, jit_train_step, lifter_input_2d, make_train_step

STEPS = 5
SMALL = ModelConfig(width=64)  # dropout 0.5 and BatchNorm on, as in the paper's network
FIRST_STEPS, TOTAL_STEPS, SAMPLES = 2, 4, 64  # the multi-process run: 1 epoch of 4 batches of 16
# Per-device batches stay small (2 and 4 samples): with several CPU devices in one process,
# jaxlib 0.10's batched LAPACK SVD (output triangulation) can deadlock the shared thread pool
# once a device holds ~16 samples (see docs_snippets/multi_device.md).


@dataclasses.dataclass(frozen=True)
class Problem:
    """16 exact samples x 4 views, the small lifter, and its pure train step (L_out on from step 2)."""

    model: LifterNetwork
    train_step: Callable
    initial_state: TrainState
    batch: MultiViewBatch


def reference_problem() -> Problem:
    model = SMALL.build(17)
    optimizer = OptimizerConfig().build(STEPS)
    train_step = make_train_step(model, SMALL, optimizer, LossConfig(output_triangulation_start=0.4), STEPS)
    batch, _ = exact_batch(np.random.default_rng(0), 16, 4, 17)
    state = init_train_state(model, optimizer, jax.random.key(0))
    return Problem(model, train_step, jax.device_get(state), jax.tree.map(np.asarray, batch))


def sharded_run(problem: Problem, mesh) -> tuple[TrainState, dict]:
    """`STEPS` steps of `jit_train_step` on `mesh`, and the dropout patterns of one forward pass."""
    state, key = parallel.replicate((problem.initial_state, jax.random.key(1)), mesh)
    batch = parallel.global_batch(problem.batch, mesh, len(problem.batch.pseudo3d))
    step = jit_train_step(problem.train_step, mesh)
    for _ in range(STEPS):
        state, _ = step(state, batch, key, False)
    copy = parallel.replicated(mesh)
    patterns = jax.jit(
        lambda variables, batch, key: zero_patterns(problem.model, variables, batch, key),
        in_shardings=(copy, parallel.batch_sharding(mesh), copy),
    )(parallel.replicate(problem.initial_state.variables, mesh), batch, key)
    return jax.device_get(state), jax.device_get(patterns)


def zero_patterns(model, variables, batch: MultiViewBatch, key) -> dict:
    """Where every layer's training-mode output is zero: dropout's masks (and ReLU's zeros)."""
    keypoints, confidence = lifter_input_2d(batch)
    inputs = normalize_views(keypoints, batch.cameras.K, confidence, SMALL.input_normalization)
    _, captured = model.apply(
        variables,
        inputs,
        train=True,
        rngs={"dropout": key},
        mutable=["batch_stats", "intermediates"],
        capture_intermediates=True,
    )
    return jax.tree.map(lambda output: output == 0, captured["intermediates"])


def flat(tree, prefix: str) -> dict[str, np.ndarray]:
    """A pytree as {prefix + key path: numpy array}, for npz files."""
    leaves = jax.tree_util.tree_leaves_with_path(tree)
    return {prefix + jax.tree_util.keystr(path): np.asarray(leaf) for path, leaf in leaves}


def _sharded(out: str) -> None:
    mesh = parallel.data_mesh()
    state, patterns = sharded_run(reference_problem(), mesh)
    try:
        parallel.local_rows(mesh, 12)
        uneven = ""
    except ValueError as error:
        uneven = str(error)
    np.savez(
        out,
        **flat(state.params, "params"),
        **flat(state.batch_stats, "batch_stats"),
        **flat(patterns, "zeros"),
        uneven_batch_error=np.asarray(uneven),
    )


def process_config(run_dir: str, parallel_config: ParallelConfig = ParallelConfig()) -> ExperimentConfig:
    """The tiny synthetic experiment of the multi-process test (4 steps of 16 samples)."""
    return ExperimentConfig(
        data=synthetic.SyntheticData(SyntheticConfig(num_train_subjects=1, num_test_subjects=0, samples_per_subject=SAMPLES)),
        model=SMALL,
        train=TrainConfig(batch_size=16, epochs=1, max_steps=TOTAL_STEPS, log_every=1, checkpoint_every=1),
        run=RunConfig(run_dir=pathlib.Path(run_dir), progress=False),
        parallel=parallel_config,
    )


def _process(process_id: int, count: int, port: int, run_dir: str, out: str) -> None:
    cluster = ParallelConfig(coordinator_address=f"127.0.0.1:{port}", num_processes=count, process_id=process_id)
    config = process_config(run_dir, cluster)
    joined = parallel.initialize(cluster.coordinator_address, cluster.num_processes, cluster.process_id)
    assert joined and jax.process_count() == count, (joined, jax.process_count())
    train_set = pseudo_labelling.label(synthetic.load_splits(config.data).train)
    first = dataclasses.replace(config, train=dataclasses.replace(config.train, max_steps=FIRST_STEPS))
    train(first, TrainingStream.of(first, train_set), prepare_run_dir(first))
    # The same run directory again: every process restores the checkpoint and training goes on.
    state, _ = train(config, TrainingStream.of(config, train_set), prepare_run_dir(config))
    np.savez(out, **flat(state.params, "params"), step=np.asarray(state.step))


if __name__ == "__main__":
    mode, *args = sys.argv[1:]
    if mode == "sharded":
        _sharded(*args)
    else:
        _process(int(args[0]), int(args[1]), int(args[2]), *args[3:])
