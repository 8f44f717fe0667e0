"""How good a lifter is without 3D ground truth: what its single-view predictions say about each other.

A user's own rig has no motion capture.  Its held-out recordings still hold what the training
losses use, several calibrated views of each instant, so three measures need no ground truth
(each per camera, the camera whose view was lifted, and overall):

- **disagreement_mm**: the single-view predictions of one instant, each turned from its camera's
  axes into the world's, differ from each other by this much (mean joint distance to the other
  views' predictions, root-relative).  One pose seen from several cameras has one shape; a lifter
  that guesses depth differently per view does not.
- **reprojection_px**: each prediction, placed at the triangulated root, projected into the
  *other* views and compared with their detections (mean pixel distance over detected joints).
  It checks depth, which a view cannot check in itself.  Detector noise sets a floor under it.
- **triangulation_p_mpjpe_mm**: P-MPJPE against the held-out triangulation of all views (in the
  lifted view's camera frame), the pseudo-label the lifter would have been trained towards.

What a measure cannot score counts as a failure, never as left out: a prediction that is not finite, or a
joint it places behind a camera it is projected into, scores `FAILED` (1000 mm or px, far beyond any working
lifter), so a diverged model ranks last instead of first.  A healthy lifter has no such cells, and its
values are unchanged by the rule.

Which one to select models by is measured on Human3.6M, where the ground truth is known: docs/rig.md
("Train on your own rig") gives the rank correlations with the true P-MPJPE.
"""

from __future__ import annotations

import numpy as np

from jaxpose.camera import projection_matrices
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.training.evaluation import compute_metrics, poses_in_views

METRICS = ("disagreement_mm", "reprojection_px", "triangulation_p_mpjpe_mm")
CHUNK = 2048  # instants per block of the pairwise measures
FAILED = 1000.0
"""The score (mm or px) of what cannot be scored: a non-finite prediction, a joint behind a camera."""


def self_consistency(pred: np.ndarray, dataset: MultiViewDataset, triangulated: np.ndarray, labelled: np.ndarray) -> dict:
    """The three measures of the module docstring for predictions [N, C, J, 3] (mm, root-relative,
    each view's camera frame) of the (undistorted) `dataset`, whose views' triangulation is
    `triangulated` [N, J, 3] world mm with `labelled` bool[N, J] where it is defined.

    Returns {metric: {"overall": float, "per_camera": [C floats]}} (NaN where a camera has no lifted view).
    """
    N, C, J, _ = pred.shape
    dataset = dataset.undistorted()
    lifted = dataset.samples.confidence[..., 0] > 0  # [N, C]: views whose root was detected
    disagreement, reprojection = np.empty((N, C)), np.empty((N, C))
    for start in range(0, N, CHUNK):  # bounded memory: [chunk, C, C, J, 3] intermediates
        rows = np.arange(start, min(start + CHUNK, N))
        disagreement[rows], reprojection[rows] = _view_agreement(pred[rows], dataset, rows, triangulated[rows], labelled[rows])

    # (c) Against the triangulation, where every joint of the instant has a label.
    target = poses_in_views(dataset, triangulated)
    complete = labelled.all(-1)
    finite = np.isfinite(pred).all((-2, -1))  # [N, C]
    per_pose, _ = compute_metrics(np.where(finite[..., None, None], pred, 0.0).reshape(N * C, J, 3), target.reshape(N * C, J, 3).astype(np.float32))
    against_triangulation = np.where(finite, per_pose["p_mpjpe"].reshape(N, C), FAILED)
    against_triangulation = np.where(complete[:, None], against_triangulation, np.nan)

    measures = {"disagreement_mm": disagreement, "reprojection_px": reprojection, "triangulation_p_mpjpe_mm": against_triangulation}
    return {name: _summary(values, lifted) for name, values in measures.items()}


def _view_agreement(pred, dataset: MultiViewDataset, rows, triangulated, labelled) -> tuple[np.ndarray, np.ndarray]:
    """Measures (a) and (b) of the module docstring for the instants `rows`: two f[n, C]."""
    C = pred.shape[1]
    cameras = dataset.cameras_for(rows)
    R = np.asarray(cameras.R, np.float64)  # [n, C, 3, 3]
    lifted = dataset.samples.confidence[rows, :, 0] > 0
    world = np.einsum("ncij,ncki->nckj", R, pred.astype(np.float64))  # R^T p: camera axes -> world axes

    # (a) Each lifted view against the other lifted views of its instant (a non-finite pair scores FAILED).
    pairwise = np.linalg.norm(world[:, :, None] - world[:, None], axis=-1).mean(-1)  # [n, C, C]
    others = lifted[:, None, :] & lifted[:, :, None] & ~np.eye(C, dtype=bool)
    pairwise = np.where(others & ~np.isfinite(pairwise), FAILED, pairwise)
    with np.errstate(invalid="ignore", divide="ignore"):
        disagreement = np.where(others, pairwise, 0.0).sum(-1) / others.sum(-1)  # NaN without another view

    # (b) Placed at the triangulated root, into the other views.
    placed = world + triangulated[:, None, :1].astype(np.float64)  # [n, C, J, 3] world
    P = np.asarray(projection_matrices(cameras), np.float64)  # [n, C', 3, 4]
    homogeneous = np.concatenate([placed, np.ones_like(placed[..., :1])], -1)
    projected = np.einsum("nvik,ncjk->ncvji", P, homogeneous)  # [n, C (lifted), C' (into), J, 3]
    depth = projected[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        pixels = projected[..., :2] / depth[..., None]
    distance = np.linalg.norm(pixels - dataset.samples.keypoints2d[rows][:, None].astype(np.float64), axis=-1)  # [n, C, C', J]
    distance = np.where((depth > 0) & np.isfinite(distance), distance, FAILED)  # behind the camera, or not finite
    seen = (dataset.samples.confidence[rows][:, None] > 0) & labelled[:, None, None, :1]
    seen = seen & ~np.eye(C, dtype=bool)[None, :, :, None]
    with np.errstate(invalid="ignore", divide="ignore"):
        reprojection = np.where(seen, distance, 0.0).sum((2, 3)) / seen.sum((2, 3))
    return disagreement, reprojection


def _summary(values: np.ndarray, lifted: np.ndarray) -> dict:
    """{"overall": mean, "per_camera": [mean per camera]} over the lifted views where the value is defined
    (NaN only where the measure does not apply: no other view, no label; failures are already `FAILED`)."""
    defined = lifted & np.isfinite(values)
    per_camera = [float(values[defined[:, c], c].mean()) if defined[:, c].any() else float("nan") for c in range(values.shape[1])]
    return {"overall": float(values[defined].mean()) if defined.any() else float("nan"), "per_camera": per_camera}
