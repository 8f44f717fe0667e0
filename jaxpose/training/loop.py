"""The training loop of a run: train (or resume) from the run directory's last checkpoint, log, evaluate a
test subset now and then, checkpoint, and stop cleanly on Ctrl-C or SIGTERM."""

from __future__ import annotations

import dataclasses
import logging
import pathlib
import signal
import time
from collections.abc import Callable, Iterator
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh
from tqdm.auto import tqdm

from jaxpose.training.experiment import ExperimentConfig, TrainConfig
from jaxpose.training.run_directory import RunDirectory, RunLog
from jaxpose.training import checkpoint, parallel
from jaxpose.training.evaluator import Evaluator
from jaxpose.data.batch import MultiViewBatch
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.training.step import TrainState, init_train_state, jit_train_step, make_train_step

log = logging.getLogger("jaxpose")


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


def budget_batches(
    dataset: MultiViewDataset, budget: Budget, seed: int, mesh: Mesh, start_step: int, window: int, samples: np.ndarray | None = None
) -> Iterator[tuple[int, MultiViewBatch]]:
    """Endless (step, global batch) stream of `budget` from `start_step` on: `parallel.process_batches`
    itself where the budget is not capped; else each epoch's first `budget.steps_per_epoch` batches of
    that stream, so a step's batch still depends only on (seed, step) and a resume replays it.
    `samples`: the rows of `dataset` trained on (`parallel.process_batches`)."""
    if not budget.capped:
        yield from parallel.process_batches(dataset, budget.batch_size, seed, mesh, start_step, window, samples)
        return
    step = start_step
    while True:
        epoch, offset = divmod(step, budget.steps_per_epoch)
        full_step = epoch * budget.full_steps_per_epoch + offset
        for _, batch in parallel.process_batches(dataset, budget.batch_size, seed, mesh, full_step, window, samples):
            yield step, batch
            step += 1
            if step % budget.steps_per_epoch == 0:
                break


class Diverged(Exception):
    """Training produced a non-finite loss or weights; the message says where and what is kept."""


def _variables_finite(state: TrainState) -> bool:
    """Whether every weight and batch statistic is finite (read to the host before each checkpoint: no program compiled)."""
    return all(np.isfinite(leaf).all() for leaf in jax.tree.leaves(jax.device_get(state.variables)))


def _diverged(done: int, what: str, manager, config: ExperimentConfig) -> Diverged:
    manager.wait_until_finished()
    kept = manager.latest_step()
    where = f"the last checkpoint, step {kept}, is finite and kept" if kept is not None else "no checkpoint was written"
    return Diverged(
        f"training diverged at step {done}: {what}; {where}. Lower --optimizer.learning-rate"
        f" ({config.optimizer.learning_rate:g}) or check the data, then start again with --run.overwrite"
    )


class Interrupted(Exception):
    """Raised inside the loop when SIGINT/SIGTERM arrived; the checkpoint is already saved."""


class _SignalFlag:
    """Turns SIGINT/SIGTERM into a flag the loop polls, so the checkpoint is written between steps."""

    def __init__(self):
        self.received: int | None = None
        self._previous = {}

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, _frame):
        if self.received is not None:  # a second Ctrl-C: stop at once
            raise KeyboardInterrupt
        self.received = signum
        log.warning("signal %d received: saving a checkpoint before exit", signum)

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def periodic_evaluation(config: ExperimentConfig, test: MultiViewDataset, model) -> Callable[[Any], dict]:
    """variables -> `Evaluator.overall` on `config.train.eval_samples` evenly spaced test samples."""
    rows = np.unique(np.linspace(0, len(test) - 1, min(config.train.eval_samples, len(test))).astype(int))
    return Evaluator.of(config, test.subset(rows), model).overall


