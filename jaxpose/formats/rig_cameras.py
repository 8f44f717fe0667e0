"""A calibrated rig as any calibration file gives it, what a kind of calibration file is, and the checks
every calibration reader applies.

`RigCalibration` is what `jaxpose.formats.calibration_files.read_rig_calibration` returns whatever the
file; `CalibrationFormat` is one kind of file (`anipose_toml`, `easymocap_yaml`, `camera_file` and
`h36m_cameras` each define one, and `calibration_files.FORMATS` lists them).  The length units a file may
be in, the rig-size check that catches a wrong unit, and the intrinsic-matrix and rotation-matrix checks
live here so that each reader words its errors the same way.

Conventions (docs/conventions.md): `x_cam = R @ x_world + t`, t in millimetres, distortion
`dist = (k1, k2, p1, p2, k3)` of OpenCV's model, or (k1, k2, k3, k4, 0) of its fisheye model
(`jaxpose.camera`).
"""

from __future__ import annotations

import dataclasses
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Literal

import numpy as np

from jaxpose.camera import Cameras, camera_centres
from jaxpose.formats.camera_names import CameraMismatch, match_cameras
from jaxpose.formats.errors import DataFormatError

__all__ = [
    "MIN_BASELINE_MM",
    "MM_PER_UNIT",
    "CalibrationFormat",
    "CalibrationUnit",
    "RigCalibration",
    "check_distinct_centres",
    "check_intrinsics",
    "check_rig_size",
    "check_rotation",
    "known_image_sizes",
    "millimetres_by_definition",
    "pick_subject",
    "rig_size",
]

CalibrationUnit = Literal["auto", "m", "cm", "mm"]
MM_PER_UNIT = {"m": 1000.0, "cm": 10.0, "mm": 1.0}
# A rig that films people: camera centres at least 10 cm and at most 200 m apart.
RIG_SIZE_RANGE_MM = (100.0, 200_000.0)
UNIT_FLAG = "--data.calibration-unit"
# Written matrices carry few digits: a rotation is accepted when R R^T is this close to I.
ROTATION_TOLERANCE = 1e-4
# Two views closer than this share one viewpoint: nothing can be triangulated between them.
MIN_BASELINE_MM = 1.0
# Intrinsics no camera has (pixels): a focal length under 1 px would see over 180 degrees, over 1e6 px
# a 1920-px image would span 0.1 degrees; pixels are square within a few percent (anamorphic lenses: 2x).
# K's condition number is about max(f, c^2 / f): ~1e3 in every real calibration; 1e7 takes a focal
# length under 1 px with the principal point 3,000 px away, and float32 keeps only 7 digits.
FOCAL_RANGE_PX = (1.0, 1e6)
ASPECT_RANGE = (0.25, 4.0)
MAX_CONDITION = 1e7


