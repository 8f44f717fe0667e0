"""One camera's intrinsics as a single-view command takes them (`jaxpose.predict --intrinsics`).

Four numbers fx fy cx cy; a calibration file and a camera name (a rig's calibration as
`jaxpose.formats.calibration_files` reads it: Anipose / Pose2Sim / FreeMoCap TOML, EasyMocap intri.yml, a
jaxpose camera file), e.g. ``calibration.toml cam01``, the name matched to the file's cameras as
`jaxpose.formats.camera_names` matches them (``cam_01`` finds Pose2Sim's ``int_cam01_img``); or a JSON
file holding one camera in the fields of a jaxpose camera file entry: {"K": [[fx, s, cx], [0, fy, cy],
[0, 0, 1]], "dist": [k1, k2, p1, p2, k3] or null, "image_size": [width, height] or null}; other fields
(R, t, name) are ignored.

`read_rig_intrinsics` reads the lenses of a whole rig the same way (K, distortion, image sizes; the
extrinsics dropped), for recovering the rig's poses from the person with known lenses
(`jaxpose.calibration.RigDetections`' K and dist).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jaxpose.formats import files

from jaxpose.formats import calibration_files
from jaxpose.formats.rig_cameras import check_intrinsics
from jaxpose.formats.errors import DataFormatError


@dataclasses.dataclass(frozen=True)
class CameraIntrinsics:
    """The camera that saw the poses, as `jaxpose.serving.inference.Lifter3D.predict` takes it."""

    K: np.ndarray | None = None
    """f32[3, 3] shared by every pose or f32[N, 3, 3] one per pose; None: the default of `image_size`."""
    dist: np.ndarray | None = None
    """OpenCV distortion (k1, k2, p1, p2, k3) [5], or None: the keypoints are pinhole pixels."""
    image_size: tuple[float, float] | None = None
    """(width, height) px, or None where unknown."""

    def of_poses(self, rows: slice | np.ndarray) -> np.ndarray | None:
        """K for the poses `rows`: the shared one, or theirs."""
        return self.K if self.K is None or self.K.ndim == 2 else self.K[rows]


def read_intrinsics(values: Sequence[str]) -> CameraIntrinsics:
    """The camera `values` name, in one of the forms of the module docstring."""
    if len(values) == 4:
        fx, fy, cx, cy = (float(v) for v in values)
        return CameraIntrinsics(_checked_K([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], "--intrinsics fx fy cx cy"))
    if len(values) == 2:
        return _calibration_camera(Path(values[0]), values[1])
    if len(values) != 1:
        raise ValueError(
            f"--intrinsics takes 4 numbers (fx fy cx cy), a calibration file and a camera name, or one JSON camera"
            f" file; got {len(values)} values"
        )
    path = Path(values[0])
    if not path.is_file():
        raise FileNotFoundError(f"--intrinsics file {path} does not exist")
    camera = files.read_json(path, "an --intrinsics camera")
    if not isinstance(camera, dict) or "K" not in camera:
        raise ValueError(f"{path}: expected a camera {{'K': 3x3, 'dist': [5] or null, 'image_size': [w, h]}}")
    dist = camera.get("dist")
    size = camera.get("image_size")
    return CameraIntrinsics(
        _checked_K(camera["K"], f"--intrinsics {path}, field 'K'"),
        None if dist is None else np.asarray(dist, np.float32),
        None if size is None else tuple(size),
    )


@dataclasses.dataclass(frozen=True)
class RigIntrinsics:
    """The lenses of a rig's cameras, in the order asked for: K f64[C, 3, 3], dist f64[C, 5] or None
    (pinhole), its `distortion_model`, image_size int64[C, 2] (width, height) or None."""

    camera_names: tuple[str, ...]
    K: np.ndarray
    dist: np.ndarray | None
    distortion_model: str
    image_size: np.ndarray | None
    source: str


def read_rig_intrinsics(path: str | Path, camera_names: Sequence[str], what: str = "cameras") -> RigIntrinsics:
    """The intrinsics of `camera_names` (matched to the file's cameras by `RigCalibration.select`, `what`
    says where the names come from) from any rig calibration file `read_rig_calibration` reads; the
    file's rotations and translations are dropped."""
    rig = calibration_files.read_rig_calibration(path).select(camera_names, what)
    cameras = rig.cameras
    return RigIntrinsics(
        camera_names=rig.camera_names,
        K=np.asarray(cameras.K, np.float64),
        dist=None if cameras.dist is None else np.asarray(cameras.dist, np.float64),
        distortion_model=cameras.distortion_model,
        image_size=rig.image_size,
        source=f"{rig.source} (intrinsics only)",
    )


def _checked_K(value, where: str) -> np.ndarray:
    """f32[3, 3] intrinsics from `value`, refused as every calibration reader refuses them
    (`jaxpose.formats.rig_cameras.check_intrinsics`: a near-singular K too)."""
    try:
        K = np.array(value, np.float64)
    except (TypeError, ValueError):
        K = None
    if K is None or K.shape != (3, 3) or not np.isfinite(K).all():
        raise DataFormatError(where, "a 3x3 intrinsic matrix of finite numbers", repr(value)[:200])
    check_intrinsics(K, where)
    return K.astype(np.float32)


def _calibration_camera(path: Path, camera: str) -> CameraIntrinsics:
    """One camera of a rig calibration file."""
    rig = calibration_files.read_rig_calibration(path).select([camera], f"--intrinsics {path} {camera}")
    cameras = rig.cameras
    if cameras.dist is not None and cameras.distortion_model != "opencv":
        raise ValueError(
            f"--intrinsics {path} {camera}: its {cameras.distortion_model!r} lens model is not OpenCV's, which predict"
            " undistorts with; undistort the keypoints first and pass the camera's fx fy cx cy"
        )
    size = None if rig.image_size is None else tuple(float(v) for v in rig.image_size[0])
    dist = None if cameras.dist is None else np.asarray(cameras.dist[0], np.float32)
    return CameraIntrinsics(np.asarray(cameras.K[0], np.float32), dist, size)
