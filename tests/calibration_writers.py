"""Calibration files written as the tools write them, for the tests of the calibration readers: a
synthetic rig, aniposelib's TOML (trailing commas), cv2.FileStorage's YAML (3-space indent, wrapped lists)
and EasyMocap's own YAML writer (2-space indent, one-line lists)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from fixtures_real_data import ring_of_cameras
from scipy.spatial.transform import Rotation

from jaxpose.camera import Cameras
from jaxpose.formats.rig_cameras import RigCalibration


def synthetic_rig(count=4, seed=0, fisheye=False, with_size=True) -> RigCalibration:
    rng = np.random.default_rng(seed)
    placed = ring_of_cameras(rng, count, 3500.0)
    R = np.array([rotation for rotation, _ in placed])
    t = -np.einsum("cij,cj->ci", R, np.array([centre for _, centre in placed]))
    K = np.zeros((count, 3, 3))
    K[:, [0, 1], [0, 1]] = rng.uniform(900, 1500, (count, 2))
    K[:, :2, 2] = rng.uniform(490, 540, (count, 2))
    K[:, 2, 2] = 1.0
    if fisheye:
        dist = np.concatenate([rng.normal(0, 0.05, (count, 4)), np.zeros((count, 1))], axis=1)
    else:
        dist = rng.normal(0, 0.02, (count, 5))
    return RigCalibration(
        camera_names=tuple(f"cam{index}" for index in range(count)),
        cameras=Cameras(K=K, R=R, t=t, dist=dist, distortion_model="fisheye" if fisheye else "opencv"),
        image_size=np.array([[1000 + c, 1002 - c] for c in range(count)], np.int64) if with_size else None,
        source="synthetic",
        unit="mm",
    )


def aniposelib_style_toml(rig: RigCalibration, scale: float = 1.0, tables=None) -> str:
    """aniposelib's CameraGroup.dump layout: `[cam_i]`, trailing commas, Rodrigues from scipy."""

    def array(values) -> str:
        values = np.asarray(values, np.float64)
        if values.ndim > 1:
            return "[ " + " ".join(array(row) + "," for row in values) + "]"
        return "[ " + " ".join(repr(float(value)) + "," for value in values) + "]"

    out = []
    for c, name in enumerate(rig.camera_names):
        out.append(f"[{tables[c] if tables else f'cam_{c}'}]")
        out.append(f'name = "{name}"')
        out.append(f"size = [ {rig.image_size[c][0]}, {rig.image_size[c][1]},]")
        out.append(f"matrix = {array(rig.cameras.K[c])}")
        out.append(f"distortions = {array(rig.cameras.dist[c])}")
        out.append(f"rotation = {array(Rotation.from_matrix(rig.cameras.R[c]).as_rotvec())}")
        out.append(f"translation = {array(rig.cameras.t[c] / scale)}")
        out.append("")
    out += ["[metadata]", "adjusted = false", "error = 0.0", ""]
    return "\n".join(out)


def opencv_matrix(key: str, matrix: np.ndarray, indent: str, wrap: bool) -> str:
    matrix = np.atleast_2d(matrix)
    if wrap:  # cv2.FileStorage: %.16e, lists wrapped after four values
        values = [f"{value:.16e}" for value in matrix.ravel()]
        chunks = [", ".join(values[i : i + 4]) for i in range(0, len(values), 4)]
        data = "[ " + (",\n" + indent * 2).join(chunks) + " ]"
    else:  # EasyMocap's writer: %.6f on one line
        data = "[" + ", ".join(f"{value:.6f}" for value in matrix.ravel()) + "]"
    rows, cols = matrix.shape
    return f"{key}: !!opencv-matrix\n{indent}rows: {rows}\n{indent}cols: {cols}\n{indent}dt: d\n{indent}data: {data}\n"


def write_easymocap(
    folder: Path, rig: RigCalibration, intri_names=None, extri_names=None, wrap=False, rodrigues="3x1", rotation_noise=0.0
):
    """intri.yml + extri.yml of `rig` (T in metres)."""
    folder.mkdir(parents=True, exist_ok=True)
    indent = "   " if wrap else "  "
    intri_names = list(intri_names or rig.camera_names)
    extri_names = list(extri_names or rig.camera_names)
    index = {name: c for c, name in enumerate(rig.camera_names)}
    names = lambda listed: "names:\n" + "".join(f'{indent}- "{name}"\n' for name in listed)  # noqa: E731
    intri = "%YAML:1.0\n---\n" + names(intri_names)
    for name in intri_names:
        intri += opencv_matrix(f"K_{name}", rig.cameras.K[index[name]], indent, wrap)
        intri += opencv_matrix(f"dist_{name}", rig.cameras.dist[index[name]][None], indent, wrap)
    extri = "%YAML:1.0\n---\n" + names(extri_names)
    for name in extri_names:
        R = rig.cameras.R[index[name]]
        vector = Rotation.from_matrix(R).as_rotvec() + rotation_noise
        extri += opencv_matrix(f"R_{name}", vector[:, None] if rodrigues == "3x1" else vector[None], indent, wrap)
        extri += opencv_matrix(f"Rot_{name}", R, indent, wrap)
        extri += opencv_matrix(f"T_{name}", rig.cameras.t[index[name]][:, None] / 1000.0, indent, wrap)
    (folder / "intri.yml").write_text(intri)
    (folder / "extri.yml").write_text(extri)
