"""Ground truth matched to a skeleton's joints, for evaluation: which joints a data set's 3D ground
truth gives, and a ground truth of its own joint names brought onto a skeleton by name.

A data set's ground truth may cover only some joints of its skeleton: a rig project's motion capture
shares only some names with the detector's keypoints, and is NaN elsewhere.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from jaxpose.data.dataset import MultiViewDataset
from jaxpose.formats.errors import DataFormatError
from jaxpose.skeleton import ROOT, Skeleton


def ground_truth_joints(dataset: MultiViewDataset) -> np.ndarray:
    """Indices of the joints the 3D ground truth gives: every joint, unless it covers fewer (a rig
    project's ground truth shares only some joint names with the detector's skeleton; NaN elsewhere).
    A joint counts where it is known in most instants that have ground truth; the root always counts
    (evaluation is root-relative), and an instant lacking any counted joint has no ground truth."""
    finite = np.isfinite(dataset.samples.target3d).all(-1)  # [N, J]
    rows = finite.any(-1)
    if not rows.any():
        return np.arange(dataset.skeleton.num_joints)
    counted = finite[rows].mean(0) >= 0.5
    counted[ROOT] = True
    return np.flatnonzero(counted)


def ground_truth_joint_names(dataset: MultiViewDataset) -> tuple[str, ...]:
    """The names of `ground_truth_joints`; empty where the data set has no ground truth at all."""
    if dataset.samples.target3d is None or not len(dataset) or not np.isfinite(dataset.samples.target3d).any():
        return ()
    return tuple(dataset.skeleton.joint_names[j] for j in ground_truth_joints(dataset))


def on_skeleton(
    points: np.ndarray, joint_names: Sequence[str], skeleton: Skeleton, root_from: tuple[str, str] | None, where: str
) -> np.ndarray:
    """Ground truth points [N, J', 3] of the joints `joint_names` -> [N, J, 3] on `skeleton`'s joints,
    matched by name, NaN for the joints it lacks.

    The root is the midpoint of the two joints `root_from` where the ground truth has both (a
    detector's root is the hips' midpoint by definition; a motion capture's "pelvis" may lie
    elsewhere), else the ground truth's joint of the root's name; without either, evaluation (which
    is root-relative) is impossible and a `DataFormatError` names `where`.
    """
    columns = {name: points[:, i] for i, name in enumerate(joint_names)}
    root = skeleton.joint_names[0]
    if root_from is not None and all(name in columns for name in root_from):
        columns[root] = 0.5 * (columns[root_from[0]] + columns[root_from[1]])
    if root not in columns:
        hips = f" or both of {list(root_from)}" if root_from is not None else ""
        raise DataFormatError(where, f"the root joint {root!r}{hips} (evaluation is root-relative)", f"joints {list(joint_names)}")
    matched = np.full((len(points), skeleton.num_joints, 3), np.nan, points.dtype)
    for j, name in enumerate(skeleton.joint_names):
        if name in columns:
            matched[:, j] = columns[name]
    return matched
