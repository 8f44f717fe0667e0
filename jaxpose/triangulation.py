"""Batched linear (DLT) triangulation of joints seen by C >= 2 calibrated views.

Each view contributes two linear equations per joint, `u P3 - P1` and `v P3 - P2`.  Each is a plane
through the camera centre that contains the viewing ray.  We scale every row so that its first three
coefficients form a unit normal: the row's residual is then the distance (mm) from the point to that
plane.  That makes the system well conditioned in float32 whatever the pixel and millimetre scales,
and gives per-view weights a geometric meaning: weight w multiplies a view's distances.

Methods (all exact on noise-free data, all jittable and batched over any leading axes):
- "svd": the reference DLT: the right singular vector of the smallest singular value, under
  `jax.vmap`, with the unknowns rescaled so that the homogeneous coordinate is O(1).
- "eigh": the same vector from the 4x4 `A^T A` (cheaper, squares the condition number).
- "normal": the least-squares point for the sum of squared point-to-plane distances, from the 3x3
  normal equations in closed form.  No iterative decomposition, so it is the fastest on CPU and its
  gradients are simple; with noise it differs slightly from "svd" (see benchmarks/triangulation.py).
"""

from __future__ import annotations

from typing import Literal

import jax
import jax.numpy as jnp

from jaxpose.camera import Cameras, projection_matrices, undistort_points

Method = Literal["svd", "eigh", "normal"]


def dlt_system(P: jax.Array, points2d: jax.Array, weights: jax.Array | None = None) -> jax.Array:
    """The weighted, row-normalized DLT system: [..., J, 2C, 4] for P [..., C, 3, 4], points [..., C, J, 2]."""
    u = points2d[..., 0:1]  # [..., C, J, 1]
    v = points2d[..., 1:2]
    row_u = u * P[..., None, 2, :] - P[..., None, 0, :]  # [..., C, J, 4]
    row_v = v * P[..., None, 2, :] - P[..., None, 1, :]
    rows = jnp.stack([row_u, row_v], axis=-2)  # [..., C, J, 2, 4]
    normal_length = jnp.linalg.norm(rows[..., :3], axis=-1, keepdims=True)
    rows = rows / jnp.maximum(normal_length, 1e-12)
    if weights is not None:
        weights = weights[..., None, None]
        # `where`, not a product: a dropped view may hold NaN/inf garbage, and 0 * NaN = NaN.
        rows = jnp.where(weights > 0, rows * weights, 0.0)
    rows = jnp.moveaxis(rows, -4, -3)  # [..., J, C, 2, 4]
    return rows.reshape(*rows.shape[:-3], -1, 4)


def _homogeneous_to_point(solution: jax.Array, scale: jax.Array) -> jax.Array:
    w = solution[..., 3:4]
    w = jnp.where(jnp.abs(w) < 1e-12, jnp.where(w < 0, -1e-12, 1e-12), w)
    return solution[..., :3] / w * scale


def _balanced(A: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Rescale the unknowns so that x/s and the homogeneous 1 are of the same magnitude.

    The plane offsets (column 4) are distances of the world origin to the planes, i.e. the scene's
    scale; with s their RMS, the system in Y = (x / s, 1) has columns of comparable norm.
    """
    scale = jnp.sqrt(jnp.mean(A[..., 3] ** 2, axis=-1, keepdims=True)) + 1.0  # [..., 1]
    return A * jnp.concatenate([jnp.broadcast_to(scale, scale.shape[:-1] + (3,)), jnp.ones_like(scale)], -1)[..., None, :], scale


def _solve_svd(A: jax.Array) -> jax.Array:
    balanced, scale = _balanced(A)
    flat = balanced.reshape(-1, *balanced.shape[-2:])
    _, _, vh = jax.vmap(lambda a: jnp.linalg.svd(a, full_matrices=False))(flat)
    solution = vh[:, -1, :].reshape(*A.shape[:-2], 4)
    return _homogeneous_to_point(solution, scale)


def _solve_eigh(A: jax.Array) -> jax.Array:
    balanced, scale = _balanced(A)
    gram = jnp.einsum("...ri,...rj->...ij", balanced, balanced)
    _, vectors = jnp.linalg.eigh(gram)
    return _homogeneous_to_point(vectors[..., :, 0], scale)


def _solve_normal(A: jax.Array) -> jax.Array:
    normals, offsets = A[..., :3], A[..., 3]
    gram = jnp.einsum("...ri,...rj->...ij", normals, normals)  # [..., 3, 3]
    rhs = -jnp.einsum("...ri,...r->...i", normals, offsets)
    # Closed-form inverse of the symmetric 3x3 matrix through its adjugate (no LAPACK call).
    a, b, c = gram[..., 0, 0], gram[..., 0, 1], gram[..., 0, 2]
    d, e, f = gram[..., 1, 1], gram[..., 1, 2], gram[..., 2, 2]
    cof_a, cof_b, cof_c = d * f - e * e, c * e - b * f, b * e - c * d
    cof_d, cof_e, cof_f = a * f - c * c, b * c - a * e, a * d - b * b
    determinant = a * cof_a + b * cof_b + c * cof_c
    determinant = jnp.where(jnp.abs(determinant) < 1e-20, 1e-20, determinant)
    adjugate = jnp.stack(
        [jnp.stack([cof_a, cof_b, cof_c], -1), jnp.stack([cof_b, cof_d, cof_e], -1), jnp.stack([cof_c, cof_e, cof_f], -1)],
        axis=-2,
    )
    return jnp.einsum("...ij,...j->...i", adjugate, rhs) / determinant[..., None]


_SOLVERS = {"svd": _solve_svd, "eigh": _solve_eigh, "normal": _solve_normal}


def triangulate(
    P: jax.Array, points2d: jax.Array, weights: jax.Array | None = None, method: Method = "svd"
) -> jax.Array:
    """Triangulate every joint: P [..., C, 3, 4], points2d [..., C, J, 2] (undistorted pixels),
    weights [..., C, J] (0 drops a view for that joint) -> world points [..., J, 3].

    A joint with fewer than two views of positive weight has no defined solution; its output is
    finite but meaningless, and callers mask it (see `jaxpose.data.pseudo_label_validity`).
    """
    if P.shape[-2:] != (3, 4):
        raise ValueError(f"triangulate: P must be [..., C, 3, 4], got {P.shape}")
    if points2d.shape[-1] != 2 or points2d.shape[-3] != P.shape[-3]:
        raise ValueError(f"triangulate: points2d must be [..., C={P.shape[-3]}, J, 2], got {points2d.shape}")
    if points2d.shape[-3] < 2:
        raise ValueError(f"triangulate: needs at least 2 views, got C={points2d.shape[-3]}")
    if weights is not None and weights.shape[-2:] != points2d.shape[-3:-1]:
        raise ValueError(f"triangulate: weights must be [..., C, J] = {points2d.shape[-3:-1]}, got {weights.shape}")
    try:
        solver = _SOLVERS[method]
    except KeyError:
        raise ValueError(f"triangulate: unknown method {method!r}; expected one of {sorted(_SOLVERS)}") from None
    return solver(dlt_system(P, points2d, weights))


def triangulate_cameras(
    cameras: Cameras, keypoints2d: jax.Array, weights: jax.Array | None = None, method: Method = "svd"
) -> jax.Array:
    """Triangulate detections in (possibly distorted) pixels: cameras [..., C], keypoints [..., C, J, 2]."""
    undistorted = undistort_points(cameras, keypoints2d)
    return triangulate(projection_matrices(cameras), undistorted, weights, method)
