"""Lifted 3D poses out to a file (`jaxpose.predict`'s output), one pose per input pose, in input order.

By suffix; poses are root-relative, in the camera frame (x right, y down, z forward), in mm unless said
otherwise:
- ``.json``: a list of {"image_id", "pose3d_mm": [[x, y, z] * J] or null, "joint_names"};
- ``.npz``: ``pose3d_mm`` f32[N, J, 3] (NaN rows), ``valid`` [N], ``image_id`` [N], ``joint_names`` [J];
- ``.csv``: a header row ``image_id,<joint>_x_mm,<joint>_y_mm,<joint>_z_mm,...``, then a row per pose with
  empty cells for a pose that could not be lifted;
- ``.trc`` (OpenSim markers, `jaxpose.formats.trc`): a data row per pose, Frame# from 1, Time = (Frame# - 1)
  / fps, a marker per joint (``/`` in a name becomes ``_``), Units m, empty fields for a pose that could
  not be lifted.  Its axes are OpenSim's for a subject facing the camera (X forward, Y up, Z to the
  subject's right): X = -z, Y = -y, Z = -x of the camera frame (a rotation of the camera axes), as line 1
  of the file says after the file name.  A TRC holds one subject: an input with several people per
  image gives a row per person, one after the other.
"""

from __future__ import annotations

import csv
import json
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from jaxpose.formats import trc
from jaxpose.formats.outputs import atomic_output

SUFFIXES = (".json", ".npz", ".csv", ".trc")
# The .trc axes from the camera frame's (x right, y down, z forward): X = -z, Y = -y, Z = -x, a rotation
# (determinant +1) to OpenSim's X forward, Y up, Z right for a subject who faces the camera.
TRC_AXES = np.array([[0, 0, -1], [0, -1, 0], [-1, 0, 0]], np.float32)
TRC_NOTE = "(jaxpose: root-relative; X=-z Y=-y Z=-x of the camera's x right y down z forward)"


def write_poses(path: Path, poses: np.ndarray, image_ids: list[Any], joint_names: Sequence[str], fps: float = 10.0) -> None:
    """Poses f32[N, J, 3] mm (NaN rows: not lifted) as the file `path` says by its suffix (`SUFFIXES`, see
    the module docstring); `fps` is the TRC's rate.  Written to a temporary name renamed into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    valid = np.isfinite(poses).all((1, 2))
    if path.suffix == ".npz":
        with atomic_output(path) as temporary:
            np.savez(temporary, pose3d_mm=poses, valid=valid, image_id=np.asarray(image_ids),
                     joint_names=np.asarray(joint_names))  # fmt: skip
        return
    if path.suffix == ".trc":
        if len(set(image_ids)) < len(image_ids):
            warnings.warn(
                f"{path}: several poses share an image id; the TRC gets a row per pose, one after the other",
                stacklevel=2,
            )
        metres = np.where(valid[:, None, None], poses, np.nan) @ TRC_AXES.T / 1000.0
        trc.write_trc(path, metres, joint_names, fps, units="m", path_note=TRC_NOTE)
        return
    # 0.01 mm is far below any pose error; float64 first so the text holds no float32 round-off digits.
    rounded = np.round(poses.astype(np.float64), 2)
    if path.suffix == ".csv":
        header = ["image_id"] + [f"{joint}_{axis}_mm" for joint in joint_names for axis in "xyz"]
        with atomic_output(path) as temporary, open(temporary, "w", newline="") as file:
            writer = csv.writer(file, lineterminator="\n")
            writer.writerow(header)
            for image_id, pose, ok in zip(image_ids, rounded, valid):
                writer.writerow([image_id, *(pose.ravel().tolist() if ok else [""] * pose.size)])
        return
    records = [
        {"image_id": image_id, "pose3d_mm": pose.tolist() if ok else None, "joint_names": list(joint_names)}
        for image_id, pose, ok in zip(image_ids, rounded, valid)
    ]
    with atomic_output(path) as temporary:
        temporary.write_text(json.dumps(records))
