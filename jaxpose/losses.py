"""The paper's four self-supervised geometric losses (Sec. III-C), pure and model-agnostic.

Every function takes the lifter output `pred` f32[B, C, J, 3] (for each view, the root-relative
pose in THAT camera's frame, mm, root row zero) and a `MultiViewBatch`; any B, C >= 2 and J.

Choices the paper leaves open, made here once for all four terms:
- Units.  3D terms are in metres and 2D terms in focal-normalized image units (pixels / focal
  length), so that with the paper's weights (1, 1, 0.001, 0.01) the pseudo-label and re-projection
  terms have gradients of the same order for a subject a few metres away, and no term depends on the
  image resolution.  "L2" is the squared Euclidean distance per joint; "L1" the sum of absolute
  coordinate differences per joint (PyTorch's L1 summed over coordinates).
- Reduction.  Means over the valid (sample, view[, view], joint) entries rather than the paper's
  sums, so the loss scale does not change with batch size, C or J.  The root joint, zero by
  construction, is excluded from every mean.
- Masks.  A view is usable when its root (pelvis) has confidence > 0 (the lifter input is root-
  relative).  A joint whose pseudo-label has `pseudo3d_weight` 0 (too few consistent views) teaches
  nothing through any term, and neither does any joint of a sample whose root label has weight 0.
  A detection serves as a target (L_proj's 2D target, L_con's reference view, a view of L_out's
  triangulation) only with confidence > 0 and, when the batch carries one, `detection_weight` > 0:
  the robust pseudo-label methods set it to 0 for views that disagree with the label (outliers).
  Such a detection is still an input, whose prediction the terms pull towards the consistent
  views.  Masked entries are removed with `where`, so a missing joint can never inject a NaN into
  the loss or its gradient.
- Consistency: view c is the target for view c' as the paper says ("we consider the camera view c
  as the ground-truth"): a stop-gradient on the target side, all ordered pairs c != c'.
- Output triangulation: each view's prediction is placed at the triangulated root, projected into
  its own image (pinhole: detections are undistorted on load), the C projections are triangulated
  and the result is a constant target (stop-gradient).  The authors' release triangulated the input
  detections again here; we follow the paper.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

from jaxpose.camera import (
    MM_PER_M,
    Cameras,
    project_from_camera,
    projection_matrices,
    rotate_between_cameras,
    world_to_camera,
)
from jaxpose.data.batch import MultiViewBatch
from jaxpose.skeleton import ROOT
from jaxpose.triangulation import Method, triangulate


@struct.dataclass
class LossWeights:
    """The paper's omega_1..omega_4 (defaults: the paper's values).  A pytree of scalars, so
    weights may be traced values inside `jax.jit` (e.g. switching a term on without a recompile)."""

    input_triangulation: float | jax.Array = 1.0
    reprojection: float | jax.Array = 1.0
    consistency: float | jax.Array = 0.001
    output_triangulation: float | jax.Array = 0.01


def _masked_mean(values: jax.Array, mask: jax.Array) -> jax.Array:
    mask = jnp.broadcast_to(mask, values.shape).astype(values.dtype)
    total = jnp.sum(jnp.where(mask > 0, values * mask, 0.0))
    return total / jnp.maximum(jnp.sum(mask), 1.0)


def _without_root(mask: jax.Array) -> jax.Array:
    """Zero the root joint (last axis) of a mask: its error is zero by construction."""
    return jnp.asarray(mask).at[..., ROOT].set(0.0)


def usable_views(batch: MultiViewBatch) -> jax.Array:
    """f32[B, C]: 1 where the view's root was detected, so its root-relative input is defined."""
    return jnp.asarray(batch.confidence[..., ROOT] > 0, dtype=jnp.float32)


def _label_weight(batch: MultiViewBatch) -> jax.Array:
    """f32[B, J]: the pseudo-label weight of each joint times that of its root (the labels are
    used root-relative, so an untrusted root spoils every joint of its sample)."""
    if batch.pseudo3d_weight is None:
        return jnp.ones(batch.pseudo3d.shape[:-1], jnp.float32)
    label = jnp.asarray(batch.pseudo3d_weight)
    return label * label[:, ROOT : ROOT + 1]


def target_weight(batch: MultiViewBatch) -> jax.Array:
    """f32[B, C, J]: how far each detection may serve as a training target; 0 where it is missing
    (confidence 0) or an outlier (`detection_weight` 0)."""
    detected = jnp.asarray(batch.confidence) > 0
    weight = jnp.ones(detected.shape, jnp.float32) if batch.detection_weight is None else batch.detection_weight
    return jnp.where(detected, weight, 0.0)


def _root_relative(points: jax.Array) -> jax.Array:
    return points - points[..., ROOT : ROOT + 1, :]


