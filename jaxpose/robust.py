"""Robust input triangulation: pseudo-labels that survive outlying and swapped 2D detections.

The pseudo-label of a joint (paper Eq. 2) is the DLT over every view that detected it, so one
gross outlier or one left/right swap among C = 4 views moves it by tens of millimetres, and the
lifter is then taught that error through L_in and, via the root, L_proj and L_out.  This module
offers, beside the plain DLT:

- The confidence-weighted DLT.  Nothing to add here: `triangulate(P, points2d, weights=confidence)`
  already is it (each view's rows scaled by its confidence, 0 dropping the view), and it is what
  the methods "svd" / "eigh" / "normal" of `pseudo_labels` compute.
- `irls_triangulate`: iteratively re-weighted DLT.  Starting from the confidence-weighted solution,
  every view of a joint is re-weighted by a Cauchy function of its reprojection residual (pixels)
  and the DLT solved again, a few times.  Cheap (C-view systems only) and effective against a
  minority of moderate outliers; a start that is already far off (half the views wrong, or one
  view off by a metre, as a left/right swap of the arms can be) can trap it.
- `ransac_triangulate`: every pair of views is a hypothesis (C(C, 2) of them, 6 for C = 4), scored
  by the total confidence of the views that agree with it within `threshold_px` (their number when
  the detector gives no confidence), then by their residuals; exhaustive, so deterministic, and it
  finds the consistent views even when they are only two.

Their inner solves use the closed-form "normal" solver: about 10x faster than SVD on CPU, and, as
the exact least squares of the point-to-plane distances, more accurate than the SVD's algebraic
solution when the views' weights differ a lot (see `experiments/pseudo_labels.py`).

Both end alike (`refine_on_inliers`): the DLT over the views within `threshold_px`, the inliers
re-selected against that solution and the DLT solved once more; a joint keeps weight 1 only if at
least `min_views` views end within `threshold_px` of its final point, otherwise it gets weight 0
and teaches nothing.  `agreeing_views` names the views that end within `threshold_px`: the others
are outliers, and `jaxpose.training.pseudo_labelling.label` records them so that the losses do not take
them as targets either (`MultiViewBatch.detection_weight`).

All functions are pure, jittable, and batched over any leading axes: P [..., C, 3, 4] as built by
`jaxpose.camera.projection_matrices` (K [R | t], so the third projected coordinate is the depth in
mm), points2d [..., C, J, 2] undistorted pixels, confidence [..., C, J].  A view with confidence 0
contributes nothing anywhere, whatever its coordinates hold (NaN and inf included).
"""

from __future__ import annotations

import itertools
from typing import Literal, get_args

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import project_with_matrices
from jaxpose.triangulation import Method, triangulate

PseudoLabelMethod = Literal["svd", "eigh", "normal", "unweighted", "irls", "ransac"]
PSEUDO_LABEL_METHODS: tuple[str, ...] = get_args(PseudoLabelMethod)
OUTLIER_REJECTING_METHODS: tuple[str, ...] = ("irls", "ransac")

DEFAULT_THRESHOLD_PX = 25.0
DEFAULT_IRLS_ITERATIONS = 3
DEFAULT_IRLS_SCALE_PX = 10.0

# Residual given to a point at or behind a camera: it is no projection at all, so it must count as an
# outlier; a large finite number (not inf) keeps every sum and square finite.
BEHIND_CAMERA_PX = 1e6
_MIN_DEPTH_MM = 1e-3


def in_front(P: jax.Array, points3d: jax.Array) -> jax.Array:
    """bool[..., C, J]: the point lies in front of the camera (positive depth)."""
    return project_with_matrices(P, points3d)[..., 2] > _MIN_DEPTH_MM


def reprojection_residuals(P: jax.Array, points2d: jax.Array, points3d: jax.Array) -> jax.Array:
    """Pixel distance between each view's detection and the projection of the 3D point: [..., C, J].

    P [..., C, 3, 4], points2d [..., C, J, 2], points3d [..., J, 3] (leading axes broadcast).
    Points at or behind a camera get `BEHIND_CAMERA_PX`.  Garbage detections give garbage (even NaN)
    residuals: callers select with `confidence > 0` (NaN compares False with any threshold).
    """
    projected = project_with_matrices(P, points3d)
    depth = projected[..., 2]
    visible = depth > _MIN_DEPTH_MM
    pixels = projected[..., :2] / jnp.where(visible, depth, 1.0)[..., None]
    residual = jnp.linalg.norm(pixels - points2d, axis=-1)
    return jnp.where(visible, residual, BEHIND_CAMERA_PX)


