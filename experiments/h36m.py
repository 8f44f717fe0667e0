"""Human3.6M: self-supervised training on S1, S5, S6, S7, S8 (4 views), single-view evaluation on
S9 and S11, P-MPJPE per action (the paper's Tables I and II).

    python -m experiments.h36m --data.data-dir /data/h36m                  # preset cpu: ~21 min on 2 CPU cores
    python -m experiments.h36m --preset paper --data.data-dir /data/h36m   # the paper's hyper-parameters
    python -m experiments.h36m --preset dev --data.data-dir /data/h36m     # development split on S1 (~2 min)
    python -m experiments.h36m --data.detections sh ...                    # Stacked Hourglass 2D (16 joints)
    python -m experiments.h36m --supervision full ...                      # the same network on 3D ground truth
    python -m experiments.h36m --preset paper --help                       # every flag, with that preset's values

Where to get the files and how to lay them out: docs/data.md ("Getting the data").  The run
directory holds the runner's report.md/report.json and table_paper_layout.md, the P-MPJPE per action
in the column order of the paper's Table II next to the paper's rows.  A run trained with 17 joints
(detections cpn or gt) can be evaluated on MPI-INF-3DHP with `python -m experiments.mpi_inf_3dhp`.
"""

from __future__ import annotations

import dataclasses
import pathlib
from typing import Literal

import numpy as np

from experiments import cli, paper_tables
from jaxpose.training.experiment import ExperimentConfig, cpu_recipe, paper_preset
from jaxpose.training.experiment import calibration_lines, mocap_calibration, on_training_calibration
from jaxpose.training.splits import Splits
from jaxpose.datasets.h36m import DETECTION_FILES, POSES_3D_FILE, TEST_SUBJECTS, TRAIN_SUBJECTS, load_h36m, subject_rigs


# The Stacked Hourglass detector was trained on MPII: its "Spine" is MPII's thorax (~200 mm from the
# mocap spine) and its "Head" MPII's head top (~120 mm from the mocap head).  A self-supervised
# lifter learns the detector's joints, so reports also give the errors without these two.
SH_MPII_JOINTS = ("Spine", "Head")


@dataclasses.dataclass(frozen=True)
class H36MData:
    """Human3.6M files and protocol (see jaxpose.datasets.h36m and docs/data.md)."""

    data_dir: pathlib.Path = pathlib.Path("data/h36m")
    """Folder of the Human3.6M files: the h36m.zip tree of Martinez et al. and/or VideoPose3D's npz files."""
    layout: Literal["auto", "martinez", "videopose3d"] = "auto"
    """3D poses: martinez (S*/MyPoses/3D_positions/*.h5), videopose3d (data_3d_h36m.npz), auto (martinez if present)."""
    detections: str = "cpn"
    """2D source: cpn (VideoPose3D's CPN npz, as the paper), sh (h36m.zip, 16 joints), gt, or a 2D .npz path."""
    cameras_path: pathlib.Path | None = None
    """Calibration the training subjects are triangulated and trained with: cameras.h5 or a jaxpose
    camera file, e.g. one recovered by `python -m jaxpose.calibrate`; None = the reference."""
    reference_cameras_path: pathlib.Path | None = None
    """Calibration of the motion capture, for the test samples' ground truth (and --data.detections gt):
    None = <data-dir>/cameras.h5 where it exists, else --data.cameras-path."""
    train_subjects: tuple[str, ...] = TRAIN_SUBJECTS
    """Subjects to train on (the standard protocol: S1 S5 S6 S7 S8)."""
    test_subjects: tuple[str, ...] = TEST_SUBJECTS
    """Subjects to evaluate on (the standard protocol: S9 S11)."""
    train_stride: int = 5
    """Keep every n-th frame of the subjects other than S9 and S11 (5: 50 -> 10 fps, as the paper)."""
    test_stride: int = 5
    """Keep every n-th frame of S9 and S11 (5: 50 -> 10 fps, as the paper)."""
    split: Literal["subjects", "trials"] = "subjects"
    """"subjects": train on --data.train-subjects, test on --data.test-subjects (the benchmark);
    "trials": the development protocol on --data.train-subjects alone: for every subject and
    action, the trial whose sequence name sorts first trains (e.g. "Walking") and the other
    trials test (e.g. "Walking 1"); --data.test-subjects must then be empty.  The training trials
    keep every --data.train-stride-th frame, the test trials every --data.test-stride-th."""


