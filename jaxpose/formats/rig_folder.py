"""A rig project folder as files: the names its reader (`jaxpose.rig`) looks for and the example
writer (`jaxpose.synthetic.project`) writes, and the ground truth file, read and written here::

    PROJECT/
      calibration.toml            CALIBRATION_TOML: the name the writers give it (a reader finds any
                                  calibration file by its content)
      <recording>/
        detections.npz            DETECTIONS_NPZ (`jaxpose.formats.detections_npz`), or
        <camera>_json/            `json_folder(camera)`: OpenPose JSON frames of one camera
        ground_truth.npz          GROUND_TRUTH_NPZ, optional, evaluation only (`read_ground_truth`)

``ground_truth.npz``: ``points3d`` f32[N, J, 3] (one person) or f32[N, P, J, 3] (P people, NaN while a
person is out of the scene) world mm (the calibration's world frame), ``frames`` int[N] (the detections'
frame numbers), ``joint_names`` str[J] (matched to the detector's keypoints by name).  The person axis
is the people's identities, not the order in which any detection file lists them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import read_npz_arrays

CALIBRATION_TOML = "calibration.toml"
DETECTIONS_NPZ = "detections.npz"
GROUND_TRUTH_NPZ = "ground_truth.npz"
JSON_FOLDER_SUFFIX = "_json"


def json_folder(camera: str) -> str:
    """The folder of a camera's OpenPose JSON frames, named as OpenPose users and Pose2Sim name it."""
    return f"{camera}{JSON_FOLDER_SUFFIX}"


def folder_camera(folder_name: str) -> str:
    """The camera whose detections a folder holds: "cam01_json" and "cam01" are camera "cam01"."""
    return folder_name.removesuffix(JSON_FOLDER_SUFFIX)


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """A recording's ``ground_truth.npz``: points f64[N, P, J, 3] world mm (P = 1 for a file without a
    person axis), frames int64[N], joint names [J]."""

    points: np.ndarray
    frames: np.ndarray
    joint_names: tuple[str, ...]


def read_ground_truth(path: Path) -> GroundTruth:
    """Read and check a ``ground_truth.npz``; errors name the file and its arrays."""
    arrays = read_npz_arrays(path, "ground truth of one recording (evaluation only)")
    missing = [name for name in ("points3d", "frames", "joint_names") if name not in arrays]
    if missing:
        raise DataFormatError(path, f"arrays {missing} (points3d [N, (P,) J, 3] mm, frames [N], joint_names [J])", f"only {sorted(arrays)}")
    points = np.asarray(arrays["points3d"], np.float64)
    frames = np.asarray(arrays["frames"], np.int64)
    names = tuple(str(name) for name in np.atleast_1d(arrays["joint_names"]))
    if points.ndim == 3:
        points = points[:, None]  # one person
    if points.ndim != 4 or points.shape[2:] != (len(names), 3) or frames.shape != (len(points),):
        raise DataFormatError(
            path, "points3d [N, J, 3] or [N, P, J, 3], frames [N], joint_names [J] of matching sizes",
            f"points3d {points.shape}, frames {frames.shape}, {len(names)} joint names",
        )  # fmt: skip
    return GroundTruth(points=points, frames=frames, joint_names=names)


def write_ground_truth(path: Path, points3d: np.ndarray, frames: np.ndarray, joint_names: Sequence[str]) -> None:
    """Write a ``ground_truth.npz`` (points f32[N, J, 3] or [N, P, J, 3] world mm, frames int64[N])."""
    np.savez(path, points3d=np.asarray(points3d, np.float32), frames=np.asarray(frames, np.int64), joint_names=np.array(joint_names))
