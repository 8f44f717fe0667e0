"""An in-memory multi-view data set and its batching.

Every loader (synthetic, Human3.6M, HumanEva-I, MPI-INF-3DHP) returns a `MultiViewDataset`: numpy
arrays with one row per synchronized instant, so shuffling moves whole multi-view samples and can
never mix views of different instants (the authors' release recovered views by reshaping rows).
Cameras are stored once per rig (a subject's calibration) and gathered per batch by `rig_index`.
A data set can also carry every frame of the recordings its samples come from (`FrameContext`), so that
a temporal lifter's window can be cut around any sample however the samples were thinned.

The per-sample arrays are one pytree, `jaxpose.data.samples.Samples`, which alone lists them; code reads
them as `dataset.samples.keypoints2d`, not through accessors here: accessors would list every field a
second time, and the explicit `samples.` tells a per-sample array from what the samples share (skeleton,
rigs, context).  `with_samples` replaces some of them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence

import jax
import numpy as np

from jaxpose.camera import Cameras, undistort_compiled
from jaxpose.chunks import map_in_chunks
from jaxpose.data.batch import MultiViewBatch
from jaxpose.data.samples import Samples, check_shapes
from jaxpose.skeleton import Skeleton


@dataclasses.dataclass(frozen=True)
class FrameContext:
    """Every frame of a data set's recordings, in recording order: keypoints2d f32[M, C, J, 2] pixels,
    confidence f32[M, C, J].  Shared, not copied, by the subsets of one data set."""

    keypoints2d: np.ndarray
    confidence: np.ndarray


def window_rows(row: np.ndarray, span: np.ndarray, window: int) -> np.ndarray:
    """Context rows of the `window` frames centred on each sample: row i32[N] (the sample's own frame),
    span i32[N, 2] (first and one-past-last row of its stretch of consecutive frames) -> i32[N, window].
    Frames beyond the stretch's ends repeat its edge frame (VideoPose3D's padding)."""
    half = window // 2
    return np.clip(row[:, None] + np.arange(-half, half + 1), span[:, :1], span[:, 1:] - 1)


def consecutive_spans(labels: Mapping[str, np.ndarray]) -> np.ndarray:
    """i32[N, 2]: for rows in recording order, the first and one-past-last row of each row's stretch of
    consecutive frames (same subject and sequence, frame numbers increasing by 1)."""
    frame = labels["frame"].astype(np.int64)
    N = len(frame)
    starts = np.ones(N, bool)
    starts[1:] = frame[1:] != frame[:-1] + 1
    for name in ("subject", "sequence"):
        if name in labels:
            starts[1:] |= labels[name][1:] != labels[name][:-1]
    first = np.maximum.accumulate(np.where(starts, np.arange(N), 0))
    boundaries = np.append(np.flatnonzero(starts), N)
    end = boundaries[np.searchsorted(boundaries, np.arange(N), side="right")]
    return np.stack([first, end], -1).astype(np.int32)


@dataclasses.dataclass(frozen=True)
class MultiViewDataset:
    """N instants seen by C views, J joints: their per-sample arrays (`samples`, see `Samples`), and what
    they share: the skeleton, the `rigs` (`Cameras` of numpy arrays with leading [R, C], gathered per sample
    by `samples.rig_index`) and the `context`: every frame of the samples' recordings, which each sample's
    context rows point into (`window_rows`); None where the loader keeps no full-rate 2D (then only the
    frame lifter trains on it).
    """

    skeleton: Skeleton
    rigs: Cameras
    samples: Samples
    context: FrameContext | None = None

    def __post_init__(self):
        samples = self.samples
        N, C, J, two = samples.keypoints2d.shape
        if two != 2 or J != self.skeleton.num_joints:
            raise ValueError(
                f"keypoints2d: expected (N, C, {self.skeleton.num_joints}, 2) for skeleton {self.skeleton.name},"
                f" got {samples.keypoints2d.shape}"
            )
        check_shapes(samples, C, J)
        if self.rigs.K.shape[1] != C:
            raise ValueError(f"rigs: {self.rigs.K.shape[1]} views per rig but keypoints2d has C={C}")
        if N and (samples.rig_index.min() < 0 or samples.rig_index.max() >= self.rigs.K.shape[0]):
            raise ValueError(f"rig_index: values must lie in [0, {self.rigs.K.shape[0]}), got {samples.rig_index.max()}")
        if (self.context is None) != (samples.context_row is None) or (self.context is None) != (samples.context_span is None):
            raise ValueError("context, context_row and context_span: all three or none")
        if self.context is not None and self.context.keypoints2d.shape[1:] != (C, J, 2):
            raise ValueError(f"context.keypoints2d: expected (M, {C}, {J}, 2), got {self.context.keypoints2d.shape}")

    def with_samples(self, **arrays) -> "MultiViewDataset":
        """This data set with the per-sample `arrays` (fields of `Samples`) replaced."""
        return dataclasses.replace(self, samples=dataclasses.replace(self.samples, **arrays))

    def with_own_context(self) -> "MultiViewDataset":
        """This data set, whose samples are every frame of its recordings in order, as its own context:
        subsets taken afterwards (a stride, a split) keep the frames between their samples for windows."""
        samples = self.samples
        rows = np.arange(len(self), dtype=np.int32)
        return dataclasses.replace(
            self,
            context=FrameContext(samples.keypoints2d, samples.confidence),
            samples=dataclasses.replace(samples, context_row=rows, context_span=consecutive_spans(samples.labels)),
        )

    def windows(self, indices: np.ndarray, window: int) -> tuple[np.ndarray, np.ndarray]:
        """The `window` frames centred on each of the samples `indices`, every view: keypoints2d
        f32[n, C, window, J, 2] and confidence f32[n, C, window, J] (`window_rows`)."""
        if self.context is None:
            raise ValueError(
                f"a temporal window of {window} frames needs each recording's frames in order, and this data set"
                " keeps none (its loader gives single frames): use --model.temporal-window 1"
            )
        rows = window_rows(self.samples.context_row[indices], self.samples.context_span[indices], window)
        return (
            np.moveaxis(self.context.keypoints2d[rows], 1, 2),
            np.moveaxis(self.context.confidence[rows], 1, 2),
        )

    def __len__(self) -> int:
        return self.samples.keypoints2d.shape[0]

    @property
    def num_views(self) -> int:
        return self.samples.keypoints2d.shape[1]

    def subset(self, indices: np.ndarray) -> "MultiViewDataset":
        """The samples `indices`, copied; every sample in order is the data set itself (a memory-mapped
        data set then stays on disk)."""
        if len(indices) == len(self) and np.array_equal(indices, np.arange(len(self))):
            return self
        return dataclasses.replace(self, samples=jax.tree.map(lambda array: array[indices], self.samples))

    def where(self, **label_values) -> "MultiViewDataset":
        """The samples whose labels are in the given values, e.g. `where(subject=["S9", "S11"])`."""
        keep = np.ones(len(self), dtype=bool)
        for name, values in label_values.items():
            keep &= np.isin(self.samples.labels[name], np.asarray(values))
        return self.subset(np.flatnonzero(keep))

    def recalibrated(self, rigs: Mapping[str, Cameras]) -> "MultiViewDataset":
        """The same detections with each subject's rig replaced (`rigs[subject]`: numpy `Cameras` [C]).

        For training on a calibration recovered from the detections (`jaxpose.calibrate`): its world
        frame is not the motion capture's, so the 3D ground truth no longer fits and is dropped.
        """
        of_sample = self.samples.labels["subject"].tolist()
        subjects = list(dict.fromkeys(of_sample))
        missing = [subject for subject in subjects if subject not in rigs]
        if missing:
            raise ValueError(f"recalibrated: no rig for subjects {missing} (given: {sorted(rigs)})")
        stacked = jax.tree.map(lambda *fields: np.stack(fields), *[rigs[subject] for subject in subjects])
        index = {subject: i for i, subject in enumerate(subjects)}
        rig_index = np.array([index[subject] for subject in of_sample], np.int32)
        return dataclasses.replace(self.with_samples(rig_index=rig_index, target3d=None), rigs=stacked)

    def usable_view_count(self) -> np.ndarray:
        """i32[N]: views whose root and at least one other joint were detected (confidence > 0)."""
        confidence = self.samples.confidence
        return ((confidence[..., 0] > 0) & ((confidence[..., 1:] > 0).sum(-1) >= 1)).sum(-1)

    def cameras_for(self, indices: np.ndarray) -> Cameras:
        return jax.tree.map(lambda field: field[self.samples.rig_index[indices]], self.rigs)

    def batch(self, indices: np.ndarray, window: int = 1) -> MultiViewBatch:
        """Gather samples into a `MultiViewBatch` of numpy arrays (vectorized, no per-sample loop), with
        the lifter's input windows of `window` frames where it is > 1."""
        samples = self.samples
        if samples.pseudo3d is None:
            raise ValueError("dataset has no pseudo-labels yet: label it with jaxpose.training.pseudo_labelling.label first")
        window2d, window_confidence = self.windows(indices, window) if window > 1 else (None, None)
        return MultiViewBatch(
            window2d=window2d,
            window_confidence=window_confidence,
            keypoints2d=samples.keypoints2d[indices],
            confidence=samples.confidence[indices],
            cameras=self.cameras_for(indices),
            pseudo3d=samples.pseudo3d[indices],
            pseudo3d_weight=samples.pseudo3d_weight[indices],
            detection_weight=None if samples.detection_weight is None else samples.detection_weight[indices],
            target3d=None if samples.target3d is None else samples.target3d[indices],
        )

    def undistorted(self) -> "MultiViewDataset":
        """Undistort the detections once on load and drop the distortion from the rigs.

        Everything downstream (triangulation, losses, the lifter input) is then pinhole, and no
        training step repeats the iterative undistortion.
        """
        if self.rigs.dist is None:
            return self
        samples = self.samples
        points = _undistort(self.rigs, samples.rig_index, samples.keypoints2d)
        # A detection the lens model cannot undistort (far outside the image: NaN) is undetected.
        placed = np.isfinite(points).all(-1)
        confidence = np.where(placed, samples.confidence, 0.0).astype(samples.confidence.dtype) if not placed.all() else samples.confidence
        points = np.where(placed[..., None], points, 0.0).astype(np.float32) if not placed.all() else points
        dataset = dataclasses.replace(self.with_samples(keypoints2d=points, confidence=confidence), rigs=self.rigs.without_distortion())
        if self.context is None:
            return dataset
        # Only the frames some sample's window can reach, each through the rig of a sample that reaches it.
        dataset = self._compact_context(dataset)
        context = _undistort(self.rigs, self._context_rig_index(dataset), dataset.context.keypoints2d)
        placed = np.isfinite(context).all(-1)
        fields = {"keypoints2d": np.where(placed[..., None], context, 0.0).astype(np.float32)}
        if not placed.all():
            fields["confidence"] = np.where(placed, dataset.context.confidence, 0.0).astype(dataset.context.confidence.dtype)
        return dataclasses.replace(dataset, context=dataclasses.replace(dataset.context, **fields))

    @staticmethod
    def _compact_context(dataset: "MultiViewDataset") -> "MultiViewDataset":
        """`dataset` with its context reduced to the stretches its samples lie in."""
        M = len(dataset.context.keypoints2d)
        samples = dataset.samples
        edges = np.zeros(M + 1, np.int64)
        spans = np.unique(samples.context_span, axis=0)
        np.add.at(edges, spans[:, 0], 1)
        np.add.at(edges, spans[:, 1], -1)
        used = np.cumsum(edges[:M]) > 0
        new_row = (np.cumsum(used) - 1).astype(np.int32)
        span = np.stack([new_row[samples.context_span[:, 0]], new_row[samples.context_span[:, 1] - 1] + 1], -1)
        context = FrameContext(dataset.context.keypoints2d[used], dataset.context.confidence[used])
        renumbered = dataclasses.replace(samples, context_row=new_row[samples.context_row], context_span=span.astype(np.int32))
        return dataclasses.replace(dataset, context=context, samples=renumbered)

    @staticmethod
    def _context_rig_index(dataset: "MultiViewDataset") -> np.ndarray:
        """i32[M]: each context row's rig, that of a sample whose stretch contains it (all of a stretch's
        samples come from one recording, so one rig)."""
        spans, first = np.unique(dataset.samples.context_span, axis=0, return_index=True)
        rig = np.zeros(len(dataset.context.keypoints2d), np.int32)
        for (start, end), sample in zip(spans.tolist(), first.tolist()):
            rig[start:end] = dataset.samples.rig_index[sample]
        return rig


