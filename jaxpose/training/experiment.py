"""The experiment config tree, shared by every data set; each entry point fills in its `data` part.

Frozen dataclasses, turned into a command line by tyro: every field's docstring is its `--help`.
The resolved tree is written to `<run_dir>/config.json`, against which a resume checks that it
continues the same run.  (Inference needs none of it: each checkpoint records its network.)
"""

from __future__ import annotations

import dataclasses
import json
import math
import pathlib
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Generic, TypeVar

from jaxpose.camera import Cameras
from jaxpose.training.config import RESCALED_LOSS, InputAugmentation, LossConfig, OptimizerConfig, PseudoLabelConfig
from jaxpose.model import ModelConfig
from jaxpose.data.dataset import MultiViewDataset

DataT = TypeVar("DataT")


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Training loop."""

    batch_size: int = 1024
    """Multi-view samples per step; the lifter sees batch_size x C poses."""
    epochs: int = 20
    """Passes over the training samples.  Given on the command line without --train.max-samples, it
    lifts a preset's sample cap: that many full epochs are trained."""
    max_samples: int = 0
    """The most training samples seen (steps x batch_size; 0 = no cap).  Where the epochs would see
    more, every epoch is thinned to a random part of the training samples (a new part each epoch) so
    that the run fits, and the schedules (learning rate, the output triangulation's last 10%,
    checkpoints) span the shortened run; the report says so."""
    max_steps: int = 0
    """Stop after this many steps (0 = train all epochs).  The schedules still span all epochs."""
    seed: int = 0
    """Seeds the initialization, the data order and the dropout masks."""
    log_every: int = 50
    """Steps between lines in metrics.jsonl."""
    checkpoint_every: int = 1000
    """Steps between checkpoints (one is also written at the end and on Ctrl-C/SIGTERM)."""
    keep_checkpoints: int = 3
    """Checkpoints kept on disk (the newest ones)."""
    eval_batch_size: int = 16384
    """Poses per inference call during evaluation."""
    eval_every: int = 0
    """Steps between evaluations of the current model on a fixed subset of the test split (0 = never),
    logged as eval_p_mpjpe / eval_mpjpe to metrics.jsonl, TensorBoard and plots/periodic_evaluation.png.
    For watching a run only: nothing is selected on it, and the report is always the final checkpoint."""
    eval_samples: int = 1000
    """Test samples (with all their views) in each periodic evaluation: a fixed, evenly spaced subset."""
    eval_max_samples: int = 200_000
    """The report evaluates at most this many held-out samples (0 = all): a larger test split is thinned
    to every k-th sample, evenly through its recordings, and the report says so.  Evaluation holds
    every view's prediction, triangulation and target at once (about 1 KB per sample and view), so
    this bounds its memory: a million held-out instants would need over 4 GB."""
    eval_flip: bool = False
    """Evaluate the report with test-time flip augmentation (`jaxpose.flip`: each view's pose and its mirror
    image lifted and averaged; the periodic evaluation stays plain).  Given to a finished run's command, it
    evaluates the final checkpoint again and rewrites the report."""
    augment: InputAugmentation = InputAugmentation()
    """The detector's failure modes imposed on the lifter's input (jaxpose.training.config.InputAugmentation);
    all 0 by default."""


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """The run directory and reporting."""

    run_dir: pathlib.Path = pathlib.Path("runs/default")
    """Holds config.json, metrics.jsonl, checkpoints/, report.{json,md} and plots/.  Starting again
    on the same directory resumes from its last complete checkpoint."""
    overwrite: bool = False
    """Start from scratch even if run_dir holds a run (its checkpoints and logs are deleted)."""
    plot_samples: int = 4
    """Test samples drawn as GT-vs-prediction skeletons in the report."""
    progress: bool = True
    """Show progress bars."""
    tensorboard: bool = True
    """Also write TensorBoard event files to <run_dir>/tensorboard while training (needs tensorboardX:
    pip install 'jaxpose[monitor]'; without it a warning, and metrics.jsonl as always).  Watch with
    `tensorboard --logdir runs/`."""


