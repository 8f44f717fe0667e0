"""MPI-INF-3DHP test set: single-view evaluation data (the paper trains on Human3.6M, tests here).

Files: `<data_dir>/TS1 .. TS6/annot_data.mat`, either kind of MATLAB file (v7.3 = HDF5, or the
older format), each with (MATLAB shapes, n frames):

    annot2               2 x 17 x 1 x n   pixels
    annot3               3 x 17 x 1 x n   camera frame, mm
    univ_annot3          3 x 17 x 1 x n   mm, scaled to the "universal" skeleton (the one evaluated)
    valid_frame          1 x n            1 = frame used for evaluation
    activity_annotation  1 x n            activity code 1..7 (`ACTIVITY_NAMES`)

Only valid frames are kept (2,935 in all six sequences, docs/conventions.md).  Joints are
re-ordered from the file's order (`FILE_JOINTS`) to `MPI_INF_3DHP_17`, whose joint k matches
`H36M_17` joint k.  The format facts of this data set were not checked against real files here.

Intrinsics.  The test set's README gives the cameras' physical parameters (facts; values as
distributed with the test set): studio sequences TS1-TS4, 2048 x 2048 px on a 10 x 10 mm sensor,
focal length 7.32506 mm, pixel aspect 1.00044, principal point offset (-0.0322884, 0.0929296) mm;
outdoor sequences TS5-TS6, 1920 x 1080 px on a 10 x 5.625 mm sensor, focal length 8.770747185 mm,
pixel aspect 0.993236423, offset (-0.104908645, 0.104899704) mm.  Our K (see `camera_intrinsics`):
fx = f W / sensor_w, fy = fx * pixel aspect, c = image centre + offset in pixels, i.e.

    TS1-TS4: fx 1500.172, fy 1500.832, cx 1017.387, cy 1043.032
    TS5-TS6: fx 1683.983, fy 1672.594, cx 939.858,  cy 560.141

The outdoor camera's lens distortion is not modelled: annot2 is used as given.
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import read_mat, real_array
from jaxpose.skeleton import MPI_INF_3DHP_17, Skeleton

SEQUENCES = ("TS1", "TS2", "TS3", "TS4", "TS5", "TS6")
ACTIVITY_NAMES = {
    1: "Stand/Walk",
    2: "Exercise",
    3: "Sit on Chair",
    4: "Reach/Crouch",
    5: "On Floor",
    6: "Sports",
    7: "Misc.",
}
# The file's joint order, in MPI_INF_3DHP_17's joint names.
FILE_JOINTS = (
    "HeadTop", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist",
    "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "Pelvis", "Spine", "Head",
)
_FILE_TO_OURS = np.array([FILE_JOINTS.index(name) for name in MPI_INF_3DHP_17.joint_names])

# Physical camera parameters of the test set (see the module docstring).
_STUDIO = dict(image=(2048, 2048), sensor=(10.0, 10.0), focal=7.32506, aspect=1.00044, offset=(-0.0322884, 0.0929296))
_OUTDOOR = dict(
    image=(1920, 1080), sensor=(10.0, 5.625), focal=8.770747185, aspect=0.993236423, offset=(-0.104908645, 0.104899704)
)
_CAMERA_OF = {"TS1": _STUDIO, "TS2": _STUDIO, "TS3": _STUDIO, "TS4": _STUDIO, "TS5": _OUTDOOR, "TS6": _OUTDOOR}


def camera_intrinsics(sequence: str) -> np.ndarray:
    """K (f64[3, 3], pixels) of a test sequence's camera, from the published physical parameters."""
    camera = _CAMERA_OF[sequence]
    (width, height), (sensor_w, sensor_h) = camera["image"], camera["sensor"]
    fx = camera["focal"] * width / sensor_w
    cx = width / 2 + camera["offset"][0] * width / sensor_w
    cy = height / 2 + camera["offset"][1] * height / sensor_h
    return np.array([[fx, 0.0, cx], [0.0, fx * camera["aspect"], cy], [0.0, 0.0, 1.0]])


