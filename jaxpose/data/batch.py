"""`MultiViewBatch`, the unit of training data, and its host-side validation.

Validation runs in numpy on the host, before data enter `jax.jit`: inside the step a bad value can
only become a NaN, outside it can become an error message that names the field, shape and index.  A field
that is also a data set's per-sample array has the shape `jaxpose.data.samples.Samples` gives it.
"""

from __future__ import annotations

import jax
import numpy as np
from flax import struct

from jaxpose.camera import Cameras, camera_centres
from jaxpose.data import samples
from jaxpose.formats.rig_cameras import MIN_BASELINE_MM


@struct.dataclass
class MultiViewBatch:
    """B synchronized instants seen by C calibrated views, J joints.

    keypoints2d:     f32[B, C, J, 2] detected 2D, pixels.
    confidence:      f32[B, C, J] detector confidence in [0, 1]; 0 = missing joint or view.
    cameras:         `Cameras` with leading [B, C].
    pseudo3d:        f32[B, J, 3] world mm, the input triangulation (the pseudo-label).
    pseudo3d_weight: f32[B, J] in [0, 1]; 0 = this joint's pseudo-label is not trusted (too few
                     consistent views) and teaches nothing.  None means all ones.
    target3d:        f32[B, J, 3] world mm ground truth, for evaluation and the supervised baseline
                     only; self-supervised training never reads it.
    detection_weight: f32[B, C, J] in [0, 1]; 0 = this detection must not serve as a training
                     target (L_proj's 2D target, L_con's reference view, a view of L_out's
                     triangulation): it disagrees with its joint's pseudo-label, as the robust
                     pseudo-label methods find outliers.  The lifter still sees it as input.
                     None means every detection with confidence > 0.
    window2d:        f32[B, C, T, J, 2] pixels: the T frames of each view centred on the sample's instant,
                     the input of a temporal lifter (`jaxpose.model.LifterNetwork.temporal_window`); the
                     losses use the centre frame, `keypoints2d`.  None for the frame lifter.
    window_confidence: f32[B, C, T, J], the confidence of `window2d`.
    """

    keypoints2d: jax.Array
    confidence: jax.Array
    cameras: Cameras
    pseudo3d: jax.Array
    pseudo3d_weight: jax.Array | None = None
    target3d: jax.Array | None = None
    detection_weight: jax.Array | None = None
    window2d: jax.Array | None = None
    window_confidence: jax.Array | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        """(B, C, J)."""
        return tuple(self.confidence.shape)


class BatchValidationError(ValueError):
    """Raised by `validate_batch`; the message names the field, its shape and the first bad index."""


