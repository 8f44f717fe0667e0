"""From per-sequence arrays of a real data set to one `MultiViewDataset`.

The Human3.6M and HumanEva-I loaders match each subject's 3D sequences with their 2D in a
`SequencePlan` (which names the sequences skipped or kept with views missing), read the planned
sequences into `CapturedSequence`s (one subject's sequence, every frame, with the frames to keep as samples)
and hand them to `build_dataset`, which stacks them, attaches one rig per subject, where a recording
carries no 2D projects its 3D ground truth through the real cameras, and keeps every frame's 2D as the
samples' `FrameContext` (the windows of a temporal lifter).
"""

from __future__ import annotations

import dataclasses
import logging
import warnings
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxpose.camera import Cameras, project
from jaxpose.chunks import map_in_chunks
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.data.samples import Samples
from jaxpose.formats.errors import DataFormatError
from jaxpose.skeleton import Skeleton

logger = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class CapturedSequence:
    """n frames of one sequence seen by C cameras, J joints, of which those at `kept` become samples.

    frames: i32[n] frame numbers in the original recording; points3d: f32[n, J, 3] world mm;
    keypoints2d: f32[n, C, J, 2] pixels, or None for ground-truth 2D (projected from points3d);
    confidence: f32[n, C, J], 0 for a camera whose 2D is missing; None = 1 everywhere;
    kept: i32[k] rows of the samples (e.g. every 5th frame); None = every row.
    """

    subject: str
    action: str
    sequence: str
    frames: np.ndarray
    points3d: np.ndarray
    keypoints2d: np.ndarray | None
    confidence: np.ndarray | None = None
    kept: np.ndarray | None = None


def build_dataset(skeleton: Skeleton, recordings: Sequence[CapturedSequence], rigs: Mapping[str, Cameras]) -> MultiViewDataset:
    """Stack recordings into a data set; `rigs[subject]` is that subject's `Cameras` [C] (numpy).

    Either every recording has keypoints2d or none has (then all 2D are projections of the 3D,
    with distortion).  Confidence is each recording's, else 1: the detection files carry no scores.
    The samples are the `kept` rows; every row's 2D stays as their context (`MultiViewDataset.windows`).
    """
    if not recordings:
        raise ValueError("build_dataset: no recordings")
    if len({r.keypoints2d is None for r in recordings}) > 1:
        raise ValueError("build_dataset: either all recordings carry 2D detections or none does")
    subjects = list(dict.fromkeys(r.subject for r in recordings))
    stacked = jax.tree.map(lambda *fields: np.stack(fields), *[rigs[s] for s in subjects])
    rig_of = {subject: index for index, subject in enumerate(subjects)}
    rig_index = np.concatenate([np.full(len(r.frames), rig_of[r.subject], np.int32) for r in recordings])
    target3d = np.concatenate([r.points3d for r in recordings]).astype(np.float32, copy=False)
    if recordings[0].keypoints2d is None:
        keypoints2d = project_to_views(stacked, rig_index, target3d)
    else:
        keypoints2d = np.concatenate([r.keypoints2d for r in recordings]).astype(np.float32, copy=False)
    views_and_joints = keypoints2d.shape[1:3]
    confidence = np.concatenate(
        [np.ones((len(r.frames), *views_and_joints), np.float32) if r.confidence is None else r.confidence for r in recordings]
    ).astype(np.float32, copy=False)

    def label(field):
        return np.concatenate([np.full(len(r.frames), getattr(r, field)) for r in recordings])

    labels = {
        "subject": label("subject"),
        "action": label("action"),
        "sequence": label("sequence"),
        "frame": np.concatenate([r.frames for r in recordings]).astype(np.int32),
    }
    samples = Samples(keypoints2d=keypoints2d, confidence=confidence, rig_index=rig_index, target3d=target3d, labels=labels)
    every_frame = MultiViewDataset(skeleton=skeleton, rigs=stacked, samples=samples).with_own_context()
    offsets = np.cumsum([0] + [len(r.frames) for r in recordings[:-1]])
    kept = [np.arange(len(r.frames)) if r.kept is None else np.asarray(r.kept) for r in recordings]
    return every_frame.subset(np.concatenate([offset + rows for offset, rows in zip(offsets, kept)]))