def train(
    config: ExperimentConfig,
    train_set: MultiViewDataset,
    run_dir: pathlib.Path,
    test_set: MultiViewDataset | None = None,
    samples: np.ndarray | None = None,
) -> tuple[TrainState, Any]:
    """Train (or resume) on `train_set`, which must carry pseudo-labels, or on its rows `samples`
    (drawn without copying a memory-mapped data set).  Returns (state, model).
    With `train.eval_every`, a subset of `test_set` is evaluated every so many steps (monitoring only).

    Data parallel over `config.parallel.data` devices of all processes (`jaxpose.training.parallel`); the
    returned state is this process's copy, on one local device.
    """
    cfg = config.train
    count = len(train_set) if samples is None else len(samples)
    budget = training_budget(count, cfg)
    per_epoch, total_steps = budget.steps_per_epoch, budget.total_steps
    stop_step = min(total_steps, cfg.max_steps) if cfg.max_steps > 0 else total_steps
    model = config.model.build(train_set.skeleton.num_joints)
    optimizer = config.optimizer.build(total_steps)
    mesh = parallel.data_mesh(config.parallel.data)
    init_key, dropout_key = jax.random.split(jax.random.key(cfg.seed))
    state, dropout_key = parallel.replicate((init_train_state(model, optimizer, init_key), dropout_key), mesh)
    manager = checkpoint.checkpoint_manager(RunDirectory(run_dir).checkpoints, cfg.keep_checkpoints)
    lifter = checkpoint.LifterRecord(train_set.skeleton, config.model)
    restored = checkpoint.restore_latest(manager, state, discard_unreadable=True)
    if restored is not None:
        state = restored
        log.info("resumed from step %d of %d", int(state.step), total_steps)
    run_log = RunLog(run_dir, int(jax.device_get(state.step)), config.run.tensorboard)
    learning_rate = config.optimizer.learning_rate_schedule(total_steps)
    evaluate = periodic_evaluation(config, test_set, model) if cfg.eval_every > 0 and test_set is not None else None
    train_step = make_train_step(
        model, config.model, optimizer, config.loss, total_steps,
        share_every=cfg.log_every, last_step=stop_step,
        augmentation=cfg.augment, skeleton=train_set.skeleton,
    )  # fmt: skip
    step_fn = jit_train_step(train_step, mesh)
    start = int(state.step)
    views = train_set.num_views
    log.info(
        "training: %d samples x %d views, batch %d over %d devices (%d processes), %d steps/epoch,"
        " %d epochs (%d steps%s), from step %d",
        count, views, cfg.batch_size, mesh.size, jax.process_count(), per_epoch, cfg.epochs, total_steps,
        f"; stopping at step {stop_step} (--train.max-steps)" if stop_step < total_steps else "", start,
    )  # fmt: skip
    if budget.capped:
        log.info("training %s", budget.note())
    bar = tqdm(total=stop_step, initial=start, desc="train", unit="step", disable=not config.run.progress or jax.process_index() != 0)
    last_time, last_step = time.perf_counter(), start
    with _SignalFlag() as interrupt:
        batches = budget_batches(train_set, budget, cfg.seed, mesh, start, config.model.temporal_window, samples)
        for step, batch in batches:
            if step >= stop_step:
                break
            state, metrics = step_fn(state, batch, dropout_key)
            done = step + 1
            bar.update(1)
            if done % cfg.log_every == 0 or done == stop_step:
                metrics = {k: float(v) for k, v in jax.device_get(metrics).items()}
                if not np.isfinite(metrics["loss"]):
                    bar.close()
                    run_log.close()
                    raise _diverged(done, f"the loss is {metrics['loss']}", manager, config)
                now = time.perf_counter()
                rate = (done - last_step) * cfg.batch_size / max(now - last_time, 1e-9)
                last_time, last_step = now, done
                record = {"step": done, "epoch": done / per_epoch, "samples_per_s": rate, **metrics}
                run_log.write("train", record | {"learning_rate": float(learning_rate(step))})
                bar.set_postfix(loss=f"{metrics['loss']:.4g}", samples_s=f"{rate:.0f}")
            if evaluate is not None and (done % cfg.eval_every == 0 or done == stop_step):
                run_log.write("eval", {"step": done, **evaluate(parallel.local_replica(state).variables)})
            if done % cfg.checkpoint_every == 0 or done == stop_step or interrupt.received is not None:
                if not _variables_finite(state):  # never a non-finite checkpoint, so a resume cannot load one
                    bar.close()
                    run_log.close()
                    raise _diverged(done, "the weights are not finite", manager, config)
                checkpoint.save(manager, state, lifter)
            if interrupt.received is not None:
                manager.wait_until_finished()
                bar.close()
                run_log.close()
                raise Interrupted(f"stopped by signal {interrupt.received} at step {done}; checkpoint saved in {run_dir}")
    bar.close()
    run_log.close()
    if not _variables_finite(state):
        raise _diverged(int(jax.device_get(state.step)), "the weights are not finite", manager, config)
    checkpoint.save(manager, state, lifter)
    manager.wait_until_finished()
    return parallel.local_replica(state), model
