"""The data a run trains on: which samples, how many steps (`Budget`), and the stream of device batches
(`TrainingStream`), one owner of each.

The batch of step s is a pure function of (seed, s): epoch e = s // steps_per_epoch is every sample in the
order `epoch_order(seed, e)`, of which the run trains the first `steps_per_epoch` batches.  A resumed run,
or a process holding a slice of the batch, therefore sees the same batches.  A background thread gathers
the next batches and puts them on the devices while the current step runs (as big_vision's input
pipeline does), so the step does not wait for the host.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
from collections.abc import Iterator

import numpy as np
from jax.sharding import Mesh

from jaxpose.data.batch import MultiViewBatch
from jaxpose.data.dataset import MultiViewDataset, epoch_order
from jaxpose.training import parallel
from jaxpose.training.experiment import ExperimentConfig, TrainConfig

PREFETCH = 2
"""Device batches made ahead of the step: one to be consumed next, one being made (more only holds memory)."""


@dataclasses.dataclass(frozen=True)
class Budget:
    """The steps a run trains: `epochs` epochs of `steps_per_epoch` batches of `batch_size` samples.

    Without a cap (or where it does not bind) an epoch is every training sample once, in full batches.
    Where `--train.max-samples` binds, each epoch is thinned instead of the run losing epochs: its first
    `steps_per_epoch` batches of that epoch's shuffled order, so a new random part of the samples each
    epoch.  The recipe keeps its character: the same number of epochs and reshuffles, the output
    triangulation in its last 10% of epochs, the learning rate decaying over the whole (shortened) run,
    every sample still likely to be seen over a long run; and a project whose one epoch is larger
    than the cap still fits (fewer whole epochs could not).
    """

    samples: int
    """Training samples (multi-view instants)."""
    batch_size: int
    epochs: int
    full_steps_per_epoch: int
    """Full batches in an epoch over every sample (the remainder is dropped: one shape, one compile)."""
    steps_per_epoch: int
    """Batches per epoch as trained: `full_steps_per_epoch`, or fewer under the cap."""
    max_samples: int

    @property
    def total_steps(self) -> int:
        return self.steps_per_epoch * self.epochs

    @property
    def capped(self) -> bool:
        return self.steps_per_epoch < self.full_steps_per_epoch

    def note(self) -> str:
        """What a capped budget trains, for the log and the report: "N of M epochs-worth of samples (...):
        the cap X of --train.max-samples"."""
        trained = self.total_steps * self.batch_size
        return (
            f"{trained / self.samples:.1f} of {self.epochs} epochs-worth of samples ({trained:,} samples: {self.epochs}"
            f" epochs of {self.steps_per_epoch:,} of {self.full_steps_per_epoch:,} batches each): the cap {self.max_samples:,}"
            " of --train.max-samples"
        )


def training_budget(num_samples: int, train: TrainConfig) -> Budget:
    """The steps `train` gives a training set of `num_samples` samples; a batch larger than the data,
    or a cap below one batch per epoch, ends the program in one line."""
    if num_samples == 0:
        raise SystemExit(
            "error: no training sample is left: every instant was held out (--data.validation-*), or has fewer usable"
            " views than --pseudo-labels.min-views (scores below the data's score threshold, e.g. --data.min-confidence)"
        )
    if num_samples < train.batch_size:
        raise SystemExit(
            f"error: --train.batch-size {train.batch_size} is larger than the training set ({num_samples} samples);"
            f" choose at most {num_samples}"
        )
    if 0 < train.max_samples < train.batch_size * train.epochs:
        raise SystemExit(
            f"error: --train.max-samples {train.max_samples} is below one batch per epoch (--train.batch-size"
            f" {train.batch_size} x --train.epochs {train.epochs} = {train.batch_size * train.epochs}); raise it, or"
            " lower --train.epochs"
        )
    full = num_samples // train.batch_size
    per_epoch = full
    if train.max_samples > 0:
        per_epoch = min(full, train.max_samples // (train.batch_size * train.epochs))
    return Budget(num_samples, train.batch_size, train.epochs, full, per_epoch, train.max_samples)


@dataclasses.dataclass(frozen=True)
class TrainingStream:
    """The samples a run trains on (the rows `rows` of `dataset`, drawn without copying a memory-mapped data
    set; None: all), its `budget`, and the batches of every step (`batches`)."""

    dataset: MultiViewDataset
    rows: np.ndarray | None
    budget: Budget
    seed: int
    window: int
    """Frames of the lifter's input window (1: the instant alone)."""

    @classmethod
    def of(cls, config: ExperimentConfig, dataset: MultiViewDataset, rows: np.ndarray | None = None) -> TrainingStream:
        """The stream of `config`'s budget, seed and input window over `dataset` (its `rows`); a batch larger
        than the data, or a cap below one batch per epoch, ends the program in one line (`training_budget`)."""
        count = len(dataset) if rows is None else len(rows)
        return cls(dataset, rows, training_budget(count, config.train), config.train.seed, config.model.temporal_window)

    def batch_rows(self, start_step: int = 0) -> Iterator[tuple[int, np.ndarray]]:
        """Endless (step, the rows of `dataset` in its global batch) from `start_step` on: a pure function of
        (seed, step)."""
        budget, step = self.budget, start_step
        while True:
            epoch, offset = divmod(step, budget.steps_per_epoch)
            order = epoch_order(budget.samples, self.seed, epoch)
            if self.rows is not None:
                order = self.rows[order]
            for position in range(offset, budget.steps_per_epoch):
                yield step, order[position * budget.batch_size : (position + 1) * budget.batch_size]
                step += 1

    def batches(self, mesh: Mesh, start_step: int, stop_step: int, prefetch: int = PREFETCH) -> Iterator[tuple[int, MultiViewBatch]]:
        """(step, global batch on the devices of `mesh`) for the steps `start_step` .. `stop_step` - 1, each made
        by a background thread up to `prefetch` steps ahead.  This process gathers only the samples its own
        devices hold (`parallel.local_rows`).  An error while making a batch is raised here; closing the
        iterator (a `break`, an exception in the loop) stops the thread."""
        local = parallel.local_rows(mesh, self.budget.batch_size)
        ready: queue.Queue = queue.Queue(maxsize=prefetch)
        stop = threading.Event()

        def put(item) -> bool:  # False once the consumer has gone
            while not stop.is_set():
                try:
                    ready.put(item, timeout=0.1)
                    return True
                except queue.Full:
                    continue
            return False

        def produce() -> None:
            try:
                for step, rows in self.batch_rows(start_step):
                    if step >= stop_step:
                        break
                    batch = parallel.global_batch(self.dataset.batch(rows[local], self.window), mesh, self.budget.batch_size)
                    if not put((step, batch)):
                        return
            except BaseException as error:  # handed to the consumer, which raises it
                put(error)
                return
            put(None)

        thread = threading.Thread(target=produce, name="training-stream", daemon=True)
        thread.start()
        try:
            while (item := ready.get()) is not None:
                if isinstance(item, BaseException):
                    raise item
                yield item
        finally:
            stop.set()
            thread.join()