def _first_index(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def _check_shape(name: str, array, expected: tuple[int | None, ...]) -> np.ndarray:
    array = np.asarray(array)
    if array.ndim != len(expected) or any(e is not None and s != e for s, e in zip(array.shape, expected)):
        pretty = tuple("?" if e is None else e for e in expected)
        raise BatchValidationError(f"{name}: expected shape {pretty}, got {array.shape}")
    if not np.issubdtype(array.dtype, np.floating):
        raise BatchValidationError(f"{name}: expected a floating dtype, got {array.dtype} (shape {array.shape})")
    return array


def _check_finite(name: str, array: np.ndarray) -> None:
    bad = ~np.isfinite(array)
    if bad.any():
        index = _first_index(bad)
        raise BatchValidationError(
            f"{name}: {int(bad.sum())} non-finite values (NaN/inf) in shape {array.shape}; first at index {index}"
            f" = {array[index]}"
        )


def validate_cameras(cameras: Cameras, batch_shape: tuple[int, ...], name: str = "cameras") -> None:
    """Finite intrinsics with positive focal lengths, proper rotations, distinct camera centres."""
    K = _check_shape(f"{name}.K", cameras.K, (*batch_shape, 3, 3))
    R = _check_shape(f"{name}.R", cameras.R, (*batch_shape, 3, 3))
    t = _check_shape(f"{name}.t", cameras.t, (*batch_shape, 3))
    for field, array in (("K", K), ("R", R), ("t", t)):
        _check_finite(f"{name}.{field}", array)
    if cameras.dist is not None:
        dist = _check_shape(f"{name}.dist", cameras.dist, (*batch_shape, 5))
        _check_finite(f"{name}.dist", dist)
    bad_focal = (K[..., 0, 0] <= 0) | (K[..., 1, 1] <= 0)
    if bad_focal.any():
        raise BatchValidationError(
            f"{name}.K: non-positive focal length at index {_first_index(bad_focal)} (shape {K.shape})"
        )
    bad_row = np.abs(K[..., 2, :] - np.array([0.0, 0.0, 1.0])).max(-1) > 1e-6
    if bad_row.any():
        raise BatchValidationError(f"{name}.K: last row must be (0, 0, 1); bad at index {_first_index(bad_row)}")
    orthogonality = np.abs(np.einsum("...ji,...jk->...ik", R, R) - np.eye(3)).max((-2, -1))
    not_rotation = (orthogonality > 1e-3) | (np.linalg.det(R) < 0)
    if not_rotation.any():
        raise BatchValidationError(
            f"{name}.R: not a rotation (orthonormal, det +1) at index {_first_index(not_rotation)} (shape {R.shape})"
        )
    if len(batch_shape) >= 1 and batch_shape[-1] >= 2:
        centers = camera_centres(R, t)
        gaps = np.linalg.norm(centers[..., :, None, :] - centers[..., None, :, :], axis=-1)
        gaps = gaps + np.eye(batch_shape[-1]) * 1e9
        coincident = gaps.min(-1) < MIN_BASELINE_MM
        if coincident.any():
            raise BatchValidationError(
                f"{name}: two views share one camera centre (baseline < {MIN_BASELINE_MM:g} mm) at index"
                f" {_first_index(coincident)}; triangulation needs distinct viewpoints"
            )


def validate_batch(batch: MultiViewBatch, min_views: int = 2) -> None:
    """Reject what would silently poison training; raises `BatchValidationError`.

    Checks: shapes and float dtypes of every field; no NaN/inf anywhere; confidence,
    pseudo3d_weight and detection_weight in [0, 1]; at least `min_views` usable views (root and one more joint with
    confidence > 0) in every sample; cameras (see `validate_cameras`); no camera with most of a
    sample's joints behind it; every pseudo-label of positive weight in front of every camera that
    sees it.
    """
    if not isinstance(batch.cameras, Cameras):
        raise BatchValidationError(f"cameras: expected a jaxpose.camera.Cameras, got {type(batch.cameras).__name__}")
    keypoints = np.asarray(batch.keypoints2d)
    if keypoints.ndim != 4 or keypoints.shape[-1] != 2:
        raise BatchValidationError(f"keypoints2d: expected shape (B, C, J, 2), got {keypoints.shape}")
    B, C, J, _ = keypoints.shape
    if B == 0 or J < 2:
        raise BatchValidationError(
            f"keypoints2d: need at least 1 sample and 2 joints (root and one more), got shape {keypoints.shape}"
        )
    keypoints = _check_shape("keypoints2d", keypoints, samples.field_shape("keypoints2d", B, C, J))
    confidence = _check_shape("confidence", batch.confidence, samples.field_shape("confidence", B, C, J))
    pseudo3d = _check_shape("pseudo3d", batch.pseudo3d, samples.field_shape("pseudo3d", B, C, J))
    _check_finite("keypoints2d", keypoints)
    _check_finite("confidence", confidence)
    _check_finite("pseudo3d", pseudo3d)
    out_of_range = (confidence < 0) | (confidence > 1)
    if out_of_range.any():
        index = _first_index(out_of_range)
        raise BatchValidationError(f"confidence: values must lie in [0, 1]; {confidence[index]} at index {index}")
    for name in ("pseudo3d_weight", "detection_weight"):
        if getattr(batch, name) is not None:
            weight = _check_shape(name, getattr(batch, name), samples.field_shape(name, B, C, J))
            _check_finite(name, weight)
            outside = (weight < 0) | (weight > 1)
            if outside.any():
                index = _first_index(outside)
                raise BatchValidationError(f"{name}: values must lie in [0, 1]; {weight[index]} at index {index}")
    if batch.target3d is not None:
        target = _check_shape("target3d", batch.target3d, samples.field_shape("target3d", B, C, J))
        _check_finite("target3d", target)
    if (batch.window2d is None) != (batch.window_confidence is None):
        raise BatchValidationError("window2d and window_confidence: both or neither")
    if batch.window2d is not None:
        T = np.shape(batch.window2d)[2] if np.ndim(batch.window2d) == 5 else None
        window = _check_shape("window2d", batch.window2d, (B, C, T, J, 2))
        window_confidence = _check_shape("window_confidence", batch.window_confidence, (B, C, T, J))
        _check_finite("window2d", window)
        _check_finite("window_confidence", window_confidence)
        if ((window_confidence < 0) | (window_confidence > 1)).any():
            raise BatchValidationError("window_confidence: values must lie in [0, 1]")
    if C < min_views:
        raise BatchValidationError(f"keypoints2d: {C} views in shape {keypoints.shape}; need at least {min_views}")
    usable = (confidence[..., 0] > 0) & ((confidence[..., 1:] > 0).sum(-1) >= 1)
    too_few = usable.sum(-1) < min_views
    if too_few.any():
        sample = int(np.argmax(too_few))
        raise BatchValidationError(
            f"confidence: sample {sample} has {int(usable[sample].sum())} usable views (root and another joint with"
            f" confidence > 0), need at least {min_views}; drop it or fix the detections"
        )
    validate_cameras(batch.cameras, (B, C))
    depth = np.einsum("bcij,bnj->bcni", np.asarray(batch.cameras.R), pseudo3d)[..., 2] + np.asarray(
        batch.cameras.t
    )[:, :, None, 2]
    detected = confidence > 0
    behind = (depth <= 0) & detected
    # One joint behind a camera can be an outlier's triangulation (its label then has weight 0); most
    # of a sample's joints behind a camera cannot: that camera faces away or its convention is wrong.
    share = behind.sum(-1) / np.maximum(detected.sum(-1), 1)
    facing_away = share > 0.5
    if facing_away.any():
        sample, view = _first_index(facing_away)
        raise BatchValidationError(
            f"pseudo3d: {share[sample, view]:.0%} of the detected joints of sample {sample} are behind camera {view}:"
            " it faces away; check the camera convention (x_cam = R x_world + t, t in mm)"
        )
    if batch.pseudo3d_weight is not None:  # a label of weight 0 is never used, wherever it lies
        behind &= np.asarray(batch.pseudo3d_weight)[:, None, :] > 0
    if behind.any():
        index = _first_index(behind)
        raise BatchValidationError(
            f"pseudo3d: joint {index[2]} of sample {index[0]} is behind camera {index[1]} (depth {depth[index]:.1f} mm);"
            " check the camera convention (x_cam = R x_world + t, t in mm)"
        )
