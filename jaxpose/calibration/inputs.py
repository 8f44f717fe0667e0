"""What rig calibration reads: one subject's synchronized multi-view detections, and where they come from.

Two sources: an ``.npz`` written by any detector pipeline (`read_detections_npz`, format below), or a subject of
a data set jaxpose already loads (`from_dataset`, e.g. Human3.6M's S1 with its known intrinsics).

The ``.npz`` arrays:

- ``keypoints`` f32[N, C, J, 2]: pixels (as detected, i.e. distorted), N synchronized frames, C views;
- ``confidence`` f32[N, C, J] (optional, default 1): 0 = not detected;
- ``camera_names`` str[C]; ``image_size`` int[C, 2] (width, height) pixels;
- ``skeleton``: a skeleton name of `jaxpose.skeleton` (e.g. "h36m16", "h36m17", "coco17");
- ``K`` f32[C, 3, 3], ``dist`` f32[C, 5] and ``distortion_model`` ("opencv", the default, or "h36m"),
  all optional, where the intrinsics are known.  Without ``K`` the focal lengths are estimated.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from jaxpose.formats.camera_file import DISTORTION_MODELS
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import read_npz_arrays
from jaxpose.skeleton import SKELETONS, Skeleton, get_skeleton


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
        def fail(field: str, expected: str, found: str):
            raise DataFormatError(f"{self.source}, field {field!r}", expected, found)

        if self.keypoints.ndim != 4 or self.keypoints.shape[-1] != 2:
            fail("keypoints", "shape [N, C, J, 2] (pixels)", f"shape {self.keypoints.shape}")
        N, C, J, _ = self.keypoints.shape
        if C < 2:
            fail("keypoints", "at least 2 views (axis 1 of [N, C, J, 2]) to calibrate a rig", f"C = {C}")
        if J != self.skeleton.num_joints:
            fail("keypoints", f"{self.skeleton.num_joints} joints of skeleton {self.skeleton.name!r}", f"J = {J}")
        if self.confidence.shape != (N, C, J):
            fail("confidence", f"shape [N, C, J] = {(N, C, J)}", f"shape {self.confidence.shape}")
        if not np.all(np.isfinite(self.confidence)) or np.any(self.confidence < 0):
            fail("confidence", "finite values >= 0", "NaN, infinite or negative values")
        bad = (self.confidence > 0) & ~np.all(np.isfinite(self.keypoints), axis=-1)
        if bad.any():
            n, c, j = np.argwhere(bad)[0]
            fail(
                "keypoints",
                "finite pixels wherever confidence > 0 (give a missing joint confidence 0)",
                f"{int(bad.sum())} NaN/infinite keypoints with positive confidence, the first at frame {n},"
                f" view {c} ({self.camera_names[c] if c < len(self.camera_names) else c}),"
                f" joint {self.skeleton.joint_names[j]!r}",
            )
        if len(self.camera_names) != C:
            fail("camera_names", f"{C} names (one per view)", f"{len(self.camera_names)}")
        if len(set(self.camera_names)) != C:
            fail("camera_names", "distinct names", f"{list(self.camera_names)}")
        if self.image_size.shape != (C, 2) or np.any(self.image_size <= 0):
            fail("image_size", f"[C, 2] = {(C, 2)} positive (width, height) pixels", f"{self.image_size.tolist()}")
        if self.K is not None and (self.K.shape != (C, 3, 3) or not np.all(np.isfinite(self.K))):
            fail("K", f"finite [C, 3, 3] = {(C, 3, 3)} intrinsics", f"shape {self.K.shape}, finite: {bool(np.all(np.isfinite(self.K)))}")
        if self.dist is not None:
            if self.K is None:
                fail("dist", "intrinsics K as well (distortion is applied in K's normalized coordinates)", "no K")
            if self.dist.shape != (C, 5) or not np.all(np.isfinite(self.dist)):
                fail("dist", f"finite [C, 5] = {(C, 5)} (k1, k2, p1, p2, k3)", f"shape {self.dist.shape}, finite: {bool(np.all(np.isfinite(self.dist)))}")
        if self.distortion_model not in DISTORTION_MODELS:
            fail("distortion_model", f"one of {DISTORTION_MODELS}", repr(self.distortion_model))

    def without_intrinsics(self) -> "RigDetections":
        """The same detections with K and dist withheld: the uncalibrated case (focal lengths estimated)."""
        return dataclasses.replace(self, K=None, dist=None)


def read_detections_npz(path: str | Path) -> RigDetections:
    """Read the ``.npz`` described in the module docstring; errors name the file and the array."""
    path = Path(path)
    arrays = read_npz_arrays(path, "multi-view detections for calibration")
    missing = [name for name in ("keypoints", "camera_names", "image_size", "skeleton") if name not in arrays]
    if missing:
        raise DataFormatError(path, f"arrays {missing} (see `python -m jaxpose.calibrate --help`)", f"only {sorted(arrays)}")
    skeleton_name = str(arrays["skeleton"])
    if skeleton_name not in SKELETONS:
        raise DataFormatError(f"{path}, array 'skeleton'", f"one of {sorted(SKELETONS)}", repr(skeleton_name))
    keypoints = np.asarray(arrays["keypoints"], np.float32)
    confidence = arrays.get("confidence")
    return RigDetections(
        keypoints=keypoints,
        confidence=np.ones(keypoints.shape[:-1], np.float32) if confidence is None else np.asarray(confidence, np.float32),
        camera_names=tuple(str(name) for name in np.atleast_1d(arrays["camera_names"])),
        image_size=np.asarray(arrays["image_size"]).astype(np.int64),
        skeleton=get_skeleton(skeleton_name),
        K=None if "K" not in arrays else np.asarray(arrays["K"], np.float64),
        dist=None if "dist" not in arrays else np.asarray(arrays["dist"], np.float64),
        distortion_model=str(arrays.get("distortion_model", "opencv")),
        source=str(path),
    )


def from_dataset(
    dataset: MultiViewDataset, subject: str, camera_names: tuple[str, ...], image_size: np.ndarray, source: str = "data set"
) -> RigDetections:
    """One subject of a loaded data set (its "subject" label), with its rig's intrinsics (see
    `RigDetections.without_intrinsics` for the uncalibrated case).

    The extrinsics of the data set are dropped: they are what calibration recovers.
    """
    rows = np.flatnonzero(dataset.labels["subject"] == subject)
    if not len(rows):
        raise DataFormatError(source, f"samples of subject {subject!r}", f"subjects {sorted(set(dataset.labels['subject']))}")
    rig_indices = np.unique(dataset.rig_index[rows])
    if len(rig_indices) != 1:
        raise ValueError(f"{source}: subject {subject!r} spans {len(rig_indices)} rigs; calibrate one rig at a time")
    rig = dataset.rigs[int(rig_indices[0])]
    return RigDetections(
        keypoints=dataset.keypoints2d[rows],
        confidence=dataset.confidence[rows],
        camera_names=tuple(camera_names),
        image_size=np.asarray(image_size, np.int64),
        skeleton=dataset.skeleton,
        K=np.asarray(rig.K, np.float64),
        dist=None if rig.dist is None else np.asarray(rig.dist, np.float64),
        distortion_model=rig.distortion_model,
        source=f"{source} subject {subject}",
    )