def cauchy_weights(residual: jax.Array, scale: float) -> jax.Array:
    """The Cauchy M-estimator's IRLS weight 1 / (1 + (r / scale)^2): ~1 for inliers, ~(scale/r)^2 beyond."""
    return 1.0 / (1.0 + (residual / scale) ** 2)


def _views_within(residual: jax.Array, confidence: jax.Array, threshold_px: float) -> jax.Array:
    """bool[..., C, J]: detected views whose residual is at most the threshold."""
    return (confidence > 0) & (residual <= threshold_px)


def _masked_confidence(confidence: jax.Array, keep: jax.Array | bool = True) -> jax.Array:
    """Confidence where detected (and `keep`), else exactly 0 (`where`: no 0 * NaN anywhere)."""
    return jnp.where(keep & (confidence > 0), confidence, 0.0)


def agreeing_views(
    P: jax.Array, points2d: jax.Array, confidence: jax.Array, points3d: jax.Array, threshold_px: float
) -> jax.Array:
    """f32[..., C, J]: 1 where a view detected the joint within `threshold_px` of its 3D point, else 0."""
    return _views_within(reprojection_residuals(P, points2d, points3d), confidence, threshold_px).astype(points2d.dtype)


def refine_on_inliers(
    P: jax.Array,
    points2d: jax.Array,
    confidence: jax.Array,
    inliers: jax.Array,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_views: int = 2,
    solver: Method = "normal",
) -> tuple[jax.Array, jax.Array]:
    """Confidence-weighted DLT on `inliers` (bool [..., C, J]), inliers re-selected, solved again.

    Returns (points [..., J, 3], weight [..., J]): weight 1 where at least `min_views` detected views
    lie within `threshold_px` of the final point, else 0.
    """
    points = triangulate(P, points2d, _masked_confidence(confidence, inliers), solver)
    inliers = _views_within(reprojection_residuals(P, points2d, points), confidence, threshold_px)
    points = triangulate(P, points2d, _masked_confidence(confidence, inliers), solver)
    final = _views_within(reprojection_residuals(P, points2d, points), confidence, threshold_px)
    weight = (final.sum(-2) >= min_views).astype(points.dtype)
    return points, weight


def irls_triangulate(
    P: jax.Array,
    points2d: jax.Array,
    confidence: jax.Array,
    *,
    iterations: int = DEFAULT_IRLS_ITERATIONS,
    scale_px: float = DEFAULT_IRLS_SCALE_PX,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_views: int = 2,
    solver: Method = "normal",
) -> tuple[jax.Array, jax.Array]:
    """Iteratively re-weighted DLT on reprojection residuals -> (points [..., J, 3], weight [..., J]).

    Weights: confidence x sqrt(Cauchy(residual / scale_px)).  The square root because a DLT weight
    scales a view's rows, i.e. its distances, so the cost term is multiplied by the weight squared;
    the M-estimator's weight belongs on the cost.  Then `refine_on_inliers` with `threshold_px`.
    """
    detected = confidence > 0
    base = _masked_confidence(confidence)

    def reweight(_, points):
        residual = reprojection_residuals(P, points2d, points)
        weights = jnp.where(detected, base * jnp.sqrt(cauchy_weights(residual, scale_px)), 0.0)
        return triangulate(P, points2d, weights, solver)

    points = jax.lax.fori_loop(0, iterations, reweight, triangulate(P, points2d, base, solver))
    inliers = _views_within(reprojection_residuals(P, points2d, points), confidence, threshold_px)
    return refine_on_inliers(P, points2d, confidence, inliers, threshold_px, min_views, solver)


def view_pairs(num_views: int) -> np.ndarray:
    """i32[C(C, 2), 2]: every unordered pair of views, the RANSAC hypotheses."""
    return np.array(list(itertools.combinations(range(num_views), 2)), dtype=np.int32).reshape(-1, 2)


