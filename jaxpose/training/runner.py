"""The job every experiment entry point runs: data -> pseudo-labels -> train (or resume) -> evaluate -> report.

Its parts: `jaxpose.training.splits` (what a data loader returns), `jaxpose.training.run_directory` (config.json
and the resume check, the metric log), `jaxpose.training.loop` (the loop, checkpoints, signals) and
`jaxpose.training.report` (the evaluation, report.{json,md} and plots).

A run directory holds:
  config.json      the resolved config (what a resume checks it continues)
  metrics.jsonl    one line per `train.log_every` steps (appended across resumes)
  checkpoints/     Orbax CheckpointManager steps (the newest `train.keep_checkpoints`); each holds the
                   train state and, for `jaxpose.serving.inference`, the variables and the network's record
  report.json/.md  the evaluation on the test split, with the reference rows
  plots/           loss curves and GT-vs-prediction skeletons (PNG)
Ctrl-C or SIGTERM saves a checkpoint before exit; starting again on the same directory resumes.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np

from jaxpose.training.experiment import ExperimentConfig, check_config
from jaxpose.training.report import evaluate_and_report
from jaxpose.training.run_directory import check_resumable, exclusive, prepare_run_dir, write_record
from jaxpose.training.splits import Splits
from jaxpose.training.loop import Diverged, Interrupted, train
from jaxpose.training.stream import TrainingStream
from jaxpose.training import parallel, pseudo_labelling
from jaxpose.compilation_cache import enable_compilation_cache
from jaxpose.data.batch import validate_batch
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.logs import show_logs

log = logging.getLogger("jaxpose")

VALIDATION_ROWS = 65536  # training samples checked at a time (`validate_batch`), so the check's memory is bounded


def run(
    config: ExperimentConfig,
    load_data: Callable[[Any], Splits],
    replace_labels: Callable[[MultiViewDataset], MultiViewDataset] | None = None,
) -> dict:
    """The whole job: data -> pseudo-labels -> train (or resume) -> evaluate -> report.

    `replace_labels` maps the labelled training set to the one trained on: a diagnostic hook for
    studies of what the labels cost (`experiments.label_bias`), never part of a method.
    """
    show_logs()
    try:
        check_config(config)
    except ValueError as error:
        raise SystemExit(f"error: {error}") from None
    enable_compilation_cache()  # the train step's programs come from disk on the next run
    # Before anything touches a device: a multi-host run connects its processes first.
    parallel.initialize(config.parallel.coordinator_address, config.parallel.num_processes, config.parallel.process_id)
    check_resumable(config)
    with exclusive(config.run.run_dir):
        return _run_holding_the_directory(config, load_data, replace_labels)


def _run_holding_the_directory(
    config: ExperimentConfig,
    load_data: Callable[[Any], Splits],
    replace_labels: Callable[[MultiViewDataset], MultiViewDataset] | None,
) -> dict:
    begin = time.perf_counter()
    # Data first: a missing or malformed file then leaves no run directory behind (and an
    # --run.overwrite start does not delete the previous run before the data are known to load).
    splits = load_data(config.data)
    log.info("data: %d train / %d test samples, %d views, %d joints", len(splits.train), len(splits.test), splits.train.num_views, splits.train.skeleton.num_joints)
    splits = bounded_test_split(splits, config.train.eval_max_samples)
    # The samples trained on are rows of the whole training set, which stays as loaded (a rig
    # project's is memory-mapped: a copy of its usable rows could exceed the memory).
    usable = splits.train.usable_view_count() >= config.pseudo_labels.min_views
    samples = None
    if not usable.all():
        groups = splits.train.samples.labels.get(splits.group_label) if splits.group_label in splits.train.samples.labels else None
        where = "" if groups is None else " (" + ", ".join(f"{name}: {count}" for name, count in zip(*np.unique(groups[~usable], return_counts=True))) + ")"
        log.warning("leaving out %d training samples with fewer than %d usable views%s", int((~usable).sum()), config.pseudo_labels.min_views, where)
        samples = np.flatnonzero(usable)
    if not usable.any():  # which of the two: the stream's budget below sees only the count
        why = "every instant was held out (--data.validation-*)" if not len(usable) else (
            f"all {len(usable)} training instants have fewer usable views than --pseudo-labels.min-views {config.pseudo_labels.min_views}"
            " (scores below the data's score threshold, e.g. --data.min-confidence)")  # fmt: skip
        raise SystemExit(f"error: no training sample is left: {why}")
    # The budget is known before labelling: a batch larger than the data stops here, before the run directory is written.
    stream = TrainingStream.of(config, splits.train, samples)
    train_set = pseudo_labelling.label(splits.train, config.pseudo_labels, progress=config.run.progress)
    if replace_labels is not None:
        train_set = replace_labels(train_set)
    stream = dataclasses.replace(stream, dataset=train_set)
    trained = np.arange(len(train_set)) if stream.rows is None else stream.rows
    for start in range(0, len(trained), VALIDATION_ROWS):
        validate_batch(train_set.batch(trained[start : start + VALIDATION_ROWS], config.model.temporal_window))
    splits = dataclasses.replace(splits, train=train_set)
    run_folder = prepare_run_dir(config)  # the run's folder, for the whole run
    if jax.process_index() == 0:
        write_record(run_folder, splits.record)
        for write in splits.artifacts:
            write(run_folder)
    try:
        state, model = train(config, stream, run_folder, splits.test)
    except Interrupted as stop:
        log.warning("%s", stop)
        raise SystemExit(130) from None
    except Diverged as error:
        raise SystemExit(f"error: {error}") from None
    method = "Lifter, supervised (3D ground truth)" if config.loss.supervision == "full" else "Lifter, self-supervised (ours)"
    report = evaluate_and_report(config, splits, stream.budget, state, model, run_folder, method, time.perf_counter() - begin)
    if jax.process_index() == 0:
        print(run_folder.report_md.read_text())
        print(f"run directory: {run_folder.path}  (wall time {time.perf_counter() - begin:.0f} s)")
    return report


def bounded_test_split(splits: Splits, max_samples: int) -> Splits:
    """The test split thinned to every k-th sample where it holds more than `max_samples` (0: never)."""
    count = len(splits.test)
    if not 0 < max_samples < count:
        return splits
    step = -(-count // max_samples)
    test = splits.test.subset(np.arange(0, count, step))
    note = (
        f"The test split holds {count:,} samples, more than --train.eval-max-samples {max_samples:,}: the report"
        f" evaluates one in {step} of them ({len(test):,}, evenly through the recordings)."
    )
    log.info("%s", note)
    return dataclasses.replace(splits, test=test, notes=(*splits.notes, note))
