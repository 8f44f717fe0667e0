"""What rig calibration reads: one subject's synchronized multi-view detections, and where they come from.

Two sources: a ``detections.npz`` written by any detector pipeline (`read_detections_npz`; the format
is `jaxpose.formats.detections_npz`'s), or a subject of a data set jaxpose already loads (`from_dataset`,
e.g. Human3.6M's S1 with its known intrinsics).  Without intrinsics (K) the focal lengths are estimated.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from jaxpose.data.dataset import MultiViewDataset
from jaxpose.formats import detections_npz
from jaxpose.formats.errors import DataFormatError
from jaxpose.skeleton import SKELETONS, Skeleton, get_skeleton

if TYPE_CHECKING:
    from jaxpose.calibration import CalibrationConfig


@dataclasses.dataclass(frozen=True)
class RigDetections:
    """One subject seen by a rig: N frames, C views, J joints (numpy).

    keypoints f32[N, C, J, 2] distorted pixels; confidence f32[N, C, J]; image_size i32[C, 2]
    (width, height); K f64[C, 3, 3] and dist f64[C, 5] where known (dist needs K).
    `__post_init__` checks every shape and value and names the field at fault (`source` says where
    the data came from, for the messages).
    """

    keypoints: np.ndarray
    confidence: np.ndarray
    camera_names: tuple[str, ...]
    image_size: np.ndarray
    skeleton: Skeleton
    K: np.ndarray | None = None
    dist: np.ndarray | None = None
    distortion_model: str = "opencv"
    source: str = "detections"

    def __post_init__(self):
        detections_npz.check(
            self.source, self.keypoints, self.confidence, self.camera_names, skeleton=self.skeleton.name,
            joint_names=self.skeleton.joint_names, image_size=self.image_size, K=self.K, dist=self.dist,
            distortion_model=self.distortion_model,
        )  # fmt: skip
        views = self.keypoints.shape[1]
        if views < 2:
            raise DataFormatError(f"{self.source}, field 'keypoints'", "at least 2 views (axis 1 of [N, C, J, 2]) to calibrate a rig", f"C = {views}")

    def without_intrinsics(self) -> "RigDetections":
        """The same detections with K and dist withheld: the uncalibrated case (focal lengths estimated)."""
        return dataclasses.replace(self, K=None, dist=None)


def read_detections_npz(path: str | Path, people: CalibrationConfig | None = None) -> RigDetections:
    """Read a ``detections.npz`` (`jaxpose.formats.detections_npz`) with the image sizes and the jaxpose
    skeleton calibration needs; errors name the file and the array.  With `people` (the calibration's
    config) a person axis [N, C, P, J, 2] is read too, its people matched across views by their epipolar
    geometry (`jaxpose.calibration.matching`, with the config's thresholds), one row per person and instant."""
    detections = detections_npz.read(path, required=("image_size", "skeleton"), people=people is not None)
    if detections.skeleton not in SKELETONS:
        raise DataFormatError(f"{path}, array 'skeleton'", f"one of {sorted(SKELETONS)}", repr(detections.skeleton))
    keypoints, confidence = detections.keypoints, detections.confidence
    if keypoints.ndim == 5:
        from jaxpose.calibration.matching import match_people
        from jaxpose.camera import undistort_compiled

        pixels = None
        if detections.dist is not None:  # the epipolar geometry holds for undistorted pixels
            N, C, P, J, _ = keypoints.shape
            rows = np.nan_to_num(keypoints).transpose(0, 2, 1, 3, 4).reshape(N * P, C, J, 2)
            undistorted = np.asarray(undistort_compiled(detections.K, detections.dist, rows, model=detections.distortion_model))
            pixels = undistorted.reshape(N, P, C, J, 2).transpose(0, 2, 1, 3, 4)
        matched = match_people(keypoints, confidence, threshold_px=people.ransac_threshold_px, min_joints=people.min_joints,
                               min_confidence=people.min_confidence, seed=people.seed, pixels=pixels)  # fmt: skip
        keypoints, confidence = matched.keypoints, matched.confidence
    return RigDetections(
        keypoints=keypoints,
        confidence=confidence,
        camera_names=detections.camera_names,
        image_size=detections.image_size,
        skeleton=get_skeleton(detections.skeleton),
        K=detections.K,
        dist=detections.dist,
        distortion_model=detections.distortion_model,
        source=detections.source,
    )


def from_dataset(
    dataset: MultiViewDataset, subject: str, camera_names: tuple[str, ...], image_size: np.ndarray, source: str = "data set"
) -> RigDetections:
    """One subject of a loaded data set (its "subject" label), with its rig's intrinsics (see
    `RigDetections.without_intrinsics` for the uncalibrated case).

    The extrinsics of the data set are dropped: they are what calibration recovers.
    """
    rows = np.flatnonzero(dataset.samples.labels["subject"] == subject)
    if not len(rows):
        raise DataFormatError(source, f"samples of subject {subject!r}", f"subjects {sorted(set(dataset.samples.labels['subject']))}")
    rig_indices = np.unique(dataset.samples.rig_index[rows])
    if len(rig_indices) != 1:
        raise ValueError(f"{source}: subject {subject!r} spans {len(rig_indices)} rigs; calibrate one rig at a time")
    rig = dataset.rigs[int(rig_indices[0])]
    return RigDetections(
        keypoints=dataset.samples.keypoints2d[rows],
        confidence=dataset.samples.confidence[rows],
        camera_names=tuple(camera_names),
        image_size=np.asarray(image_size, np.int64),
        skeleton=dataset.skeleton,
        K=np.asarray(rig.K, np.float64),
        dist=None if rig.dist is None else np.asarray(rig.dist, np.float64),
        distortion_model=rig.distortion_model,
        source=f"{source} subject {subject}",
    )