UNDISTORT_CHUNK = 4096  # instants per call of the compiled undistortion


def _undistort(rigs: Cameras, rig_index: np.ndarray, keypoints2d: np.ndarray) -> np.ndarray:
    """f32[N, C, J, 2] pixels of the rigs `rig_index` [N] undistorted, in fixed-size chunks (one compilation
    per chunk size, the lenses arguments), reading `keypoints2d` chunk by chunk (a memory-mapped array stays on disk)."""
    K, dist = np.asarray(rigs.K, np.float32), np.asarray(rigs.dist, np.float32)

    def chunk(rig_rows, points):
        return undistort_compiled(K[rig_rows], dist[rig_rows], points, model=rigs.distortion_model)

    return map_in_chunks(chunk, (rig_index, keypoints2d), UNDISTORT_CHUNK).astype(np.float32, copy=False)


def concatenate(parts: Sequence[MultiViewDataset]) -> MultiViewDataset:
    """One data set of parts that share skeleton and rigs and have the same per-sample fields (the same
    labels' names); their contexts (shared or not) are joined with the rows renumbered."""
    contexts, offsets, renumbered = [], {}, []
    for part in parts:
        samples = part.samples
        if part.context is not None:
            if id(part.context) not in offsets:
                offsets[id(part.context)] = sum(len(c.keypoints2d) for c in contexts)
                contexts.append(part.context)
            offset = offsets[id(part.context)]
            samples = dataclasses.replace(
                samples, context_row=(samples.context_row + offset).astype(np.int32), context_span=(samples.context_span + offset).astype(np.int32)
            )
        renumbered.append(samples)
    if contexts and any(part.context is None for part in parts):
        raise ValueError("concatenate: either every part has a frame context or none has")
    for field in dataclasses.fields(Samples):
        structures = {str(jax.tree.structure(getattr(samples, field.name))) for samples in renumbered}
        if len(structures) > 1:
            raise ValueError(f"concatenate: the parts differ in {field.name} (None in some, or other labels): {sorted(structures)}")
    context = None
    if contexts:
        context = FrameContext(
            np.concatenate([c.keypoints2d for c in contexts]), np.concatenate([c.confidence for c in contexts])
        )
    samples = jax.tree.map(lambda *arrays: np.concatenate(arrays), *renumbered)
    return dataclasses.replace(parts[0], samples=samples, context=context)


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
