"""HumanEva-I in VideoPose3D's layout: 3 views, 15 joints (`HUMANEVA_15`), 60 fps.

Files in `data_dir` (docs/conventions.md)::

    data_3d_humaneva15.npz            positions_3d: "Train/S1" -> "Walk 1 chunk0" -> f32[N, 15, 3] world m
    data_2d_humaneva15_<source>.npz   positions_2d: same keys -> 3 x f32[N, 15, 2] pixels (C1, C2, C3)
    cameras.json                      a jaxpose camera file (`jaxpose.formats.camera_file`) with subjects
                                      "S1".."S3", cameras "C1", "C2", "C3" (used for both partitions)

Protocol: the training split is Train/S1-S3, all actions; the test split Validate/S1-S3, Walk and
Jog only.  The motion capture loses markers now and then: frames whose 3D has a NaN or an all-zero
joint, or whose 2D has a NaN, are dropped (their count is logged).  Labels: "subject" ("S1"),
"action" ("Walk"), "sequence" ("Walk 1 chunk0"), "frame" (row of the sequence's arrays).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from jaxpose.formats.camera_file import load_cameras, select_views
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.formats.errors import DataFormatError
from jaxpose.datasets.sequences import CapturedSequence, PlannedSequence, SequencePlan, build_dataset, stack_views
from jaxpose.datasets.videopose3d import load_positions, subject_poses3d, subject_views2d
from jaxpose.skeleton import HUMANEVA_15

logger = logging.getLogger(__name__)

TRAIN_SUBJECTS = ("Train/S1", "Train/S2", "Train/S3")
TEST_SUBJECTS = ("Validate/S1", "Validate/S2", "Validate/S3")
TEST_ACTIONS = ("Walk", "Jog")
CAMERA_NAMES = ("C1", "C2", "C3")
POSES_3D_FILE = "data_3d_humaneva15.npz"


def load_humaneva(
    data_dir: str | Path,
    split: str = "train",
    *,
    detections: str | Path = "gt",
    subjects: tuple[str, ...] | None = None,
    cameras_path: str | Path | None = None,
    stride: int = 1,
    progress: bool = True,
) -> MultiViewDataset:
    """Load the HumanEva-I training or test split as a `MultiViewDataset` (world mm, pixels).

    split: "train" (Train/S1-S3, all actions) or "test" (Validate/S1-S3, Walk and Jog).
    subjects: a subset of the split's subjects (default: all three).  detections: "gt" (the 3D
    projected through the cameras, with distortion), a source name such as "detectron_pt_coco"
    (-> `data_2d_humaneva15_<source>.npz`), or the path of a 2D npz.  cameras_path: default
    `<data_dir>/cameras.json`.  stride: keep every stride-th frame.
    """
    data_dir = Path(data_dir)
    if split not in ("train", "test"):
        raise ValueError(f"split must be 'train' or 'test', got {split!r}")
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    split_subjects = TRAIN_SUBJECTS if split == "train" else TEST_SUBJECTS
    subjects = split_subjects if subjects is None else tuple(subjects)
    if not set(subjects) <= set(split_subjects):
        raise ValueError(f"subjects of the {split} split are {split_subjects}, got {subjects}")

    calibration_path = Path(cameras_path) if cameras_path else data_dir / "cameras.json"
    rigs = subject_rigs(calibration_path, subjects)
    path3d = data_dir / POSES_3D_FILE
    positions3d = load_positions(path3d, "positions_3d", "VideoPose3D HumanEva-I 3D poses")
    positions2d = None
    if detections != "gt":
        is_path = isinstance(detections, Path) or str(detections).endswith(".npz")
        path2d = Path(detections) if is_path else data_dir / f"data_2d_humaneva15_{detections}.npz"
        positions2d = load_positions(path2d, "positions_2d", "VideoPose3D HumanEva-I 2D keypoints")

    plan = SequencePlan("HumanEva-I", CAMERA_NAMES)
    for subject in subjects:
        poses = subject_poses3d(path3d, positions3d, subject, HUMANEVA_15.num_joints)
        views = {}
        if positions2d is not None:
            views = subject_views2d(path2d, positions2d, subject, CAMERA_NAMES, HUMANEVA_15.num_joints)
            plan.skip_2d_without_3d(subject, sorted(set(views) - set(poses)))
        for name in sorted(poses):
            if split == "test" and _action(name) not in TEST_ACTIONS:
                continue
            plan.add(subject, name, poses[name], None if positions2d is None else views.get(name, {}))
    sequences = plan.sequences(data_dir, f"HumanEva-I {split} sequences of {list(subjects)}")

    recordings, dropped = [], 0
    for sequence in tqdm(sequences, desc=f"HumanEva-I {split}", unit="seq", disable=not progress):
        recording, invalid = _read_recording(sequence, stride)
        recordings.append(recording)
        dropped += invalid
    kept = sum(len(r.kept) for r in recordings)
    logger.info(
        "HumanEva-I %s: dropped %d of %d frames with invalid markers (NaN or all-zero)", split, dropped, kept + dropped
    )
    if not kept:
        raise DataFormatError(data_dir, f"HumanEva-I {split} frames with valid markers", "none")
    return build_dataset(HUMANEVA_15, recordings, rigs)


# Canonical action names by prefix: releases spell HumanEva's walking trials both "Walk 1 chunk0"
# and "Walking 1 chunk0"; matching by prefix keeps them in the Walk/Jog test split either way.
_ACTION_PREFIXES = ("Walk", "Jog", "Box", "Gestures", "ThrowCatch")


def _action(sequence: str) -> str:
    """"Walk 1 chunk0" or "Walking 1 chunk0" -> "Walk"; unknown names keep their first word."""
    first = sequence.split(" ")[0]
    return next((prefix for prefix in _ACTION_PREFIXES if first.startswith(prefix)), first)


def subject_rigs(path: Path, subjects: tuple[str, ...]) -> dict:
    """{person ("S1"): its cameras C1-C3 (numpy `Cameras` [3])} for partition subjects ("Train/S1"),
    from a jaxpose camera file; the data set's "subject" labels are the persons."""
    calibration = load_cameras(path)
    rigs = {}
    for subject in subjects:
        person = subject.split("/")[-1]
        rigs[person] = select_views(calibration, path, person, CAMERA_NAMES)
    return rigs


def _read_recording(sequence: PlannedSequence, stride: int) -> tuple[CapturedSequence, int]:
    """One sequence, every frame, with its invalid frames dropped (the samples are the valid ones among every
    `stride`-th); also returns how many of those were dropped."""
    subject, name, poses = sequence.subject, sequence.name, sequence.poses3d
    frames = np.arange(len(poses), dtype=np.int32)
    points = poses.astype(np.float64) * 1000.0  # metres -> mm
    valid = np.isfinite(points).all((1, 2)) & ~(points == 0).all(-1).any(-1)
    keypoints = confidence = None
    if sequence.views is not None:
        keypoints, confidence = stack_views(f"HumanEva-I {subject} {name!r}", sequence.views, CAMERA_NAMES, len(poses), frames)
        valid &= np.isfinite(keypoints).all((1, 2, 3))
        keypoints, confidence = keypoints[valid], confidence[valid]
    recording = CapturedSequence(
        subject=subject.split("/")[-1],
        action=_action(name),
        sequence=name,
        frames=frames[valid],
        points3d=points[valid].astype(np.float32),
        keypoints2d=keypoints,
        confidence=confidence,
        kept=np.flatnonzero(frames[valid] % stride == 0),
    )
    return recording, int((~valid[::stride]).sum())