def ransac_triangulate(
    P: jax.Array,
    points2d: jax.Array,
    confidence: jax.Array,
    *,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    min_views: int = 2,
    solver: Method = "normal",
) -> tuple[jax.Array, jax.Array]:
    """Exhaustive RANSAC over view pairs -> (points [..., J, 3], weight [..., J]).

    For every joint, each pair of detected views is triangulated; the hypothesis whose views within
    `threshold_px` (its inliers) have the largest total confidence wins, ties broken by the smaller
    sum of squared inlier residuals.  Then `refine_on_inliers` on the winner's inliers.
    """
    num_views = P.shape[-3]
    pairs = view_pairs(num_views)  # [K, 2]
    pair_confidence = _masked_confidence(confidence)[..., pairs, :]  # [..., K, 2, J]
    hypotheses = triangulate(P[..., pairs, :, :], points2d[..., pairs, :, :], pair_confidence, solver)  # [..., K, J, 3]
    residual = reprojection_residuals(P[..., None, :, :, :], points2d[..., None, :, :, :], hypotheses)  # [..., K, C, J]
    inliers = _views_within(residual, confidence[..., None, :, :], threshold_px)
    # The hypothesis whose inliers carry the most confidence wins (the most inliers when confidence
    # is all 1); the squared residuals, scaled into [0, 1e-3), only break ties.
    support = jnp.sum(jnp.where(inliers, confidence[..., None, :, :], 0.0), axis=-2)  # [..., K, J]
    cost = jnp.sum(jnp.where(inliers, residual**2, 0.0), axis=-2) / (threshold_px**2 * num_views + 1.0)
    score = support - 1e-3 * cost
    usable = (pair_confidence > 0).all(-2)
    best = jnp.argmax(jnp.where(usable, score, -1.0), axis=-2)  # [..., J]
    chosen = jnp.take_along_axis(inliers, best[..., None, None, :], axis=-3)[..., 0, :, :]  # [..., C, J]
    return refine_on_inliers(P, points2d, confidence, chosen, threshold_px, min_views, solver)


def pseudo_labels(
    P: jax.Array,
    points2d: jax.Array,
    confidence: jax.Array,
    method: PseudoLabelMethod = "svd",
    *,
    min_views: int = 2,
    threshold_px: float = DEFAULT_THRESHOLD_PX,
    irls_iterations: int = DEFAULT_IRLS_ITERATIONS,
    irls_scale_px: float = DEFAULT_IRLS_SCALE_PX,
) -> tuple[jax.Array, jax.Array]:
    """The input triangulation by `method` -> (points [..., J, 3] world mm, weight [..., J] in {0, 1}).

    - "svd", "eigh", "normal": the confidence-weighted DLT with that solver (`triangulate`);
      weight 1 where at least `min_views` views detected the joint and the point lies in front of
      all of them.
    - "unweighted": the paper's DLT, every detected view (confidence > 0) with weight 1 (SVD).
    - "irls", "ransac": `irls_triangulate` / `ransac_triangulate`, weight 1 where at least
      `min_views` views agree within `threshold_px`.
    """
    if method in get_args(Method):
        points = triangulate(P, points2d, _masked_confidence(confidence), method)
    elif method == "unweighted":
        points = triangulate(P, points2d, (confidence > 0).astype(points2d.dtype), "svd")
    elif method == "irls":
        return irls_triangulate(
            P, points2d, confidence, iterations=irls_iterations, scale_px=irls_scale_px,
            threshold_px=threshold_px, min_views=min_views,
        )  # fmt: skip
    elif method == "ransac":
        return ransac_triangulate(P, points2d, confidence, threshold_px=threshold_px, min_views=min_views)
    else:
        raise ValueError(f"unknown pseudo-label method {method!r}; expected one of {PSEUDO_LABEL_METHODS}")
    # A point behind a camera that detected it is certainly wrong (an outlier can put it there).
    seen_behind = (confidence > 0) & ~in_front(P, points)
    weight = (((confidence > 0).sum(-2) >= min_views) & ~seen_behind.any(-2)).astype(points.dtype)
    return points, weight