def _world_pose_in_views(cameras: Cameras, pose_world: jax.Array) -> jax.Array:
    """World poses [B, J, 3] -> root-relative poses in every camera [B, C, J, 3]."""
    return _root_relative(world_to_camera(cameras, pose_world[:, None]))


def _root_in_cameras(batch: MultiViewBatch) -> jax.Array:
    """[B, C, 1, 3]: the triangulated root in every camera's frame, where the predictions are placed."""
    return world_to_camera(batch.cameras, batch.pseudo3d[:, None, ROOT : ROOT + 1, :])


def _in_every_camera(cameras: Cameras, pred: jax.Array) -> jax.Array:
    """[B, C, C', J, 3]: the prediction of view c' rotated into the axes of camera c."""
    source = jax.tree.map(lambda field: field[:, None, :], cameras)  # c' along axis 2
    target = jax.tree.map(lambda field: field[:, :, None], cameras)  # c along axis 1
    return rotate_between_cameras(source, target, pred[:, None])


def _label_penalty(target: jax.Array, pred: jax.Array, robust_scale_mm: float | jax.Array) -> jax.Array:
    """The "L2" of L_in and L_out per joint, m^2: the squared distance (the paper) when
    `robust_scale_mm` is 0, else the pseudo-Huber 2 d^2 (sqrt(1 + (r / d)^2) - 1) with d that scale:
    the squared distance for residuals well below d, growing linearly (like an L1) above it, so that
    a label that is hundreds of millimetres off (a left/right swap in two views) pulls no harder
    than one a few centimetres off."""
    squared = jnp.sum(((target - pred) / MM_PER_M) ** 2, axis=-1)
    scale = jnp.asarray(robust_scale_mm, squared.dtype) / MM_PER_M
    safe_scale = jnp.where(scale > 0, scale, 1.0)
    huber = 2.0 * safe_scale**2 * (jnp.sqrt(1.0 + squared / safe_scale**2) - 1.0)
    return jnp.where(scale > 0, huber, squared)


def input_triangulation_loss(pred: jax.Array, batch: MultiViewBatch, robust_scale_mm: float | jax.Array = 0.0) -> jax.Array:
    """L_in (Eq. 2): L2 between each view's prediction and the pseudo-label in that camera."""
    target = _world_pose_in_views(batch.cameras, batch.pseudo3d)
    penalty = _label_penalty(target, pred, robust_scale_mm)  # [B, C, J]
    mask = usable_views(batch)[..., None] * _label_weight(batch)[:, None, :]
    return _masked_mean(penalty, _without_root(mask))


def reprojection_loss(pred: jax.Array, batch: MultiViewBatch) -> jax.Array:
    """L_proj (Eq. 3): every view's prediction, placed at the triangulated root, projected into
    every view c (C x C pairs), L1 against view c's root-relative detections."""
    cameras = batch.cameras
    # View c' placed at the root and taken to camera c is its pose rotated into camera c's axes plus
    # the root's position in camera c: one 3x3 rotation per view pair, no round trip through world.
    rotated = _in_every_camera(cameras, pred)  # [B, C, C', J, 3]
    target_cameras = jax.tree.map(lambda field: field[:, :, None], cameras)  # [B, C, 1]
    projected = project_from_camera(target_cameras, rotated + _root_in_cameras(batch)[:, :, None])  # [B,C,C',J,2]
    projected = projected - projected[..., ROOT : ROOT + 1, :]
    detected = batch.keypoints2d - batch.keypoints2d[..., ROOT : ROOT + 1, :]  # [B, C, J, 2]
    focal = jnp.stack([cameras.K[..., 0, 0], cameras.K[..., 1, 1]], axis=-1)[:, :, None, None, :]  # [B,C,1,1,2]
    absolute_error = jnp.sum(jnp.abs(projected - detected[:, :, None]) / focal, axis=-1)  # [B, C, C', J]
    targets = target_weight(batch)
    targets = targets * targets[..., ROOT : ROOT + 1]  # the detections are taken root-relative
    mask = targets[:, :, None, :] * usable_views(batch)[:, None, :, None] * _label_weight(batch)[:, None, None, :]
    return _masked_mean(absolute_error, _without_root(mask))


def consistency_loss(pred: jax.Array, batch: MultiViewBatch) -> jax.Array:
    """L_con (Eq. 4): view c' rotated into camera c against view c (the target), c != c', L1."""
    rotated = _in_every_camera(batch.cameras, pred)  # [B, C, C', J, 3]
    reference = jax.lax.stop_gradient(pred)[:, :, None]  # [B, C, 1, J, 3]
    absolute_error = jnp.sum(jnp.abs(rotated - reference), axis=-1) / MM_PER_M  # [B, C, C', J]
    views = usable_views(batch)
    num_views = views.shape[-1]
    pair = views[:, :, None] * views[:, None, :] * (1.0 - jnp.eye(num_views, dtype=pred.dtype))
    # The reference joint must be a detection worth a target: a guess for a missing joint, or the
    # prediction from an outlier, is no ground truth for the other views.
    mask = pair[..., None] * (target_weight(batch) * _label_weight(batch)[:, None, :])[:, :, None, :]
    return _masked_mean(absolute_error, _without_root(mask))


