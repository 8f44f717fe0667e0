"""A first rig from the person's joints: relative pose of one view pair, then the others by PnP.

The joints of one frame seen by two views are point correspondences like any others, except that a
detector's left/right swap or a missed joint makes outliers; robust estimators (OpenCV's MAGSAC++ and RANSAC) remove them.  The
best-connected pair gives an essential matrix and its relative pose; the joints it triangulates
place each further view by PnP, most-connected first, so all views share the first pair's scale.
Everything here is in normalized image coordinates (K^-1 times undistorted pixels); the result is
the start of the bundle adjustment (`jaxpose.calibration.bundle`), which refines it.
"""

from __future__ import annotations

from collections.abc import Sequence

import functools

import cv2
import jax
import numpy as np

from jaxpose.camera import project_with_matrices
from jaxpose.triangulation import triangulate

# Correspondences given to RANSAC at most (a random subset): enough for a stable estimate, bounded time.
MAX_RANSAC_POINTS = 20_000
RANSAC_CONFIDENCE = 0.999


@functools.partial(jax.jit, static_argnames="method")
def triangulate_and_project(P, points2d, weights, method: str = "svd"):
    """Joints [F, J, 3] triangulated through P [C, 3, 4] from points2d [F, C, J, 2] under weights
    [F, C, J], and their homogeneous projections [F, C, J, 3] (the depth last).  Compiled once per
    shape: views left out have weight 0, so the views registered so far do not change the shape."""
    points = triangulate(P, points2d, weights, method=method)
    return points, project_with_matrices(P, points)


class CalibrationError(ValueError):
    """The detections cannot determine a rig; the message says which views and what is missing."""


def covisible_frames(valid: np.ndarray, min_joints: int) -> np.ndarray:
    """i64[C, C]: per view pair, the frames where both views see at least `min_joints` joints."""
    sees = valid.sum(-1) >= min_joints  # [F, C]
    return (sees[:, :, None] & sees[:, None, :]).sum(0)


