"""The .npz files of VideoPose3D's data preparation, shared by the Human3.6M and HumanEva-I loaders.

- 3D: key `positions_3d`, a pickled dict subject -> sequence -> f32[N, J, 3] world METRES.
- 2D: key `positions_2d`, a pickled dict subject -> sequence -> list of C arrays f32[N, J, 2]
  pixels, one per camera in the data set's camera order (plus a `metadata` dict we do not need).

These readers validate the structure and shapes of one subject and return plain arrays.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import load_npz_object, real_array


def load_positions(path: Path, key: str, what: str) -> Mapping:
    """The subject -> sequence dict stored under `key` ("positions_3d" or "positions_2d")."""
    positions = load_npz_object(path, key, what)
    if not isinstance(positions, Mapping):
        raise DataFormatError(f"{path} {key}", "a pickled dict subject -> sequence -> arrays", type(positions).__name__)
    return positions


def _subject(path: Path, positions: Mapping, key: str, subject: str) -> Mapping:
    if subject not in positions:
        raise DataFormatError(f"{path} {key}", f"subject {subject!r}", f"subjects {sorted(positions)}")
    sequences = positions[subject]
    if not isinstance(sequences, Mapping):
        raise DataFormatError(f"{path} {key}[{subject!r}]", "a dict sequence -> arrays", type(sequences).__name__)
    return sequences


def subject_poses3d(path: Path, positions: Mapping, subject: str, num_joints: int) -> dict[str, np.ndarray]:
    """sequence -> f[N, J, 3] world metres (as stored), shapes checked."""
    poses = {}
    for name, array in _subject(path, positions, "positions_3d", subject).items():
        where = f"{path} positions_3d[{subject!r}][{name!r}]"
        array = real_array(array, where, f"f[N, {num_joints}, 3] metres")
        if array.ndim != 3 or array.shape[1:] != (num_joints, 3):
            raise DataFormatError(where, f"f[N, {num_joints}, 3] metres", f"shape {array.shape}")
        poses[name] = array
    return poses


def subject_views2d(
    path: Path, positions: Mapping, subject: str, camera_names: Sequence[str], num_joints: int
) -> dict[str, dict[str, np.ndarray]]:
    """sequence -> camera name -> f[N, J, 2] pixels; cameras without an array (None, empty or
    past the end of the list) are left out, so the caller can report them."""
    views = {}
    for name, arrays in _subject(path, positions, "positions_2d", subject).items():
        where = f"{path} positions_2d[{subject!r}][{name!r}]"
        if not isinstance(arrays, (list, tuple)) or len(arrays) > len(camera_names):
            found = f"{len(arrays)} items" if isinstance(arrays, (list, tuple)) else type(arrays).__name__
            raise DataFormatError(where, f"a list of {len(camera_names)} arrays (cameras {list(camera_names)})", found)
        views[name] = {}
        for camera, array in zip(camera_names, arrays):
            if array is None or len(array) == 0:
                continue
            expected = f"f[N, {num_joints}, 2] pixels"
            array = real_array(array, f"{where} camera {camera}", expected)
            if array.ndim != 3 or array.shape[1:] != (num_joints, 2):
                raise DataFormatError(f"{where} camera {camera}", expected, f"shape {array.shape}")
            views[name][camera] = array
    return views