@dataclasses.dataclass(frozen=True)
class MpiInf3dhpTestSet:
    """N valid test frames, single view, 17 joints in `MPI_INF_3DHP_17` order (root = pelvis).

    keypoints2d f32[N, 17, 2] pixels (annot2); univ3d f32[N, 17, 3] mm, universal skeleton,
    root-relative (the evaluation target); camera3d f32[N, 17, 3] mm in the camera frame (annot3);
    K f32[N, 3, 3]; activity i32[N] codes 1..7; activity_name, sequence ("TS1") str[N];
    frame i32[N] 0-based frame number in its sequence.
    """

    keypoints2d: np.ndarray
    univ3d: np.ndarray
    camera3d: np.ndarray
    K: np.ndarray
    activity: np.ndarray
    activity_name: np.ndarray
    sequence: np.ndarray
    frame: np.ndarray
    skeleton: Skeleton = MPI_INF_3DHP_17

    def __len__(self) -> int:
        return len(self.frame)


def load_mpi_inf_3dhp_test(
    data_dir: str | Path, sequences: Sequence[str] = SEQUENCES, progress: bool = True
) -> MpiInf3dhpTestSet:
    """Read the valid frames of the given test sequences (`<data_dir>/TS*/annot_data.mat`)."""
    data_dir = Path(data_dir)
    unknown = [s for s in sequences if s not in SEQUENCES]
    if unknown:
        raise ValueError(f"unknown MPI-INF-3DHP test sequences {unknown}; expected some of {SEQUENCES}")
    progress_bar = tqdm(sequences, desc="MPI-INF-3DHP", unit="seq", disable=not progress)
    parts = [_read_sequence(data_dir, name) for name in progress_bar]
    activity = np.concatenate([p["activity"] for p in parts])
    unknown_codes = sorted(set(activity.tolist()) - set(ACTIVITY_NAMES))
    if unknown_codes:
        known = sorted(ACTIVITY_NAMES)
        warnings.warn(f"MPI-INF-3DHP: activity codes {unknown_codes} are not among {known}", stacklevel=2)
    return MpiInf3dhpTestSet(
        keypoints2d=np.concatenate([p["keypoints2d"] for p in parts]),
        univ3d=np.concatenate([p["univ3d"] for p in parts]),
        camera3d=np.concatenate([p["camera3d"] for p in parts]),
        K=np.concatenate([p["K"] for p in parts]),
        activity=activity,
        activity_name=np.array([ACTIVITY_NAMES.get(code, f"activity {code}") for code in activity.tolist()], dtype=str),
        sequence=np.concatenate([np.full(len(p["frame"]), name) for p, name in zip(parts, sequences)]),
        frame=np.concatenate([p["frame"] for p in parts]),
    )


def _read_sequence(data_dir: Path, name: str) -> dict[str, np.ndarray]:
    path = data_dir / name / "annot_data.mat"
    fields = ("annot2", "annot3", "univ_annot3", "valid_frame", "activity_annotation")
    mat = {
        field: real_array(value, f"{path} {field}", "MPI-INF-3DHP test annotations")
        for field, value in read_mat(path, fields, "MPI-INF-3DHP test annotations").items()
    }
    valid = mat["valid_frame"].reshape(-1)
    count = len(valid)
    activity = mat["activity_annotation"].reshape(-1)
    if len(activity) != count:
        raise DataFormatError(f"{path} activity_annotation", f"{count} values (one per frame)", f"{len(activity)}")
    keep = np.flatnonzero(valid != 0)

    def joints(field: str, dims: int) -> np.ndarray:
        """MATLAB dims x 17 x 1 x n -> f32[n_valid, 17, dims] in our joint order."""
        array = np.asarray(mat[field], dtype=np.float64)
        if array.shape[:2] != (dims, 17) or int(np.prod(array.shape[2:])) != count:
            raise DataFormatError(f"{path} {field}", f"a {dims} x 17 x 1 x {count} array", f"shape {array.shape}")
        with np.errstate(over="ignore"):
            poses = array.reshape(dims, 17, count).transpose(2, 1, 0)[keep][:, _FILE_TO_OURS].astype(np.float32)
        bad = ~np.isfinite(poses).all((1, 2))
        if bad.any():  # a valid frame is evaluated: it must not carry a NaN into the metrics
            first = int(keep[np.argmax(bad)])
            found = f"NaN/inf (in float32) in {int(bad.sum())} valid frames, the first is frame {first}"
            raise DataFormatError(f"{path} {field}", "finite values in every valid frame", found)
        return poses

    univ = joints("univ_annot3", 3)
    return {
        "keypoints2d": joints("annot2", 2),
        "univ3d": univ - univ[:, :1],  # root-relative: joint 0 is the pelvis
        "camera3d": joints("annot3", 3),
        "K": np.broadcast_to(camera_intrinsics(name).astype(np.float32), (len(keep), 3, 3)),
        "activity": activity[keep].astype(np.int32),
        "frame": keep.astype(np.int32),
    }
