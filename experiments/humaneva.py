"""HumanEva-I: self-supervised training on Train/S1-S3, all actions (3 views), single-view
evaluation on Validate/S1-S3 Walking and Jogging, P-MPJPE per action and subject (the paper's Table III).

    python -m experiments.humaneva --data.data-dir /data/humaneva                 # preset cpu: ~45 min, 2 CPU cores
    python -m experiments.humaneva --preset paper --data.data-dir /data/humaneva  # the paper's hyper-parameters
    python -m experiments.humaneva --supervision full ...                         # the network on 3D ground truth
    python -m experiments.humaneva --preset paper --help                          # every flag, that preset's values

The files (VideoPose3D's npz files plus a camera file you write yourself) and their layout: docs/data.md
("Getting the data").  Test results are grouped by "<action> <subject>" (e.g. "Walk S1"), so
report.md and its "Avg." are per action and subject as in the paper; table_paper_layout.md puts them in
the column order of Table III next to the paper's rows.
"""

from __future__ import annotations

import dataclasses
import pathlib

import numpy as np

from experiments import cli, paper_tables
from jaxpose.training.experiment import ExperimentConfig, RunConfig, TrainConfig, paper_preset
from jaxpose.training.experiment import calibration_lines, mocap_calibration, on_training_calibration
from jaxpose.training.splits import Splits
from jaxpose.training.config import OptimizerConfig
from jaxpose.model import ModelConfig
from jaxpose.datasets.humaneva import POSES_3D_FILE, TEST_SUBJECTS, TRAIN_SUBJECTS, load_humaneva, subject_rigs

GROUP_LABEL = "action_subject"


@dataclasses.dataclass(frozen=True)
class HumanEvaData:
    """HumanEva-I files and protocol (see jaxpose.datasets.humaneva and docs/data.md)."""

    data_dir: pathlib.Path = pathlib.Path("data/humaneva")
    """Folder of data_3d_humaneva15.npz, the 2D npz files and cameras.json."""
    detections: str = "detectron_pt_coco"
    """2D source: NAME reads data_2d_humaneva15_NAME.npz (detectron_pt_coco: Mask R-CNN, COCO), gt, or a .npz path."""
    cameras_path: pathlib.Path | None = None
    """Calibration the training subjects are triangulated and trained with: a jaxpose camera file
    with subjects S1-S3, cameras C1-C3 (docs/data.md), e.g. one recovered by `python -m jaxpose.calibrate`;
    None = the reference."""
    reference_cameras_path: pathlib.Path | None = None
    """Calibration of the motion capture, for the test samples' ground truth (and --data.detections gt):
    None = <data-dir>/cameras.json where it exists, else --data.cameras-path."""
    train_subjects: tuple[str, ...] = TRAIN_SUBJECTS
    """Training partition subjects (the protocol: Train/S1 Train/S2 Train/S3, all actions)."""
    test_subjects: tuple[str, ...] = TEST_SUBJECTS
    """Test partition subjects (the protocol: Validate/S1 Validate/S2 Validate/S3, Walking and Jogging)."""
    train_stride: int = 1
    """Keep every n-th frame of the training sequences (1: all frames, 60 fps)."""
    test_stride: int = 1
    """Keep every n-th frame of the test sequences (1: all frames, as the protocol evaluates)."""


def load_splits(data: HumanEvaData) -> Splits:
    """The Train and Validate partitions; test results grouped by "<action> <subject>"."""

    reference = reference_calibration(data)

    def load(split: str, subjects: tuple[str, ...], stride: int):
        return load_humaneva(
            data.data_dir,
            split,
            detections=data.detections,
            subjects=subjects,
            cameras_path=reference,
            stride=stride,
        )

    train = load("train", data.train_subjects, data.train_stride)
    test = load("test", data.test_subjects, data.test_stride)
    train = on_training_calibration(train, data.cameras_path, reference, subject_rigs, data.train_subjects)
    labels = test.samples.labels
    action_subject = np.array([f"{action} {subject}" for action, subject in zip(labels["action"], labels["subject"])])
    test = test.with_samples(labels={**labels, GROUP_LABEL: action_subject})
    return Splits(train=train, test=test, group_label=GROUP_LABEL)


