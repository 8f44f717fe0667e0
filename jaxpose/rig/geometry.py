"""The loader's geometry in fixed shapes: the project's rigs as tables that each instant indexes, the
keypoints undistorted and joints triangulated in fixed-size chunks of rows (`jaxpose.chunks`).

Every compiled function takes the cameras as arguments, so one compilation serves every camera,
rig and recording: the number of compilations does not grow with the number or the lengths of the
recordings.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import numpy as np

from jaxpose.camera import projection_matrices, undistort_compiled
from jaxpose.chunks import map_over_parts
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.triangulation import triangulate

CHUNK = 2048  # instants per call: a chunk's person-choice intermediates stay near 50 MiB at 4 views, 2 people
TRIANGULATION_CHUNK = 256  # rows per call: a short recording's sync curves pad little

_triangulate = jax.jit(triangulate, static_argnames="method")


@dataclasses.dataclass(frozen=True)
class Rigs:
    """The project's distinct rigs in its view order, stacked: R rigs of C cameras."""

    calibrations: tuple[RigCalibration, ...]
    K: np.ndarray
    """f32[R, C, 3, 3]"""
    dist: np.ndarray
    """f32[R, C, 5], zero for a rig without distortion."""
    model: tuple[str | None, ...]
    """Each rig's distortion model, None without distortion."""
    P: np.ndarray
    """f32[R, C, 3, 4] projection matrices of undistorted pixels."""

    @classmethod
    def of(cls, calibrations: Sequence[RigCalibration]) -> "Rigs":
        cameras = [calibration.cameras for calibration in calibrations]
        return cls(
            calibrations=tuple(calibrations),
            K=np.stack([np.asarray(c.K, np.float32) for c in cameras]),
            dist=np.stack([np.zeros((len(c.K), 5), np.float32) if c.dist is None else np.asarray(c.dist, np.float32) for c in cameras]),
            model=tuple(None if c.dist is None else c.distortion_model for c in cameras),
            P=np.stack([np.asarray(projection_matrices(c.without_distortion()), np.float32) for c in cameras]),
        )


def undistort(rigs: Rigs, rig_rows: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """f32[n, C, ..., 2] pixels of the rigs `rig_rows` int[n] undistorted (as they are for a rig
    without distortion); n is a chunk's fixed size, so this compiles once per distortion model."""
    n, C = pixels.shape[:2]
    flat = pixels.reshape(n, C, -1, 2)
    out = flat
    models = np.array([rigs.model[r] or "" for r in range(len(rigs.model))])[rig_rows]
    for model in sorted(set(models.tolist()) - {""}):
        points = np.asarray(undistort_compiled(rigs.K[rig_rows], rigs.dist[rig_rows], flat, model=model))
        out = points if (models == model).all() else np.where((models == model)[:, None, None, None], points, out)
    return out.reshape(pixels.shape)


def undistort_views(calibration: RigCalibration | None, camera: str, keypoints: np.ndarray) -> np.ndarray:
    """One camera's keypoints [F, ..., 2] undistorted with `calibration` (as they are without one or
    without distortion), in fixed-size chunks of frames."""
    if calibration is None or calibration.cameras.dist is None or len(keypoints) == 0:
        return keypoints
    rigs = Rigs.of([calibration.select([camera], "the camera undistorted")])
    rows = np.zeros(len(keypoints), np.int32)
    return next(map_over_parts(lambda r, k: undistort(rigs, r, k[:, None])[:, 0], [(rows, keypoints)], CHUNK))


def triangulate_rows(P: np.ndarray, points: np.ndarray, weights: np.ndarray, method: str = "svd") -> np.ndarray:
    """`jaxpose.triangulation.triangulate` of N rows through one rig: P [C, 3, 4], points [N, C, J, 2],
    weights [N, C, J] -> f32[N, J, 3], in chunks of `TRIANGULATION_CHUNK` rows (one compilation per C, J
    and method)."""
    if len(points) == 0:
        return np.zeros((0, points.shape[2], 3), np.float32)
    P = np.asarray(P, np.float32)
    rows = (np.asarray(points, np.float32), np.asarray(weights, np.float32))
    return next(map_over_parts(lambda x, w: _triangulate(P, x, w, method=method), [rows], TRIANGULATION_CHUNK))