def load_splits(data: H36MData) -> Splits:
    """Train and test samples from one load; results are grouped by canonical action name."""
    overlap = sorted(set(data.train_subjects) & set(data.test_subjects))
    if overlap:
        raise ValueError(f"subjects {overlap} are in both --data.train-subjects and --data.test-subjects")
    if data.split == "trials" and data.test_subjects:
        raise ValueError("--data.split trials tests on other trials of --data.train-subjects: pass --data.test-subjects with no subject")
    reference = reference_calibration(data)
    trials = data.split == "trials"  # one subject's frames train and test: strides applied below
    dataset = load_h36m(
        data.data_dir,
        layout=data.layout,
        detections=data.detections,
        subjects=data.train_subjects + data.test_subjects,
        train_stride=1 if trials else data.train_stride,
        test_stride=1 if trials else data.test_stride,
        cameras_path=reference,
    )
    if trials:
        first = first_trials(dataset.samples.labels["subject"], dataset.samples.labels["action"], dataset.samples.labels["sequence"])
        train = first & (dataset.samples.labels["frame"] % data.train_stride == 0)
        test = ~first & (dataset.samples.labels["frame"] % data.test_stride == 0)
    else:
        train = np.isin(dataset.samples.labels["subject"], list(data.train_subjects))
        test = ~train
    train_set = dataset.subset(np.flatnonzero(train))
    return Splits(
        train=on_training_calibration(train_set, data.cameras_path, reference, subject_rigs, data.train_subjects),
        test=dataset.subset(np.flatnonzero(test)),
        group_label="action",
        detector_specific_joints=SH_MPII_JOINTS if data.detections == "sh" else (),
    )


def reference_calibration(data: H36MData) -> pathlib.Path:
    """The motion capture's calibration (see `H36MData.reference_cameras_path`)."""
    return mocap_calibration(data.reference_cameras_path, data.data_dir / "cameras.h5", data.cameras_path)


def first_trials(subjects: np.ndarray, actions: np.ndarray, sequences: np.ndarray) -> np.ndarray:
    """bool[N]: the samples of the trial whose sequence name sorts first among its subject's trials
    of the same action (the development protocol's training half)."""
    first = {}
    for subject, action, sequence in set(zip(subjects.tolist(), actions.tolist(), sequences.tolist())):
        key = (subject, action)
        first[key] = min(first.get(key, sequence), sequence)
    return np.array([first[s, a] == q for s, a, q in zip(subjects.tolist(), actions.tolist(), sequences.tolist())])


def expected_files(data: H36MData) -> str:
    """The files this configuration reads, for the error message when they are missing."""
    root = data.data_dir
    poses3d = {
        "martinez": f"{root}/<subject>/MyPoses/3D_positions/<Sequence>.h5 (Martinez et al.'s h36m.zip)",
        "videopose3d": f"{root}/{POSES_3D_FILE} (VideoPose3D)",
    }
    if data.layout == "auto":
        poses3d["auto"] = f"{poses3d['martinez']}, or else {poses3d['videopose3d']}"
    if data.detections == "sh":
        poses2d = f"{root}/<subject>/StackedHourglass/<Sequence>.<camera>.h5 (h36m.zip)"
    elif data.detections == "gt":
        poses2d = "none: the 3D poses projected through the cameras"
    elif data.detections in DETECTION_FILES:
        poses2d = f"{root}/{DETECTION_FILES[data.detections]} (VideoPose3D)"
    else:
        poses2d = str(data.detections)
    subjects = f"{' '.join(data.train_subjects)} (train), {' '.join(data.test_subjects)} (test)"
    return "\n".join(
        [
            f"This run reads Human3.6M from --data.data-dir {root}:",
            f"  3D poses (--data.layout {data.layout}):  {poses3d[data.layout]}",
            f"  2D (--data.detections {data.detections}):  {poses2d}",
            *calibration_lines(data.cameras_path, reference_calibration(data)),
            f"  subjects:  {subjects}",
        ]
    )