@dataclasses.dataclass(frozen=True, eq=False)
class RigCalibration:
    """One calibrated rig as read from a file.

    `cameras` holds float64 numpy fields with leading axis [C] in the library's conventions
    (`x_cam = R @ x_world + t`, t in millimetres; `dist` f64[C, 5] or None; `distortion_model`
    "opencv", "fisheye" or, from Human3.6M files, "h36m").  `image_size` is int64 [C, 2]
    (width, height) or None when the file has none; `source` names the file(s) read and `unit`
    the unit the file was read in ("m", "cm" or "mm").
    """

    camera_names: tuple[str, ...]
    cameras: Cameras
    image_size: np.ndarray | None
    source: str
    unit: str

    def select(self, names: Sequence[str], what: str) -> RigCalibration:
        """The cameras `names`, in that order, named so.

        A name is matched to the calibration's cameras as `jaxpose.formats.camera_names.match_cameras`
        says (``cam_01`` is ``int_cam01_img``; never by order); one without a camera, or with several,
        raises `DataFormatError` naming `self.source`, listing the calibration's camera names and
        `names`; `what` says where `names` come from (e.g. 'detection folders of recording walk1').
        """
        names = (names,) if isinstance(names, str) else tuple(str(name) for name in names)
        if not names:
            raise DataFormatError(self.source, f"at least one camera name from the {what}", "none")
        repeated = sorted({name for name in names if names.count(name) > 1})
        if repeated:
            raise DataFormatError(
                self.source, f"distinct camera names from the {what}", f"{repeated} more than once in {list(names)}"
            )
        try:
            matched = match_cameras(self.camera_names, names, self.source)
        except CameraMismatch as error:
            expected = f"a camera for every name of the {what}: {list(names)}"
            raise DataFormatError(self.source, expected, f"the calibration's {error}") from None
        index = np.array([self.camera_names.index(matched[name]) for name in names], dtype=np.int64)
        return dataclasses.replace(
            self,
            camera_names=names,
            cameras=self.cameras[index],
            image_size=None if self.image_size is None else self.image_size[index],
        )

    def rig_size_mm(self) -> float:
        """The largest distance between two camera centres, mm (0 for a single camera)."""
        return rig_size(self.cameras.R, self.cameras.t)


@dataclasses.dataclass(frozen=True)
class CalibrationFormat:
    """One kind of calibration file: what it is (for messages), the suffixes that name it, how a file in a
    folder is recognised as one, and its reader."""

    description: str
    suffixes: tuple[str, ...]
    recognise: Callable[[Path], bool] | None
    """Whether a file found in a folder is one, by its name or first bytes; None: never found in a folder,
    only read where it is named (a file of several subjects' rigs)."""
    read: Callable[[Path, "CalibrationUnit", str | None], RigCalibration]
    """(path, unit, subject) -> the rig: `unit` as `read_rig_calibration` takes it, `subject` for a file
    holding several rigs (`pick_subject`); a format that has no use for one ignores it."""


def pick_subject(path: Path, subjects: Sequence[str], subject: str | None) -> str:
    """The subject whose rig is read from a file holding several (`subject`; None: the file's only one)."""
    if subject is None:
        if len(subjects) == 1:
            return subjects[0]
        raise DataFormatError(path, "a subject to pick (the file holds several rigs)", f"subjects {list(subjects)}")
    if subject not in subjects:
        raise DataFormatError(path, f"the rig of subject {subject!r}", f"subjects {list(subjects)}")
    return subject


def millimetres_by_definition(path: Path, unit: CalibrationUnit) -> None:
    """Warn that `unit` is ignored for a file whose lengths are millimetres by definition (a camera file, cameras.h5)."""
    if unit not in ("auto", "mm"):
        warnings.warn(f"{path}: unit {unit!r} ignored: this file's lengths are millimetres by definition", stacklevel=4)


def known_image_sizes(sizes: Sequence[tuple[int, int] | None]) -> np.ndarray | None:
    """int64 [C, 2] of every camera's (width, height); None where some camera's is unknown."""
    return None if any(size is None for size in sizes) else np.array(sizes, dtype=np.int64)


def rig_size(R: np.ndarray, t: np.ndarray) -> float:
    """The largest distance between two camera centres (R [C, 3, 3], t [C, 3]), in the unit of t; 0 for one camera."""
    gaps = _centre_gaps(R, t)
    return float(np.where(np.isinf(gaps), 0.0, gaps).max()) if gaps.size else 0.0


