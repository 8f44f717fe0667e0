"""The training loop of a run: train (or resume) from the run directory's last checkpoint, log, evaluate a
test subset now and then, checkpoint, and stop cleanly on Ctrl-C or SIGTERM."""

from __future__ import annotations

import dataclasses
import logging
import signal
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from tqdm.auto import tqdm

from jaxpose.training.experiment import ExperimentConfig
from jaxpose.training.run_directory import RunDirectory, RunLog, RunRecord, read_record, write_record
from jaxpose.training import checkpoint, parallel
from jaxpose.training.evaluator import Evaluator
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.training.step import TrainState, init_train_state, jit_train_step, make_train_step
from jaxpose.training.stream import TrainingStream

log = logging.getLogger("jaxpose")


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
    config: ExperimentConfig, stream: TrainingStream, run: RunDirectory, test_set: MultiViewDataset | None = None
) -> tuple[TrainState, Any]:
    """Train (or resume) on `stream` (its data set must carry pseudo-labels) for its budget, or up to
    `train.max_steps`.  Returns (state, model).  With `train.eval_every`, a subset of `test_set` is
    evaluated every so many steps (monitoring only).

    Data parallel over `config.parallel.data` devices of all processes (`jaxpose.training.parallel`); the
    returned state is this process's copy, on one local device.
    """
    cfg, budget, skeleton = config.train, stream.budget, stream.dataset.skeleton
    total_steps = budget.total_steps
    stop_step = min(total_steps, cfg.max_steps) if cfg.max_steps > 0 else total_steps
    model = config.model.build(skeleton.num_joints)
    optimizer = config.optimizer.build(total_steps)
    mesh = parallel.data_mesh(config.parallel.data)
    init_key, dropout_key = jax.random.split(jax.random.key(cfg.seed))
    state, dropout_key = parallel.replicate((init_train_state(model, optimizer, init_key), dropout_key), mesh)
    # The step's switch for the gradient shares, on the devices once (the logged steps measure them).
    measure_shares = parallel.replicate({False: np.False_, True: np.True_}, mesh)
    manager = checkpoint.checkpoint_manager(run.checkpoints, cfg.keep_checkpoints)
    # The network joins the run's record (run.json, the one record of what it was trained on); every checkpoint
    # repeats it, derived from the record, because a step must restore alone: Orbax needs the network's shapes
    # before it reads the variables, and a checkpoints/ folder copied without its run.json still loads.
    record = dataclasses.replace(read_record(run) or RunRecord(), skeleton=skeleton.name, model=config.model)
    if jax.process_index() == 0:
        write_record(run, record)
    lifter = record.lifter()
    restored = checkpoint.restore_latest(manager, state, discard_unreadable=True)
    if restored is not None:
        state = restored
        log.info("resumed from step %d of %d", int(state.step), total_steps)
    run_log = RunLog(run, int(jax.device_get(state.step)), config.run.tensorboard)
    learning_rate = config.optimizer.learning_rate_schedule(total_steps)
    evaluate = periodic_evaluation(config, test_set, model) if cfg.eval_every > 0 and test_set is not None else None
    train_step = make_train_step(
        model, config.model, optimizer, config.loss, total_steps, augmentation=cfg.augment, skeleton=skeleton
    )
    step_fn = jit_train_step(train_step, mesh)
    start = int(state.step)
    log.info(
        "training: %d samples x %d views, batch %d over %d devices (%d processes), %d steps/epoch,"
        " %d epochs (%d steps%s), from step %d",
        budget.samples, stream.dataset.num_views, cfg.batch_size, mesh.size, jax.process_count(), budget.steps_per_epoch,
        cfg.epochs, total_steps, f"; stopping at step {stop_step} (--train.max-steps)" if stop_step < total_steps else "", start,
    )  # fmt: skip
    if budget.capped:
        log.info("training %s", budget.note())
    bar = tqdm(total=stop_step, initial=start, desc="train", unit="step", disable=not config.run.progress or jax.process_index() != 0)
    last_time, last_step = time.perf_counter(), start
    try:
        with _SignalFlag() as interrupt:
            for step, batch in stream.batches(mesh, start, stop_step):
                done = step + 1
                logged = done % cfg.log_every == 0 or done == stop_step
                state, metrics = step_fn(state, batch, dropout_key, measure_shares[logged])
                bar.update(1)
                if logged:
                    metrics = {k: float(v) for k, v in jax.device_get(metrics).items()}
                    if not np.isfinite(metrics["loss"]):
                        raise _diverged(done, f"the loss is {metrics['loss']}", manager, config)
                    now = time.perf_counter()
                    rate = (done - last_step) * cfg.batch_size / max(now - last_time, 1e-9)
                    last_time, last_step = now, done
                    record = {"step": done, "epoch": done / budget.steps_per_epoch, "samples_per_s": rate, **metrics}
                    run_log.write("train", record | {"learning_rate": float(learning_rate(step))})
                    bar.set_postfix(loss=f"{metrics['loss']:.4g}", samples_s=f"{rate:.0f}")
                if evaluate is not None and (done % cfg.eval_every == 0 or done == stop_step):
                    run_log.write("eval", {"step": done, **evaluate(parallel.local_replica(state).variables)})
                # The last step always checkpoints: a finished run's directory holds its final state.
                if done % cfg.checkpoint_every == 0 or done == stop_step or interrupt.received is not None:
                    if not _variables_finite(state):  # never a non-finite checkpoint, so a resume cannot load one
                        raise _diverged(done, "the weights are not finite", manager, config)
                    checkpoint.save(manager, state, lifter)
                if interrupt.received is not None:
                    manager.wait_until_finished()
                    raise Interrupted(f"stopped by signal {interrupt.received} at step {done}; checkpoint saved in {run.path}")
    finally:
        bar.close()
        run_log.close()
    manager.wait_until_finished()
    return parallel.local_replica(state), model
