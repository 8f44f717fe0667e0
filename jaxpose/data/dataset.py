"""An in-memory multi-view data set and its batching.

Every loader (synthetic, Human3.6M, HumanEva-I, MPI-INF-3DHP) returns a `MultiViewDataset`: numpy
arrays with one row per synchronized instant, so shuffling moves whole multi-view samples and can
never mix views of different instants (the authors' release recovered views by reshaping rows).
Cameras are stored once per rig (a subject's calibration) and gathered per batch by `rig_index`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import Cameras, undistort_points
from jaxpose.data.batch import MultiViewBatch
from jaxpose.skeleton import Skeleton


@dataclasses.dataclass(frozen=True)
class MultiViewDataset:
    """N instants, C views, J joints; all arrays numpy float32 unless said otherwise.

    keypoints2d f32[N, C, J, 2] pixels; confidence f32[N, C, J]; rigs: `Cameras` of numpy arrays
    with leading [R, C]; rig_index i32[N]; target3d f32[N, J, 3] world mm or None; pseudo3d and
    pseudo3d_weight (f32[N, J, 3], f32[N, J]) once `jaxpose.pseudo_labelling.label` has set them, and detection_weight
    f32[N, C, J] when its method rejects outlying views (see `MultiViewBatch`); labels: per-sample
    string/int arrays such as "subject", "action", "frame" used to group evaluation results.
    """

    skeleton: Skeleton
    keypoints2d: np.ndarray
    confidence: np.ndarray
    rigs: Cameras
    rig_index: np.ndarray
    target3d: np.ndarray | None = None
    pseudo3d: np.ndarray | None = None
    pseudo3d_weight: np.ndarray | None = None
    detection_weight: np.ndarray | None = None
    labels: Mapping[str, np.ndarray] = dataclasses.field(default_factory=dict)

    def __post_init__(self):
        N, C, J, two = self.keypoints2d.shape
        if two != 2 or J != self.skeleton.num_joints:
            raise ValueError(
                f"keypoints2d: expected (N, C, {self.skeleton.num_joints}, 2) for skeleton {self.skeleton.name},"
                f" got {self.keypoints2d.shape}"
            )
        expected = {
            "confidence": (self.confidence, (N, C, J)),
            "rig_index": (self.rig_index, (N,)),
            "target3d": (self.target3d, (N, J, 3)),
            "pseudo3d": (self.pseudo3d, (N, J, 3)),
            "pseudo3d_weight": (self.pseudo3d_weight, (N, J)),
            "detection_weight": (self.detection_weight, (N, C, J)),
        }
        for name, (array, shape) in expected.items():
            if array is not None and array.shape != shape:
                raise ValueError(f"{name}: expected shape {shape}, got {array.shape}")
        if self.rigs.K.shape[1] != C:
            raise ValueError(f"rigs: {self.rigs.K.shape[1]} views per rig but keypoints2d has C={C}")
        if N and (self.rig_index.min() < 0 or self.rig_index.max() >= self.rigs.K.shape[0]):
            raise ValueError(f"rig_index: values must lie in [0, {self.rigs.K.shape[0]}), got {self.rig_index.max()}")
        for name, values in self.labels.items():
            if len(values) != N:
                raise ValueError(f"labels[{name!r}]: {len(values)} entries for {N} samples")

    def __len__(self) -> int:
        return self.keypoints2d.shape[0]

    @property
    def num_views(self) -> int:
        return self.keypoints2d.shape[1]

    def subset(self, indices: np.ndarray) -> "MultiViewDataset":
        def take(array):
            return None if array is None else array[indices]

        return dataclasses.replace(
            self,
            keypoints2d=self.keypoints2d[indices],
            confidence=self.confidence[indices],
            rig_index=self.rig_index[indices],
            target3d=take(self.target3d),
            pseudo3d=take(self.pseudo3d),
            pseudo3d_weight=take(self.pseudo3d_weight),
            detection_weight=take(self.detection_weight),
            labels={name: values[indices] for name, values in self.labels.items()},
        )

    def where(self, **label_values) -> "MultiViewDataset":
        """The samples whose labels are in the given values, e.g. `where(subject=["S9", "S11"])`."""
        keep = np.ones(len(self), dtype=bool)
        for name, values in label_values.items():
            keep &= np.isin(self.labels[name], np.asarray(values))
        return self.subset(np.flatnonzero(keep))

    def recalibrated(self, rigs: Mapping[str, Cameras]) -> "MultiViewDataset":
        """The same detections with each subject's rig replaced (`rigs[subject]`: numpy `Cameras` [C]).

        For training on a calibration recovered from the detections (`jaxpose.calibrate`): its world
        frame is not the motion capture's, so the 3D ground truth no longer fits and is dropped.
        """
        subjects = list(dict.fromkeys(self.labels["subject"].tolist()))
        missing = [subject for subject in subjects if subject not in rigs]
        if missing:
            raise ValueError(f"recalibrated: no rig for subjects {missing} (given: {sorted(rigs)})")
        stacked = jax.tree.map(lambda *fields: np.stack(fields), *[rigs[subject] for subject in subjects])
        index = {subject: i for i, subject in enumerate(subjects)}
        rig_index = np.array([index[subject] for subject in self.labels["subject"].tolist()], np.int32)
        return dataclasses.replace(self, rigs=stacked, rig_index=rig_index, target3d=None)

    def usable_view_count(self) -> np.ndarray:
        """i32[N]: views whose root and at least one other joint were detected (confidence > 0)."""
        return ((self.confidence[..., 0] > 0) & ((self.confidence[..., 1:] > 0).sum(-1) >= 1)).sum(-1)

    def cameras_for(self, indices: np.ndarray) -> Cameras:
        return jax.tree.map(lambda field: field[self.rig_index[indices]], self.rigs)

    def batch(self, indices: np.ndarray) -> MultiViewBatch:
        """Gather samples into a `MultiViewBatch` of numpy arrays (vectorized, no per-sample loop)."""
        if self.pseudo3d is None:
            raise ValueError("dataset has no pseudo-labels yet: label it with jaxpose.pseudo_labelling.label first")
        return MultiViewBatch(
            keypoints2d=self.keypoints2d[indices],
            confidence=self.confidence[indices],
            cameras=self.cameras_for(indices),
            pseudo3d=self.pseudo3d[indices],
            pseudo3d_weight=self.pseudo3d_weight[indices],
            detection_weight=None if self.detection_weight is None else self.detection_weight[indices],
            target3d=None if self.target3d is None else self.target3d[indices],
        )

    def undistorted(self) -> "MultiViewDataset":
        """Undistort the detections once on load and drop the distortion from the rigs.

        Everything downstream (triangulation, losses, the lifter input) is then pinhole, and no
        training step repeats the iterative undistortion.
        """
        if self.rigs.dist is None:
            return self
        cameras = self.cameras_for(np.arange(len(self)))
        points = np.asarray(jax.jit(undistort_points)(cameras, jnp.asarray(self.keypoints2d)))
        return dataclasses.replace(self, keypoints2d=points.astype(np.float32), rigs=self.rigs.without_distortion())


def epoch_order(num_samples: int, seed: int, epoch: int) -> np.ndarray:
    """The sample order of one epoch: a pure function of (seed, epoch), so a resumed run replays it."""
    return np.random.default_rng([seed, epoch]).permutation(num_samples)


def steps_per_epoch(num_samples: int, batch_size: int) -> int:
    """Full batches per epoch (the remainder is dropped so every step has one shape: one compile)."""
    if num_samples < batch_size:
        raise ValueError(f"batch size {batch_size} is larger than the training set ({num_samples} samples)")
    return num_samples // batch_size


def training_indices(num_samples: int, batch_size: int, seed: int, start_step: int = 0) -> Iterator[tuple[int, np.ndarray]]:
    """Endless (step, sample indices of the batch) stream from `start_step` on.

    Whole samples are shuffled every epoch by `epoch_order`, so the indices of a step depend only on
    (seed, step): a resumed run, or a process holding a slice of the batch, sees the same batches.
    """
    per_epoch = steps_per_epoch(num_samples, batch_size)
    step = start_step
    while True:
        epoch, offset = divmod(step, per_epoch)
        order = epoch_order(num_samples, seed, epoch)
        for position in range(offset, per_epoch):
            yield step, order[position * batch_size : (position + 1) * batch_size]
            step += 1