def output_triangulation(pred: jax.Array, batch: MultiViewBatch, method: Method = "svd") -> jax.Array:
    """Y_out (Sec. III-C): triangulation of the C predictions' projections, world mm [B, J, 3]."""
    cameras = batch.cameras.without_distortion()
    projected = project_from_camera(cameras, pred + _root_in_cameras(batch))  # [B, C, J, 2]
    views = jnp.broadcast_to(usable_views(batch)[..., None], projected.shape[:-1])
    # Views whose detection of a joint is missing or an outlier do not vote on it, unless fewer
    # than two views would remain: then all usable views do, so the system stays determined.
    trusted = views * target_weight(batch)
    weights = jnp.where(jnp.sum(trusted > 0, axis=-2, keepdims=True) >= 2, trusted, views)
    return triangulate(projection_matrices(cameras), projected, weights, method)


def output_triangulation_loss(
    pred: jax.Array, batch: MultiViewBatch, method: Method = "svd", robust_scale_mm: float | jax.Array = 0.0
) -> jax.Array:
    """L_out (Eq. 5): L2 between each view's prediction and the output triangulation (a constant)."""
    target_world = jax.lax.stop_gradient(output_triangulation(pred, batch, method))
    target = _world_pose_in_views(batch.cameras, target_world)
    penalty = _label_penalty(target, pred, robust_scale_mm)
    mask = usable_views(batch)[..., None] * _label_weight(batch)[:, None, :]
    return _masked_mean(penalty, _without_root(jnp.broadcast_to(mask, penalty.shape)))


TERMS = ("input_triangulation", "reprojection", "consistency", "output_triangulation")


def loss_terms(
    pred: jax.Array, batch: MultiViewBatch, triangulation: Method = "svd", robust_scale_mm: float | jax.Array = 0.0
) -> dict[str, jax.Array]:
    """The four unweighted terms L_i, by name (`TERMS`).  `robust_scale_mm` > 0 makes the "L2" of
    L_in and L_out a pseudo-Huber of that scale (see `_label_penalty`)."""
    return {
        "input_triangulation": input_triangulation_loss(pred, batch, robust_scale_mm),
        "reprojection": reprojection_loss(pred, batch),
        "consistency": consistency_loss(pred, batch),
        "output_triangulation": output_triangulation_loss(pred, batch, triangulation, robust_scale_mm),
    }


def gradient_shares(
    pred: jax.Array,
    batch: MultiViewBatch,
    weights: LossWeights = LossWeights(),
    triangulation: Method = "svd",
    robust_scale_mm: float | jax.Array = 0.0,
) -> dict[str, jax.Array]:
    """Each term's share of the gradient with respect to the lifter output: the norm of
    d(omega_i L_i)/d pred over the sum of the four norms (0 for a term whose weight is 0).

    This is what a term does to the model: a term whose share stays near 0 changes nothing,
    whatever its value.  One backward pass through the losses (not the network) per term.
    """

    def stacked(p):
        terms = loss_terms(p, batch, triangulation, robust_scale_mm)
        return jnp.stack([getattr(weights, name) * terms[name] for name in TERMS])

    _, pullback = jax.vjp(stacked, pred)
    (grads,) = jax.vmap(pullback)(jnp.eye(len(TERMS), dtype=pred.dtype))
    norms = jnp.sqrt(jnp.sum(jnp.square(grads).reshape(len(TERMS), -1), axis=-1))
    shares = norms / jnp.maximum(jnp.sum(norms), 1e-30)
    return dict(zip(TERMS, shares))


def total_loss(
    pred: jax.Array,
    batch: MultiViewBatch,
    weights: LossWeights = LossWeights(),
    triangulation: Method = "svd",
    robust_scale_mm: float | jax.Array = 0.0,
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """omega_1 L_in + omega_2 L_proj + omega_3 L_con + omega_4 L_out (Eq. 1) and the four terms.

    `triangulation` picks the solver of the output triangulation ("svd" is the reference DLT,
    "normal" the closed-form least squares that is faster on CPU; see `jaxpose.triangulation`);
    `robust_scale_mm` > 0 turns the squared distances of L_in and L_out into a pseudo-Huber.
    """
    if pred.shape != batch.keypoints2d.shape[:-1] + (3,):
        raise ValueError(f"total_loss: pred must be [B, C, J, 3] = {batch.keypoints2d.shape[:-1] + (3,)}, got {pred.shape}")
    terms = loss_terms(pred, batch, triangulation, robust_scale_mm)
    loss = sum(getattr(weights, name) * terms[name] for name in TERMS)
    return loss, terms
