"""Human3.6M's `cameras.h5`, the calibration its users bring, and its lens model in OpenCV's terms.

`read_h36m_cameras` reads the rig of every subject; `H36M_IMAGE_SIZES` holds the video sizes the
file does not store.  Human3.6M's distortion is not OpenCV's (docs/conventions.md):
`opencv_from_h36m_distortion` fits the closest OpenCV coefficients, and `opencv_rig_from_h36m`
converts a whole rig, so that it can be written where only OpenCV's model is understood (an
Anipose-family TOML).
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jaxpose.camera import Cameras
from jaxpose.formats.rig_cameras import (
    CalibrationFormat, CalibrationUnit, RigCalibration, check_distinct_centres, known_image_sizes, millimetres_by_definition,
    pick_subject,
)  # fmt: skip
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.files import h5_dataset, open_h5

__all__ = ["FORMAT", "H36M_IMAGE_SIZES", "opencv_from_h36m_distortion", "opencv_rig_from_h36m", "read_h36m_cameras", "read_rig"]

# Video resolution (width, height) of the four Human3.6M cameras; cameras.h5 does not store it.
H36M_IMAGE_SIZES = {
    "54138969": (1000, 1002),
    "55011271": (1000, 1000),
    "58860488": (1000, 1000),
    "60457274": (1000, 1002),
}


def read_h36m_cameras(path: str | Path, dtype: type = np.float32) -> dict[str, tuple[list[str], Cameras]]:
    """Human3.6M's `cameras.h5` as subject ('S1') -> (camera names, numpy `Cameras` [4] of `dtype`).

    The file stores, per `subject{S}/camera{i}`, a rotation R and the camera centre T with
    `x_cam = R^T (X - T)` as h5py reads them (docs/conventions.md), so our world-to-camera rotation
    is R^T and our translation -R^T T.  Distortion uses the "h36m" model, dist = (k1, k2, p[0],
    p[1], k3).  Cameras are in the file's camera-number order.  float32 is what the data sets
    train with; np.float64 keeps the file's precision (the camera-file converter, `read_rig_calibration`).
    """
    path = Path(path)
    what = "Human3.6M cameras.h5 with groups subject<S>/camera<i>"
    sizes = {"R": 9, "T": 3, "f": 2, "c": 2, "k": 3, "p": 2}
    rigs = {}
    with open_h5(path, what) as file:
        subjects = _numbered(file, "subject")
        if not subjects:
            raise DataFormatError(path, f"{what}", f"top-level members {sorted(file.keys())}")
        for number, subject_key in subjects:
            cameras = _numbered(file[subject_key], "camera")
            if not cameras:
                raise DataFormatError(f"{path}:/{subject_key}", "groups camera1..camera4", "no camera groups")
            names, K, R, t, dist = [], [], [], [], []
            for _, camera_key in cameras:
                group = file[subject_key][camera_key]
                values = {}
                for field, size in sizes.items():
                    value = np.asarray(h5_dataset(group, field, path, what), np.float64).reshape(-1)
                    if value.size != size or not np.all(np.isfinite(value)):
                        raise DataFormatError(
                            f"{path}:/{subject_key}/{camera_key}/{field}",
                            f"{size} finite numbers",
                            f"shape {value.shape} with values {value[:9].tolist()}",
                        )
                    values[field] = value
                names.append(_camera_name(h5_dataset(group, "Name", path, what), f"{path}:/{subject_key}/{camera_key}/Name"))
                rotation = values["R"].reshape(3, 3)
                (fx, fy), (cx, cy) = values["f"], values["c"]
                K.append([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
                R.append(rotation.T)
                t.append(-rotation.T @ values["T"])
                k, p = values["k"], values["p"]
                dist.append([k[0], k[1], p[0], p[1], k[2]])
            rigs[f"S{number}"] = (
                names,
                Cameras(
                    K=np.array(K, dtype), R=np.array(R, dtype), t=np.array(t, dtype), dist=np.array(dist, dtype),
                    distortion_model="h36m",
                ),
            )
    return rigs


def read_rig(path: Path, unit: CalibrationUnit, subject: str | None) -> RigCalibration:
    """One subject's rig of `cameras.h5`, float64, in millimetres whatever `unit` says."""
    millimetres_by_definition(path, unit)
    rigs = read_h36m_cameras(path, np.float64)
    subject = pick_subject(path, list(rigs), subject)
    names, cameras = rigs[subject]
    source = f"{path} (subject {subject})"
    check_distinct_centres(source, names, cameras.R, cameras.t)
    return RigCalibration(tuple(names), cameras, known_image_sizes([H36M_IMAGE_SIZES.get(name) for name in names]), source, "mm")


# Never found in a folder: a file of several subjects' rigs is named (--data.calibration).
FORMAT = CalibrationFormat("Human3.6M's cameras.h5", (".h5", ".hdf5"), None, read_rig)