def _centre_gaps(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[C, C] distances between camera centres, in the unit of t, inf on the diagonal."""
    centres = camera_centres(R, t)
    return np.linalg.norm(centres[:, None] - centres[None], axis=-1) + np.diag(np.full(len(centres), np.inf))


def check_rig_size(source: str, names: Sequence[str], R: np.ndarray, t_mm: np.ndarray, unit: str, resolved_how: str) -> None:
    """Refuse a rig whose size, in mm, cannot be a rig that films people (the unit must be wrong), or two
    of its cameras `names` at one centre (`check_distinct_centres`).

    `unit` is the unit the file was read in and `resolved_how` how it was chosen, both for the
    message; a single camera is not checked.  Two cameras that no unit would separate (under
    `MIN_BASELINE_MM` apart even read in metres) are named as such before the size is checked.
    """
    if len(t_mm) < 2:
        return
    gaps = _centre_gaps(R, t_mm)
    if gaps.min() * MM_PER_UNIT["m"] / MM_PER_UNIT[unit] < MIN_BASELINE_MM:
        check_distinct_centres(source, names, R, t_mm)
    size = rig_size(R, t_mm)
    low, high = RIG_SIZE_RANGE_MM
    if not low <= size <= high:
        raise DataFormatError(
            source,
            f"camera centres {low:g} mm to {high / 1000:g} m apart, a rig that films people",
            f"a rig {size:.6g} mm across when the file is read in {unit!r} ({resolved_how}); if the file is "
            f"in another unit, say which with {UNIT_FLAG} m|cm|mm",
        )
    check_distinct_centres(source, names, R, t_mm)


def check_distinct_centres(source: str, names: Sequence[str], R: np.ndarray, t_mm: np.ndarray) -> None:
    """Refuse two cameras `names` whose centres are under `MIN_BASELINE_MM` apart: triangulation needs
    a baseline between every two views (`jaxpose.data.batch` refuses such a batch too)."""
    if len(t_mm) < 2:
        return
    gaps = _centre_gaps(R, t_mm)
    first, second = np.unravel_index(np.argmin(gaps), gaps.shape)
    if gaps[first, second] < MIN_BASELINE_MM:
        raise DataFormatError(
            source,
            f"cameras at distinct centres, at least {MIN_BASELINE_MM:g} mm apart (triangulation needs a baseline)",
            f"cameras {names[first]!r} and {names[second]!r} at one centre ({gaps[first, second]:.3g} mm apart):"
            " one camera listed twice, or a pose copied from another camera?",
        )


def check_intrinsics(K: np.ndarray, where: str) -> None:
    """Refuse a 3x3 `K` that is not [[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, or whose focal
    lengths are absurd (outside `FOCAL_RANGE_PX`, or an aspect fy / fx outside `ASPECT_RANGE`) or which is
    near-singular (condition number above `MAX_CONDITION`): undistortion and triangulation through it
    would give NaN or noise far from the message that could name the file."""
    if K[0, 0] <= 0 or K[1, 1] <= 0 or K[1, 0] != 0 or not np.array_equal(K[2], [0.0, 0.0, 1.0]):
        raise DataFormatError(where, "[[fx, skew, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0", str(K.tolist()))
    fx, fy = float(K[0, 0]), float(K[1, 1])
    (low, high), (narrow, wide) = FOCAL_RANGE_PX, ASPECT_RANGE
    condition = float(np.linalg.cond(K))
    if not (low <= fx <= high and low <= fy <= high and narrow <= fy / fx <= wide and condition <= MAX_CONDITION):
        raise DataFormatError(
            where,
            f"intrinsics in pixels: focal lengths fx, fy from {low:g} to {high:g} px, fy / fx from {narrow:g} to {wide:g}, "
            f"condition number at most {MAX_CONDITION:g} (real cameras: about 1e3)",
            f"fx {fx:.6g}, fy {fy:.6g}, condition number {condition:.3g} in {K.tolist()}",
        )


def check_rotation(matrix: np.ndarray, where: str) -> None:
    """Refuse a 3x3 matrix that is not a rotation to `ROTATION_TOLERANCE` (R R^T = I, det R = +1)."""
    if np.abs(matrix @ matrix.T - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(matrix) <= 0:
        raise DataFormatError(where, "a rotation matrix (R R^T = I, det R = +1)", str(matrix.tolist()))