def initial_rig(
    normalized: np.ndarray,
    valid: np.ndarray,
    camera_names: Sequence[str],
    threshold: float,
    min_joints: int,
    min_frames: int,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """(R f64[C, 3, 3], t f64[C, 3]): world = view 0's camera frame, unit = the first pair's baseline.

    normalized f64[F, C, J, 2] normalized image coordinates; valid bool[F, C, J]; threshold: the
    RANSAC inlier distance in normalized units (pixels / focal length).  Raises `CalibrationError`
    when no pair, or not every view, is connected through `min_frames` frames with `min_joints`
    joints seen by both views.
    """
    rng = np.random.default_rng(seed)
    C = normalized.shape[1]
    counts = covisible_frames(valid, min_joints)
    np.fill_diagonal(counts, -1)
    first, second = np.unravel_index(np.argmax(counts), counts.shape)
    if counts[first, second] < min_frames:
        raise CalibrationError(
            f"no pair of views sees the person together well enough: the best pair, {camera_names[first]} and"
            f" {camera_names[second]}, has {counts[first, second]} frames where both see >= {min_joints} joints;"
            f" calibration needs >= {min_frames}"
        )
    R = np.full((C, 3, 3), np.nan)
    t = np.full((C, 3), np.nan)
    R[first], t[first] = np.eye(3), np.zeros(3)
    R[second], t[second] = _relative_pose(normalized, valid, first, second, threshold, rng, camera_names)
    registered = [first, second]
    while len(registered) < C:
        points, usable = _triangulate_registered(normalized, valid, R, t, registered, threshold)
        candidates = [c for c in range(C) if c not in registered]
        support = [int((usable & valid[:, c]).sum()) for c in candidates]
        best = candidates[int(np.argmax(support))]
        if max(support) < min_frames * min_joints:
            raise CalibrationError(
                f"view {camera_names[best]} cannot be placed in the rig: it sees only {max(support)} of the joints"
                f" that the views {[camera_names[c] for c in registered]} triangulate; calibration needs"
                f" >= {min_frames * min_joints} ({min_frames} frames x {min_joints} joints)"
            )
        seen = usable & valid[:, best]
        R[best], t[best] = _place_by_pnp(points[seen], normalized[:, best][seen], threshold, rng, camera_names[best])
        registered.append(best)
    # Re-express every camera in view 0's frame: x_c = R_c R_0^T y + (t_c - R_c R_0^T t_0).
    relative = R @ R[0].T
    return relative, t - np.einsum("cij,j->ci", relative, t[0])


def _relative_pose(
    normalized: np.ndarray, valid: np.ndarray, a: int, b: int, threshold: float, rng: np.random.Generator,
    camera_names: Sequence[str],
) -> tuple[np.ndarray, np.ndarray]:
    """Pose of view b in view a's frame (x_b = R x_a + t, |t| = 1) from their common joints."""
    both = valid[:, a] & valid[:, b]
    points_a, points_b = normalized[:, a][both], normalized[:, b][both]
    if len(points_a) > MAX_RANSAC_POINTS:
        keep = rng.choice(len(points_a), MAX_RANSAC_POINTS, replace=False)
        points_a, points_b = points_a[keep], points_b[keep]
    cv2.setRNGSeed(int(rng.integers(2**31)))
    # MAGSAC++ rather than plain RANSAC: on a person's joints (few distinct depths, a detector's
    # outliers) plain RANSAC's best minimal sample is degrees off; MAGSAC's model is within ~0.5.
    essential, inliers = cv2.findEssentialMat(
        points_a, points_b, np.eye(3), method=cv2.USAC_MAGSAC, prob=RANSAC_CONFIDENCE, threshold=threshold
    )
    if essential is None:
        raise CalibrationError(f"views {camera_names[a]} and {camera_names[b]}: no essential matrix fits their common joints")
    # With few points the five-point solver may return several candidates stacked; keep the best one.
    _, R, t, _ = cv2.recoverPose(essential[:3], points_a, points_b, np.eye(3), mask=inliers)
    return R, t.ravel()


def _triangulate_registered(
    normalized: np.ndarray, valid: np.ndarray, R: np.ndarray, t: np.ndarray, registered: list[int], threshold: float
) -> tuple[np.ndarray, np.ndarray]:
    """Joints triangulated from the registered views, and bool[F, J]: seen by >= 2 of them and
    re-projecting within 3 thresholds in every one (so a left/right swap does not become a point)."""
    views = np.zeros(R.shape[0], bool)
    views[registered] = True
    # [C, 3, 4] normalized cameras; the views not yet placed (NaN) are zero and weigh nothing.
    P = np.where(views[:, None, None], np.concatenate([R, t[:, :, None]], axis=-1), 0.0)
    seen = valid & views[:, None]  # [F, C, J]
    points, projected = (np.asarray(a) for a in triangulate_and_project(P, normalized, seen.astype(np.float32)))
    depth = projected[..., 2]  # [F, C, J]
    error = np.linalg.norm(projected[..., :2] / np.where(depth > 0, depth, np.nan)[..., None] - normalized, axis=-1)
    consistent = np.where(seen, (depth > 0) & (error < 3 * threshold), True).all(axis=1)
    return points, consistent & (seen.sum(1) >= 2)


def _place_by_pnp(
    points: np.ndarray, observed: np.ndarray, threshold: float, rng: np.random.Generator, name: str
) -> tuple[np.ndarray, np.ndarray]:
    """A view's (R, t) from 3D joints and their normalized observations in it (RANSAC, then LM)."""
    cv2.setRNGSeed(int(rng.integers(2**31)))
    found, rvec, tvec, inliers = cv2.solvePnPRansac(
        points.astype(np.float64), observed.astype(np.float64), np.eye(3), None,
        reprojectionError=threshold, confidence=RANSAC_CONFIDENCE, iterationsCount=2000, flags=cv2.SOLVEPNP_EPNP,
    )  # fmt: skip
    if not found or inliers is None or len(inliers) < 6:
        raise CalibrationError(f"view {name}: PnP found no camera pose consistent with the joints the other views triangulate")
    inliers = inliers.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(points[inliers], observed[inliers].astype(np.float64), np.eye(3), None, rvec, tvec)
    return cv2.Rodrigues(rvec)[0], tvec.ravel()