def reference_calibration(data: HumanEvaData) -> pathlib.Path:
    """The motion capture's calibration (see `HumanEvaData.reference_cameras_path`)."""
    return mocap_calibration(data.reference_cameras_path, data.data_dir / "cameras.json", data.cameras_path)


def expected_files(data: HumanEvaData) -> str:
    """The files this configuration reads, for the error message when they are missing."""
    root = data.data_dir
    if data.detections == "gt":
        poses2d = "none: the 3D poses projected through the cameras"
    elif str(data.detections).endswith(".npz"):
        poses2d = str(data.detections)
    else:
        poses2d = f"{root}/data_2d_humaneva15_{data.detections}.npz (VideoPose3D)"
    camera_file = " (a jaxpose camera file: subjects S1-S3, cameras C1-C3)"
    return "\n".join(
        [
            f"This run reads HumanEva-I from --data.data-dir {root}:",
            f"  3D poses:  {root}/{POSES_3D_FILE} (VideoPose3D)",
            f"  2D (--data.detections {data.detections}):  {poses2d}",
            *calibration_lines(data.cameras_path, reference_calibration(data), camera_file),
            f"  subjects:  {' '.join(data.train_subjects)} (train), {' '.join(data.test_subjects)} (test)",
        ]
    )


# Preset "cpu": the best accuracy we expect from <= 60 minutes on 2 CPU cores.  The arithmetic:
# - Training set: Train/S1-S3, 5 actions, 60 fps = ~7.0k 3-view samples (the frame ranges of
#   VideoPose3D's Train partition add up to 6,978, minus the frames with lost markers).
# - Train step rate: the Human3.6M rate of width 512 at batch 512 (~900 4-view samples/s on 2 cores),
#   times 0.87 for batch 256, times 4/3 for 3 views instead of 4: ~1,050 samples/s.
# - The set is small, so we spend the budget on many passes with small batches: width 512, batch 256,
#   400 epochs x 27 steps (7.0k // 256) = 10,800 steps (about half the paper's 5000 x 4 = 20,000), 2.8M
#   samples / 1,050 per s = ~44 min.  Cosine decay after a 200-step warm-up; dropout at the
#   authors' 0.5.  Loading, triangulation and evaluation (~2.6k test samples) take well under a minute.
CPU = ExperimentConfig(
    data=HumanEvaData(),
    model=ModelConfig(width=512),
    optimizer=OptimizerConfig(schedule="cosine", warmup_steps=200),
    train=TrainConfig(batch_size=256, epochs=400, checkpoint_every=1000),
    run=RunConfig(run_dir=pathlib.Path("runs/humaneva_cpu")),
)

# Preset "paper": Sec. IV-A of the paper (`paper_preset`): batch 1600, 5000 epochs.  The paper's
# HumanEva 2D (its own Mask R-CNN + Stacked Hourglass run) is not published; the closest published
# source is VideoPose3D's detectron_pt_coco (also not fine-tuned on HumanEva).
PAPER = paper_preset(HumanEvaData(), batch_size=1600, epochs=5000, checkpoint_every=1000, run_dir="runs/humaneva_paper")

PRESETS: dict[str, ExperimentConfig] = {"cpu": CPU, "paper": PAPER}
PRESET_NOTES = {
    "cpu": "~45 min on 2 CPU cores",
    "paper": "Sec. IV-A of the paper",
}
DEFAULT = CPU
EXPERIMENT = cli.Experiment(
    name="humaneva",
    presets=PRESETS,
    preset_notes=PRESET_NOTES,
    load_splits=load_splits,
    expected_files=expected_files,
    paper_table=paper_tables.HUMANEVA_TABLE_III,
)


def main(argv: list[str] | None = None) -> dict:
    return cli.main(EXPERIMENT, argv, __doc__)


if __name__ == "__main__":
    main()