@dataclasses.dataclass(frozen=True)
class ParallelConfig:
    """Data parallelism over devices and hosts (see docs/scaling.md, "Training on several devices and hosts").

    The train state is replicated, every batch is split by samples over the devices, and BatchNorm
    statistics are taken over the whole (global) batch; `train.batch_size` is that global batch and
    must be a multiple of the number of devices.  Leave the last three fields unset for one process,
    or under `srun` (SLURM) / `mpirun` (Open MPI), where JAX reads them from the environment.
    """

    data: int = -1
    """Devices on the mesh's data axis: -1 = all devices of all processes; N = the first N (one
    process only)."""
    coordinator_address: str | None = None
    """host:port of process 0, reachable from every process, for a multi-process run (None = one
    process, or from the SLURM/Open MPI environment)."""
    num_processes: int | None = None
    """Number of processes of a multi-process run (None = one process, or from the cluster environment)."""
    process_id: int | None = None
    """This process's index, 0..num_processes-1 (None = from the cluster environment)."""


@dataclasses.dataclass(frozen=True)
class ExperimentConfig(Generic[DataT]):
    """A whole experiment: data, model, losses, optimizer, training, run directory, parallelism."""

    data: DataT
    model: ModelConfig = ModelConfig()
    loss: LossConfig = LossConfig()
    optimizer: OptimizerConfig = OptimizerConfig()
    pseudo_labels: PseudoLabelConfig = PseudoLabelConfig()
    train: TrainConfig = TrainConfig()
    run: RunConfig = RunConfig()
    parallel: ParallelConfig = ParallelConfig()


def paper_preset(data: DataT, *, batch_size: int, epochs: int, checkpoint_every: int, run_dir: str) -> ExperimentConfig[DataT]:
    """Sec. IV-A of the paper on `data`: the authors' network (ModelConfig defaults), loss weights 1, 1,
    0.001, 0.01 with L_out in the last 10% (LossConfig defaults), Adam at a constant 1e-3, and the data
    set's batch size and epochs."""
    return ExperimentConfig(
        data=data,
        model=ModelConfig(),
        loss=LossConfig(),
        optimizer=OptimizerConfig(learning_rate=1e-3, schedule="constant"),
        train=TrainConfig(batch_size=batch_size, epochs=epochs, checkpoint_every=checkpoint_every),
        run=RunConfig(run_dir=pathlib.Path(run_dir)),
    )


def cpu_recipe(
    data: DataT, *, warmup_steps: int, run_dir: str, max_samples: int = 0, drop: float = 0.0, eval_every: int | None = None
) -> ExperimentConfig[DataT]:
    """The cpu recipe on `data`, the one measured best on Human3.6M for 2 CPU cores (the measurements beside
    `experiments.h36m.CPU`), from which Human3.6M's cpu and development presets and a user's rig preset derive
    (each with its own data and budget, none a diff of another): a width-512 lifter of one stage, dropout 0.1, the rescaled loss weights with a
    pseudo-Huber label penalty (50 mm), RANSAC pseudo-labels, Adam with a cosine schedule after `warmup_steps`,
    batch 128, 70 epochs (at most `max_samples` samples where > 0); joints dropped from the input at `drop`."""
    train = TrainConfig(batch_size=128, epochs=70, checkpoint_every=4000, max_samples=max_samples, augment=InputAugmentation(drop=drop))
    return ExperimentConfig(
        data=data,
        model=ModelConfig(width=512, dropout_rate=0.1, stages=1),
        loss=dataclasses.replace(RESCALED_LOSS, label_robust_scale_mm=50.0),
        pseudo_labels=PseudoLabelConfig(method="ransac"),
        optimizer=OptimizerConfig(schedule="cosine", warmup_steps=warmup_steps),
        train=train if eval_every is None else dataclasses.replace(train, eval_every=eval_every),
        run=RunConfig(run_dir=pathlib.Path(run_dir)),
    )


def recipe_summary(config: ExperimentConfig) -> str:
    """A preset's recipe in one line for `--help`, made from its fields (so it cannot disagree with them)."""
    model, train, optimizer = config.model, config.train, config.optimizer
    parts = [
        f"width-{model.width} lifter of {model.stages} stage{'s' * (model.stages > 1)}",
        f"dropout {model.dropout_rate:g}",
        f"batch {train.batch_size}",
        f"{train.epochs} epoch{'s' * (train.epochs != 1)}" + (f" but at most {train.max_samples / 1e6:.1f}M samples" if train.max_samples else ""),
        f"Adam {optimizer.learning_rate:g} {optimizer.schedule}",
        f"{config.pseudo_labels.method} pseudo-labels",
        "the paper's loss weights" if config.loss == LossConfig() else "rescaled loss weights" if _without_penalty(config.loss) == RESCALED_LOSS else "own loss weights",
    ]
    if train.augment.drop:
        parts.append(f"joints dropped at {train.augment.drop:g}")
    if model.temporal_window > 1:
        parts.append(f"window of {model.temporal_window} frames")
    return ", ".join(parts)


