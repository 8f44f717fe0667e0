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
  relative).  An input joint counts when its confidence > 0; a pseudo-label joint counts with its
  `pseudo3d_weight`.  Masked entries are removed with `where`, so a missing joint can never inject
  a NaN into the loss or its gradient.
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
    Cameras,
    camera_to_world,
    project_from_camera,
    projection_matrices,
    rotate_between_cameras,
    world_to_camera,
)
from jaxpose.data.batch import MultiViewBatch
from jaxpose.triangulation import Method, triangulate

MM_PER_M = 1000.0
ROOT = 0


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
    if batch.pseudo3d_weight is None:
        return jnp.ones(batch.pseudo3d.shape[:-1], jnp.float32)
    return jnp.asarray(batch.pseudo3d_weight)


def _root_relative(points: jax.Array) -> jax.Array:
    return points - points[..., ROOT : ROOT + 1, :]


def _world_pose_in_views(cameras: Cameras, pose_world: jax.Array) -> jax.Array:
    """World poses [B, J, 3] -> root-relative poses in every camera [B, C, J, 3]."""
    return _root_relative(world_to_camera(cameras, pose_world[:, None]))


def _place_at_root(cameras: Cameras, pred: jax.Array, root_world: jax.Array) -> jax.Array:
    """Camera-frame absolute poses: each view's prediction translated to the root's position."""
    root_camera = world_to_camera(cameras, root_world[:, None, None, :])  # [B, C, 1, 3]
    return pred + root_camera


def input_triangulation_loss(pred: jax.Array, batch: MultiViewBatch) -> jax.Array:
    """L_in (Eq. 2): L2 between each view's prediction and the pseudo-label in that camera."""
    target = _world_pose_in_views(batch.cameras, batch.pseudo3d)
    squared = jnp.sum(((target - pred) / MM_PER_M) ** 2, axis=-1)  # [B, C, J]
    label = _label_weight(batch)
    # The target is root-relative, so an untrusted root spoils every joint of its sample.
    mask = usable_views(batch)[..., None] * (label * label[:, ROOT : ROOT + 1])[:, None, :]
    return _masked_mean(squared, _without_root(mask))


def reprojection_loss(pred: jax.Array, batch: MultiViewBatch) -> jax.Array:
    """L_proj (Eq. 3): every view's prediction, placed at the triangulated root, projected into
    every view c (C x C pairs), L1 against view c's root-relative detections."""
    cameras = batch.cameras
    absolute = _place_at_root(cameras, pred, batch.pseudo3d[:, ROOT])  # [B, C', J, 3]
    world = camera_to_world(cameras, absolute)  # [B, C', J, 3]
    target_cameras = jax.tree.map(lambda field: field[:, :, None], cameras)  # [B, C, 1]
    projected = project_from_camera(target_cameras, world_to_camera(target_cameras, world[:, None]))  # [B,C,C',J,2]
    projected = projected - projected[..., ROOT : ROOT + 1, :]
    detected = batch.keypoints2d - batch.keypoints2d[..., ROOT : ROOT + 1, :]  # [B, C, J, 2]
    focal = jnp.stack([cameras.K[..., 0, 0], cameras.K[..., 1, 1]], axis=-1)[:, :, None, None, :]  # [B,C,1,1,2]
    absolute_error = jnp.sum(jnp.abs(projected - detected[:, :, None]) / focal, axis=-1)  # [B, C, C', J]
    detected_valid = (batch.confidence > 0) & (batch.confidence[..., ROOT : ROOT + 1] > 0)  # [B, C, J]
    mask = (
        detected_valid[:, :, None, :].astype(pred.dtype)
        * usable_views(batch)[:, None, :, None]
        * _label_weight(batch)[:, None, None, ROOT : ROOT + 1]
    )
    return _masked_mean(absolute_error, _without_root(mask))


def consistency_loss(pred: jax.Array, batch: MultiViewBatch) -> jax.Array:
    """L_con (Eq. 4): view c' rotated into camera c against view c (the target), c != c', L1."""
    cameras = batch.cameras
    source = jax.tree.map(lambda field: field[:, None, :], cameras)  # c' along axis 2
    target = jax.tree.map(lambda field: field[:, :, None], cameras)  # c along axis 1
    rotated = rotate_between_cameras(source, target, pred[:, None])  # [B, C, C', J, 3]
    reference = jax.lax.stop_gradient(pred)[:, :, None]  # [B, C, 1, J, 3]
    absolute_error = jnp.sum(jnp.abs(rotated - reference), axis=-1) / MM_PER_M  # [B, C, C', J]
    views = usable_views(batch)
    num_views = views.shape[-1]
    pair = views[:, :, None] * views[:, None, :] * (1.0 - jnp.eye(num_views, dtype=pred.dtype))
    return _masked_mean(absolute_error, _without_root(jnp.ones_like(absolute_error) * pair[..., None]))


def output_triangulation(pred: jax.Array, batch: MultiViewBatch, method: Method = "svd") -> jax.Array:
    """Y_out (Sec. III-C): triangulation of the C predictions' projections, world mm [B, J, 3]."""
    cameras = batch.cameras.without_distortion()
    absolute = _place_at_root(cameras, pred, batch.pseudo3d[:, ROOT])
    projected = project_from_camera(cameras, absolute)  # [B, C, J, 2]
    weights = jnp.broadcast_to(usable_views(batch)[..., None], projected.shape[:-1])
    return triangulate(projection_matrices(cameras), projected, weights, method)


def output_triangulation_loss(pred: jax.Array, batch: MultiViewBatch, method: Method = "svd") -> jax.Array:
    """L_out (Eq. 5): L2 between each view's prediction and the output triangulation (a constant)."""
    target_world = jax.lax.stop_gradient(output_triangulation(pred, batch, method))
    target = _world_pose_in_views(batch.cameras, target_world)
    squared = jnp.sum(((target - pred) / MM_PER_M) ** 2, axis=-1)
    mask = usable_views(batch)[..., None] * _label_weight(batch)[:, None, ROOT : ROOT + 1]
    return _masked_mean(squared, _without_root(jnp.broadcast_to(mask, squared.shape)))


def total_loss(
    pred: jax.Array, batch: MultiViewBatch, weights: LossWeights = LossWeights(), triangulation: Method = "svd"
) -> tuple[jax.Array, dict[str, jax.Array]]:
    """omega_1 L_in + omega_2 L_proj + omega_3 L_con + omega_4 L_out (Eq. 1) and the four terms.

    `triangulation` picks the solver of the output triangulation ("svd" is the reference DLT,
    "normal" the closed-form least squares that is faster on CPU; see `jaxpose.triangulation`).
    """
    if pred.shape != batch.keypoints2d.shape[:-1] + (3,):
        raise ValueError(f"total_loss: pred must be [B, C, J, 3] = {batch.keypoints2d.shape[:-1] + (3,)}, got {pred.shape}")
    terms = {
        "input_triangulation": input_triangulation_loss(pred, batch),
        "reprojection": reprojection_loss(pred, batch),
        "consistency": consistency_loss(pred, batch),
        "output_triangulation": output_triangulation_loss(pred, batch, triangulation),
    }
    loss = (
        weights.input_triangulation * terms["input_triangulation"]
        + weights.reprojection * terms["reprojection"]
        + weights.consistency * terms["consistency"]
        + weights.output_triangulation * terms["output_triangulation"]
    )
    return loss, terms