# Preset "cpu": the best recipe we measured that fits in 25 minutes on 2 CPU cores.  The arithmetic:
# - Training set: S1 S5 S6 S7 S8 at 10 fps = ~78k 4-view samples (~390k frames per camera at 50 fps;
#   ~312k single-view poses).  A "sample" below is one 4-view instant, as the runner counts them.
# - A width-512 lifter of two stages trained at ~2,200 samples/s on 2 cores, at batch 128 as at 512 (a
#   width-1024 one at about a third of that): 30 epochs = 2.3M samples = ~17 min.  One stage (two
#   residual blocks, Martinez et al.'s depth) trains 1.8-2.2x as fast: 70 epochs of a full-size
#   stand-in's 72k samples (5.0M) at ~4,300 samples/s took 19 min 38 s in all, so the real 78k (5.4M)
#   about 21 min (docs/benchmarks.md "The recipe searched again"; on the development split 107 s
#   against 104 s for 30 epochs of two stages).
# - One stage for 70 epochs rather than two for 30, the same time (issue 36, development split, seeds
#   0 / 1): ground-truth 2D 36.2 / 36.3 against 41.3 / 41.3 mm P-MPJPE, SH 79.5 / 80.0 against
#   81.1 / 81.3 (80.9 re-run); 55 epochs of one stage were 37.4 / 37.2 and 80.0 / 80.2.
# - Each choice below was measured on the development split (preset "dev", docs/benchmarks.md "Development
#   protocol"): batch 128 rather than 512 (4x the steps for the same samples at the same
#   samples/s: -2.3 mm P-MPJPE self-supervised at 256, -3.6 mm at 128); dropout 0.1 rather than the
#   authors' 0.5 (a 30-epoch run is far from over-fitting: -14 mm self-supervised, -20 mm
#   supervised); RANSAC pseudo-labels with a pseudo-Huber label penalty (Stacked Hourglass and
#   CPN detections carry no usable confidence, and a left/right swap in two views otherwise
#   becomes a label: -1.9 mm); `RESCALED_LOSS`, so that L_con and L_out act at all (their accuracy
#   effect there is within the seed spread; docs/benchmarks.md "Development protocol").  Frames per epoch: every 5th frame (10 fps) for 30 epochs
#   was as good as every frame for 6 epochs (84.2 vs 84.0 mm) and triangulates 5x fewer frames.
# - Cosine decay after a warm-up of ~4% of the steps ends the short run at a low learning rate.
CPU = cpu_recipe(H36MData(), warmup_steps=1700, run_dir="runs/h36m_cpu")

# The cpu recipe's budget in samples seen: on the full benchmark 70 epochs x 606 steps x batch 128 =
# 5,429,760 samples, about the time of the two-stage recipe's 2.3M (docs/benchmarks.md).  A preset of
# the same recipe on data of another size caps at it (--train.max-samples) so as to take no longer.
CPU_SAMPLES = 5_400_000

# Preset "paper": Sec. IV-A of the paper (`paper_preset`): batch 8192, 500 epochs, CPN detections.
# ~9 steps per epoch, ~4,750 steps of ~10 s each on 2 CPU cores: a job for an accelerator.
PAPER = paper_preset(H36MData(), batch_size=8192, epochs=500, checkpoint_every=250, run_dir="runs/h36m_paper")

# Preset "dev": the development protocol on one subject (e.g. S1 of the h36m.zip tree), one trial of
# every action to train and the other to test, Stacked Hourglass detections, the cpu preset's
# recipe at a proportional budget: the same epochs over ~6k training samples, so ~1,400 steps and a
# warm-up scaled to the same ~4% of them.  About 2 minutes on 2 cores.
DEV = cpu_recipe(
    H36MData(detections="sh", train_subjects=("S1",), test_subjects=(), split="trials"), warmup_steps=150, run_dir="runs/h36m_dev"
)

PRESETS: dict[str, ExperimentConfig] = {"cpu": CPU, "paper": PAPER, "dev": DEV}
PRESET_NOTES = {
    "cpu": "the cpu recipe: ~21 min on 2 CPU cores",
    "paper": "Sec. IV-A of the paper",
    "dev": "the cpu recipe on the development protocol (S1 only, the first trial of each action trains, the other tests; SH 2D): ~2 min",
}
DEFAULT = CPU
EXPERIMENT = cli.Experiment(
    name="h36m",
    presets=PRESETS,
    preset_notes=PRESET_NOTES,
    load_splits=load_splits,
    expected_files=expected_files,
    paper_table=paper_tables.H36M_TABLE_II,
)


def main(argv: list[str] | None = None) -> dict:
    return cli.main(EXPERIMENT, argv, __doc__)


if __name__ == "__main__":
    main()