def _without_penalty(loss: LossConfig) -> LossConfig:
    return dataclasses.replace(loss, label_robust_scale_mm=RESCALED_LOSS.label_robust_scale_mm)


def mocap_calibration(given: pathlib.Path | None, default: pathlib.Path, training: pathlib.Path | None) -> pathlib.Path:
    """The motion capture's calibration, in whose world frame the 3D ground truth is: the one
    `given` (--data.reference-cameras-path), else the data set's own `default` where it exists, else
    the `training` calibration (--data.cameras-path)."""
    if given is not None:
        return given
    return default if default.exists() or training is None else training


def other_training_calibration(training: pathlib.Path | None, reference: pathlib.Path) -> pathlib.Path | None:
    """`training` where the training subjects use another calibration than the `reference` (e.g. one
    recovered by `jaxpose.calibrate`), else None (a different spelling of the same file is the same)."""
    if training is None or training.resolve() == reference.resolve():
        return None
    return training


def on_training_calibration(
    train: MultiViewDataset,
    training: pathlib.Path | None,
    reference: pathlib.Path,
    subject_rigs: Callable[[pathlib.Path, Sequence[str]], Mapping[str, Cameras]],
    subjects: Sequence[str],
) -> MultiViewDataset:
    """The training split on the `training` calibration (--data.cameras-path) where it is another than the
    `reference`, with the rigs of its `subjects` read by the data set's `subject_rigs`.  Only the training
    split: the test samples keep the reference, in whose world frame their ground truth is."""
    other = other_training_calibration(training, reference)
    return train if other is None else train.recalibrated(subject_rigs(other, subjects))


def calibration_lines(training: pathlib.Path | None, reference: pathlib.Path, kind: str = "") -> list[str]:
    """The two calibrations a real-data run reads, for the message when a file is missing or malformed;
    `kind` describes the training calibration's file."""
    return [
        f"  cameras (--data.cameras-path):  {training or reference}{kind}",
        f"  reference cameras (--data.reference-cameras-path):  {reference}",
    ]


# (section, field, the least value) of the numbers a run cannot start without: checked before anything is read or written.
_AT_LEAST = (
    ("train", "batch_size", 1), ("train", "epochs", 1), ("train", "max_samples", 0), ("train", "max_steps", 0),
    ("train", "log_every", 1), ("train", "checkpoint_every", 1), ("train", "keep_checkpoints", 1),
    ("train", "eval_batch_size", 1), ("train", "eval_every", 0), ("train", "eval_samples", 1), ("train", "eval_max_samples", 0),
    ("model", "width", 1), ("model", "stages", 1), ("model", "blocks_per_stage", 0), ("model", "temporal_window", 1),
)  # fmt: skip


def check_config(config: "ExperimentConfig") -> None:
    """A ValueError naming the first flag whose value no run can take (a batch of 0, a width of 0, a NaN or
    non-positive learning rate, a dropout outside [0, 1))."""
    for section, name, least in _AT_LEAST:
        value = getattr(getattr(config, section), name)
        if not value >= least:
            raise ValueError(f"--{section}.{name.replace('_', '-')} must be >= {least}, got {value}")
    rate = config.optimizer.learning_rate
    if not (math.isfinite(rate) and rate > 0):
        raise ValueError(f"--optimizer.learning-rate must be a positive finite number, got {rate}")
    if not 0.0 <= config.model.dropout_rate < 1.0:
        raise ValueError(f"--model.dropout-rate must lie in [0, 1), got {config.model.dropout_rate}")


def to_json_dict(config: Any) -> Any:
    """A dataclass tree as JSON-ready dicts (paths and tuples become strings and lists)."""
    if dataclasses.is_dataclass(config):
        return {f.name: to_json_dict(getattr(config, f.name)) for f in dataclasses.fields(config)}
    if isinstance(config, (list, tuple)):
        return [to_json_dict(v) for v in config]
    if isinstance(config, pathlib.Path):
        return str(config)
    return config


def dumps(config: Any) -> str:
    return json.dumps(to_json_dict(config), indent=2, sort_keys=True)