def project_to_views(rigs: Cameras, rig_index: np.ndarray, points3d: np.ndarray, chunk_size: int = 65536) -> np.ndarray:
    """Ground-truth 2D: world points f32[N, J, 3] through every camera of their rig -> f32[N, C, J, 2].

    Runs in fixed-size chunks (`jaxpose.chunks.map_in_chunks`) so that the projection compiles once.
    """
    project_chunk = jax.jit(lambda cameras, points: project(cameras, points[:, None]))

    def project_rows(rig_rows, points):
        return project_chunk(jax.tree.map(lambda field: field[rig_rows], rigs), points)

    return map_in_chunks(project_rows, (rig_index, points3d), chunk_size)


def stack_views(
    where: str, views: Mapping[str, np.ndarray], camera_names: Sequence[str], count: int, frames: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The kept `frames` of each camera's 2D (camera name -> f[N_c, J, 2]) in the order `camera_names`
    -> (keypoints f32[n, C, J, 2], confidence f32[n, C, J]).

    A camera absent from `views` (e.g. S11 "Directions" has no Stacked Hourglass file for camera
    54138969) keeps its place in the rig with coordinates 0 and confidence 0: its view is missing,
    the other views of the sequence stay usable.  Each camera's 2D must cover the `count` frames of
    the 3D sequence; frames past its end are ignored (some published detection files run longer than
    the mocap).
    """
    if not views:
        raise ValueError(f"{where}: no camera has 2D")
    joints = next(iter(views.values())).shape[1]
    keypoints = np.zeros((len(frames), len(camera_names), joints, 2), np.float32)
    confidence = np.zeros((len(frames), len(camera_names), joints), np.float32)
    for index, camera in enumerate(camera_names):
        if camera not in views:
            continue
        view = views[camera]
        if len(view) < count:
            expected = f"2D for all {count} frames of the 3D sequence"
            raise DataFormatError(f"{where}, camera {camera}", expected, f"{len(view)} frames")
        if len(view) > count:
            logger.info("%s, camera %s: ignoring %d 2D frames past the end of the 3D", where, camera, len(view) - count)
        keypoints[:, index] = view[frames]
        confidence[:, index] = 1.0
    return keypoints, confidence


@dataclasses.dataclass(frozen=True)
class PlannedSequence:
    """One sequence a loader will read: its 3D (an array, or a function reading it) and its cameras' 2D
    (camera name -> array or reader; None where the 2D is the projected ground truth)."""

    subject: str
    name: str
    poses3d: Any
    views: Mapping[str, Any] | None


class SequencePlan:
    """The sequences of a data set that have both 3D and 2D, in the order added.

    A sequence whose 2D is missing altogether, and 2D without a 3D sequence, are skipped; a sequence
    missing some cameras' 2D is kept (those views get confidence 0).  `sequences()` names both kinds
    in one warning each, attributed to the caller of the loader.
    """

    def __init__(self, dataset: str, camera_names: Sequence[str]):
        self.dataset = dataset
        self.camera_names = tuple(camera_names)
        self.planned: list[PlannedSequence] = []
        self.partial: list[str] = []
        self.skipped: list[str] = []

    def skip_2d_without_3d(self, subject: str, names: Iterable[str]) -> None:
        self.skipped += [f"{subject} {name!r} (2D without 3D)" for name in names]

    def add(self, subject: str, name: str, poses3d: Any, views: Mapping[str, Any] | None) -> None:
        """Plan one 3D sequence with its cameras' 2D (`views`; None for ground-truth 2D, empty when it has none)."""
        if views is not None:
            if not views:
                self.skipped.append(f"{subject} {name!r} (no 2D)")
                return
            missing = [camera for camera in self.camera_names if camera not in views]
            if missing:
                self.partial.append(f"{subject} {name!r} (no 2D for cameras {missing})")
        self.planned.append(PlannedSequence(subject, name, poses3d, views))

    def sequences(self, where: str | Path, expected: str) -> list[PlannedSequence]:
        """The planned sequences, after the warnings; `DataFormatError` (`expected` at `where`) if there are none."""
        if self.partial:
            message = f"{self.dataset}: {len(self.partial)} sequences miss some views, which get confidence 0: "
            warnings.warn(message + "; ".join(self.partial), stacklevel=3)
        if self.skipped:
            warnings.warn(f"{self.dataset}: skipped {len(self.skipped)} sequences: " + "; ".join(self.skipped), stacklevel=3)
        if not self.planned:
            raise DataFormatError(where, expected, "none with both 3D and 2D")
        return self.planned