def opencv_from_h36m_distortion(
    dist_h36m: np.ndarray, K: np.ndarray, image_size: Sequence[int] | None = None, grid: int = 41
) -> tuple[np.ndarray, float]:
    """The OpenCV (k1, k2, p1, p2, k3) closest to Human3.6M's distortion, and the largest pixel error.

    Human3.6M's tangential terms (docs/conventions.md) are not OpenCV's: x gets p[0] x y + p[1] (x^2 + r^2)
    where OpenCV has 2 p1 x y + p2 (r^2 + 2 x^2), so no OpenCV vector reproduces it exactly.  Both
    models are linear in their coefficients, so the closest OpenCV vector is a linear least-squares
    fit, in pixels, over a `grid` x `grid` lattice spanning the image (mapped through K^-1 to
    normalized coordinates).  `image_size` (width, height) defaults to twice the principal point.
    Returns (dist f64[5], the largest pixel distance between the two models over the lattice).
    `dist_h36m` [C, 5] with `K` [C, 3, 3] (and `image_size` [C, 2]) gives f64[C, 5] and the
    largest error over all cameras.

    On Human3.6M's S1 cameras the largest error is 0.21 to 0.41 px, at the image corners (median
    about 0.05 px); the tangential terms themselves move the corners by 1.5 to 2.8 px.  What the
    five coefficients cannot hold is a shift of (p[1], p[0]) r^2 / 2: OpenCV's 12-coefficient model
    reproduces Human3.6M's exactly with p1 = p[0]/2, p2 = p[1]/2 and thin-prism s1 = p[1]/2,
    s3 = p[0]/2, but Anipose-family files and `jaxpose.camera` hold five.
    """
    dist_h36m, K = np.asarray(dist_h36m, np.float64), np.asarray(K, np.float64)
    if dist_h36m.ndim == 2:
        sizes = [None] * len(dist_h36m) if image_size is None else list(image_size)
        fits = [opencv_from_h36m_distortion(d, k, s, grid) for d, k, s in zip(dist_h36m, K, sizes, strict=True)]
        return np.array([fit[0] for fit in fits]), max(fit[1] for fit in fits)
    if dist_h36m.shape != (5,) or K.shape != (3, 3):
        raise ValueError(f"opencv_from_h36m_distortion: dist [5] and K [3, 3] expected, got {dist_h36m.shape}, {K.shape}")
    (fx, skew, cx), (_, fy, cy) = K[0], K[1]
    width, height = (2.0 * cx, 2.0 * cy) if image_size is None else (float(image_size[0]), float(image_size[1]))
    u, v = np.meshgrid(np.linspace(0.0, width, grid), np.linspace(0.0, height, grid))
    y = (v.ravel() - cy) / fy
    x = (u.ravel() - cx - skew * y) / fx
    x_d, y_d = _distort_h36m(x, y, dist_h36m)
    terms_x, terms_y = _opencv_terms(x, y)
    # Pixel displacements: u = fx x_d + skew y_d + cx, v = fy y_d + cy.
    A = np.concatenate([fx * terms_x + skew * terms_y, fy * terms_y])
    b = np.concatenate([fx * (x_d - x) + skew * (y_d - y), fy * (y_d - y)])
    dist_opencv = np.linalg.lstsq(A, b, rcond=None)[0]
    residual = (A @ dist_opencv - b).reshape(2, -1)
    return dist_opencv, float(np.sqrt((residual**2).sum(0)).max())


def opencv_rig_from_h36m(rig: RigCalibration) -> tuple[RigCalibration, float]:
    """A rig with Human3.6M's distortion converted to OpenCV's (`opencv_from_h36m_distortion`), and
    the largest pixel difference the conversion makes over the cameras' images."""
    if rig.cameras.distortion_model != "h36m" or rig.cameras.dist is None:
        return rig, 0.0
    dist, error = opencv_from_h36m_distortion(rig.cameras.dist, rig.cameras.K, rig.image_size)
    return dataclasses.replace(rig, cameras=rig.cameras.replace(dist=dist, distortion_model="opencv")), error


# ----------------------------------------------------------------------------------------------
# Helpers


def _numbered(group, prefix: str) -> list[tuple[int, str]]:
    """(number, key) of the members named `<prefix><number>`, by number."""
    found = ((re.fullmatch(rf"{prefix}(\d+)", key), key) for key in group.keys())
    return sorted((int(match.group(1)), key) for match, key in found if match)


def _camera_name(codes, where: str) -> str:
    """A camera name stored as character codes.  The real cameras.h5 stores them as float64 [8, 1]
    (e.g. 53., 52., ... for "54138969"); any numeric dtype is accepted as long as every code is a
    whole number that is a valid character."""
    codes = np.asarray(codes).reshape(-1)
    if codes.dtype.kind not in "biuf" or codes.size == 0:
        raise DataFormatError(where, "a camera name as character codes (numbers)", f"dtype {codes.dtype}, shape {codes.shape}")
    valid = np.isfinite(codes) & (codes == np.round(codes)) & (codes >= 32) & (codes < 0x110000)
    if not np.all(valid):
        raise DataFormatError(
            where, "character codes: whole numbers of printable characters", f"{codes.dtype} values {codes[:8].tolist()}"
        )
    return "".join(map(chr, codes.astype(np.int64).tolist()))


def _distort_h36m(x: np.ndarray, y: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k1, k2, p0, p1, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + k1 * r2 + k2 * r2**2 + k3 * r2**3
    tangential = p0 * y + p1 * x
    return x * (radial + tangential) + p1 * r2, y * (radial + tangential) + p0 * r2


def _opencv_terms(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The OpenCV model's displacement is linear in (k1, k2, p1, p2, k3): [N, 5] for x and for y."""
    r2 = x * x + y * y
    terms_x = np.stack([x * r2, x * r2**2, 2.0 * x * y, r2 + 2.0 * x * x, x * r2**3], -1)
    terms_y = np.stack([y * r2, y * r2**2, r2 + 2.0 * y * y, 2.0 * x * y, y * r2**3], -1)
    return terms_x, terms_y
