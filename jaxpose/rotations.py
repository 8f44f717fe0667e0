"""Rotation matrices in float64 numpy: Rodrigues vectors to and from matrices, and the nearest rotation.

Calibration files store rotations as Rodrigues (axis-angle) vectors or as 3x3 matrices written with
a few digits; the readers and writers (`jaxpose.formats`), the rig comparison
(`jaxpose.calibration.compare`) and the synthetic rig all go through these functions.  Every function
takes any leading axes.
"""

from __future__ import annotations

import numpy as np

__all__ = ["nearest_rotation", "rodrigues_from_rotation", "rotation_from_rodrigues"]


def rotation_from_rodrigues(rvec: np.ndarray) -> np.ndarray:
    """Rodrigues (axis-angle) vectors [..., 3] -> rotation matrices [..., 3, 3], as cv2.Rodrigues.

    R = I + sin(theta)/theta [r]x + (1 - cos(theta))/theta^2 [r]x^2, with the second coefficient
    written as 2 sin^2(theta/2)/theta^2 (no cancellation) and Taylor series near theta = 0.
    """
    r = np.asarray(rvec, np.float64)
    theta = np.linalg.norm(r, axis=-1)[..., None, None]
    zero = np.zeros(r.shape[:-1])
    cross = np.stack(
        [
            np.stack([zero, -r[..., 2], r[..., 1]], -1),
            np.stack([r[..., 2], zero, -r[..., 0]], -1),
            np.stack([-r[..., 1], r[..., 0], zero], -1),
        ],
        -2,
    )
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, 2.0 * np.sin(0.5 * safe) ** 2 / safe**2)
    return np.eye(3) + a * cross + b * (cross @ cross)


def rodrigues_from_rotation(R: np.ndarray) -> np.ndarray:
    """Rotation matrices [..., 3, 3] -> Rodrigues vectors [..., 3] with angle in [0, pi].

    The angle is atan2(sin, cos) from the antisymmetric part and the trace (accurate at every
    angle).  Up to 90 degrees the axis is the antisymmetric part's direction; beyond, where that
    part vanishes towards 180 degrees, the axis comes from the symmetric part (1 - cos) a a^T and
    takes the antisymmetric part's sign.
    """
    R = np.asarray(R, np.float64)
    v = 0.5 * np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    s = np.linalg.norm(v, axis=-1)
    c = np.clip(0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0), -1.0, 1.0)
    theta = np.arctan2(s, c)
    # Small and moderate angles: r = theta / sin(theta) * v.
    tiny = s < 1e-12
    ratio = np.where(tiny, 1.0 + theta**2 / 6.0, theta / np.where(tiny, 1.0, s))
    near = ratio[..., None] * v
    # Large angles: a a^T = (sym(R) - c I) / (1 - c); the column of the largest diagonal entry.
    outer = (0.5 * (R + np.swapaxes(R, -1, -2)) - c[..., None, None] * np.eye(3)) / np.maximum(1.0 - c, 1e-12)[
        ..., None, None
    ]
    column = np.argmax(np.diagonal(outer, axis1=-2, axis2=-1), axis=-1)
    picked = np.take_along_axis(outer, column[..., None, None], axis=-1)[..., 0]
    diagonal = np.take_along_axis(picked, column[..., None], axis=-1)
    axis = picked / np.sqrt(np.maximum(diagonal, 1e-300))
    axis = np.where(np.sum(axis * v, axis=-1, keepdims=True) < 0.0, -axis, axis)
    far = theta[..., None] * axis
    return np.where((c < 0.0)[..., None], far, near)


def nearest_rotation(matrix: np.ndarray) -> np.ndarray:
    """The rotations closest (Frobenius) to 3x3 matrices [..., 3, 3], in float64, by SVD.

    U V^T is the closest orthonormal matrix; where it is a reflection (det -1, a matrix far from
    any rotation) the singular direction of the smallest singular value is flipped, so the result
    is always a rotation.  For a matrix that is already nearly a rotation the flip never happens.
    """
    u, _, vt = np.linalg.svd(np.asarray(matrix, np.float64))
    flip = np.sign(np.linalg.det(u @ vt))
    return u @ (np.stack([np.ones_like(flip), np.ones_like(flip), flip], -1)[..., None] * vt)


def similarity(source: np.ndarray, target: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, R, t) minimising |s R source + t - target| over corresponding points [M, 3] (Umeyama, 1991)."""
    mean_source, mean_target = source.mean(0), target.mean(0)
    a, b = source - mean_source, target - mean_target
    u, singular, vt = np.linalg.svd(b.T @ a / len(a))
    sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    R = u @ sign @ vt
    s = float(np.trace(np.diag(singular) @ sign) / a.var(0).sum())
    return s, R, mean_target - s * R @ mean_source
