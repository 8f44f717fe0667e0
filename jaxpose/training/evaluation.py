"""Evaluation of a lifter on a multi-view test set by single-view inference on every view.

Every (instant, view) pair of the test set is one single-view prediction, compared with the ground
truth in that view's camera frame, root-relative.  Results are grouped by a label (action, motion
family) and averaged over groups, as the paper's tables average over actions.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import world_to_camera
from jaxpose.chunks import map_in_chunks, map_over_parts
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.data.ground_truth import ground_truth_joints
from jaxpose.metrics import JOINT_METRICS, per_joint_metrics, pose_metrics
from jaxpose.skeleton import ROOT

METRIC_NAMES = ("mpjpe", "p_mpjpe", "n_mpjpe", "pck", "auc")
MOTION_METRICS = ("mpjve", "accel_error")  # `motion_errors`: NaN where a pose has no neighbours to difference


def poses_in_views(dataset: MultiViewDataset, poses_world: np.ndarray) -> np.ndarray:
    """World poses [N, J, 3] -> root-relative poses in every view's camera frame [N, C, J, 3]."""
    cameras = dataset.cameras_for(np.arange(len(dataset)))
    in_camera = np.asarray(jax.jit(world_to_camera)(cameras, jnp.asarray(poses_world)[:, None]))
    return in_camera - in_camera[..., :1, :]


def ground_truth_in_views(dataset: MultiViewDataset) -> tuple[np.ndarray, np.ndarray]:
    """What single-view evaluation compares with: the 3D ground truth root-relative in every view's
    camera frame [N, C, J, 3], and bool[N, C]: the views that can be lifted (their root was detected)
    and have ground truth (every joint of `ground_truth_joints`; other joints may be NaN)."""
    if dataset.samples.target3d is None:
        raise ValueError("the test split has no 3D ground truth to evaluate against")
    has_truth = np.isfinite(dataset.samples.target3d[:, ground_truth_joints(dataset)]).all((-2, -1))  # [N]
    target = np.where(has_truth[:, None, None], dataset.samples.target3d, 0.0)
    return poses_in_views(dataset, target), (dataset.samples.confidence[..., 0] > 0) & has_truth[:, None]


def lift_every_view(
    eval_step: Callable[..., jax.Array], variables, dataset: MultiViewDataset, batch_size: int = 16384, window: int = 1
) -> np.ndarray:
    """Single-view predictions for every view of every sample: [N, C, J, 3] mm.  With `window` > 1
    each view is lifted from its window of frames (`MultiViewDataset.windows`), gathered chunk by chunk.

    Chunks of exactly `batch_size` // C samples, the last padded (`jaxpose.chunks.map_over_parts`): the eval
    step compiles once, whatever the data set's size.
    """
    dataset = dataset.undistorted()
    N, C, J, _ = dataset.samples.keypoints2d.shape
    K = np.asarray(dataset.rigs.K)[dataset.samples.rig_index]  # [N, C, 3, 3]

    def lift(samples, K):
        if window > 1:
            keypoints, confidence = dataset.windows(samples, window)
        else:
            keypoints, confidence = dataset.samples.keypoints2d[samples], dataset.samples.confidence[samples]
        n = len(samples)
        flat = eval_step(variables, keypoints.reshape(n * C, *keypoints.shape[2:]), K.reshape(n * C, 3, 3),
                         confidence.reshape(n * C, *confidence.shape[2:]))  # fmt: skip
        return flat.reshape(n, C, J, 3)

    return next(map_over_parts(lift, [(np.arange(N), K)], max(1, batch_size // C)))


def compute_metrics(pred: np.ndarray, target: np.ndarray, chunk: int = 65536) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Metrics of [M, J, 3] poses in chunks of fixed size (one compile): per pose ({name: [M]},
    `METRIC_NAMES`) and per joint ({name: [M, J]}, `metrics.JOINT_METRICS`)."""
    per_pose, per_joint = map_in_chunks(lambda p, t: (pose_metrics(p, t), per_joint_metrics(p, t)), (pred, target), chunk)
    return {name: per_pose[name] for name in METRIC_NAMES}, {name: per_joint[name] for name in JOINT_METRICS}


def motion_errors(pred: np.ndarray, target: np.ndarray, sequences: np.ndarray, frames: np.ndarray, valid: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """How well single-view predictions move: {"mpjve": [N, C], "accel_error": [N, C]}, NaN where undefined.

    pred, target: [N, C, J, 3] mm (root-relative, camera frames); sequences [N]: which recording a sample
    belongs to; frames [N]: its frame number; valid bool[N, C].  Within a sequence the samples are taken in
    frame order at the sequence's step g (its most common frame gap: the evaluation stride).  The
    velocity error of a sample is the mean over joints of |(p' - p) - (t' - t)| / g to the next sample
    (mm per frame; VideoPose3D's MPJVE at g = 1); its acceleration error the mean over joints of
    |(p+ - 2p + p-) - (t+ - 2t + t-)| / g^2 around it (mm per frame^2), where the neighbours lie g frames
    away and every view-pose involved is valid.  A finite difference over g frames averages jitter out, so
    compare rows of one report (one stride), not reports at different strides.
    """
    N, C = pred.shape[:2]
    valid = np.ones((N, C), bool) if valid is None else np.asarray(valid, bool)
    order = np.lexsort((frames, sequences))
    seq, frame = np.asarray(sequences)[order], np.asarray(frames, np.int64)[order]
    repeated = np.flatnonzero((seq[1:] == seq[:-1]) & (frame[1:] == frame[:-1]))
    if repeated.size:  # e.g. two subjects' trials of one name: differencing across them would be garbage
        raise ValueError(
            f"motion_errors: sequence {str(seq[repeated[0]])!r} has frame {int(frame[repeated[0]])} more than once;"
            " name sequences uniquely (e.g. with the subject)"
        )
    p, t, ok = pred[order].astype(np.float64), target[order].astype(np.float64), valid[order]
    step = _sequence_steps(seq, frame)
    same = seq[1:] == seq[:-1]
    gaps = frame[1:] - frame[:-1]
    # next[k]: sample k + 1 is the same sequence's next sample, one step on
    has_next = np.zeros(N, bool)
    has_next[:-1] = same & (gaps == step[:-1]) & (step[:-1] > 0)
    g = np.maximum(step, 1).astype(np.float64)[:, None]
    velocity = np.full((N, C), np.nan)
    pair = has_next[:-1, None] & ok[:-1] & ok[1:]
    difference = (p[1:] - p[:-1]) - (t[1:] - t[:-1])
    velocity[:-1] = np.where(pair, np.linalg.norm(difference, axis=-1).mean(-1) / g[:-1], np.nan)
    acceleration = np.full((N, C), np.nan)
    if N >= 3:
        triple = has_next[:-2, None] & has_next[1:-1, None] & ok[:-2] & ok[1:-1] & ok[2:]
        second = (p[2:] - 2 * p[1:-1] + p[:-2]) - (t[2:] - 2 * t[1:-1] + t[:-2])
        acceleration[1:-1] = np.where(triple, np.linalg.norm(second, axis=-1).mean(-1) / g[1:-1] ** 2, np.nan)
    inverse = np.empty(N, np.int64)
    inverse[order] = np.arange(N)
    return {"mpjve": velocity[inverse].astype(np.float32), "accel_error": acceleration[inverse].astype(np.float32)}


def _sequence_steps(sequences: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Per sample (sorted by sequence, then frame) its sequence's most common frame gap; 0 for a sequence
    of one frame."""
    step = np.zeros(len(frames), np.int64)
    for name in np.unique(sequences):
        gaps = np.diff(frames[sequences == name])
        gaps = gaps[gaps > 0]
        step[sequences == name] = np.bincount(gaps).argmax() if gaps.size else 0
    return step


def frame_step(sequences: np.ndarray, frames: np.ndarray) -> int:
    """The most common frame gap between consecutive samples of a sequence (the evaluation stride)."""
    order = np.lexsort((frames, sequences))
    steps = _sequence_steps(np.asarray(sequences)[order], np.asarray(frames, np.int64)[order])
    steps = steps[steps > 0]
    return int(np.bincount(steps).argmax()) if steps.size else 0


def _finite_mean(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(finite.mean()) if finite.size else float("nan")


def summarize(
    per_pose: Mapping[str, np.ndarray],
    groups: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    per_joint: Mapping[str, np.ndarray] | None = None,
) -> dict:
    """{"overall": {metric: mean}, "groups": {group: {metric: mean}}, "group_average": {metric: mean},
    "per_joint": {metric: [mean of each joint]}}.

    `overall` averages over all poses; `group_average` averages the per-group means (the paper's
    "Avg." column); `per_joint` (when `per_joint` [M, J] arrays are given) averages each joint over
    all valid poses.  Metrics in mm except pck/auc (percent).
    """
    count = len(next(iter(per_pose.values())))
    valid = np.ones(count, bool) if valid is None else valid

    def mean(mask):
        # The motion metrics are NaN where a pose has no neighbours: their mean is over the poses that have.
        return {
            name: (_finite_mean(values[mask]) if name in MOTION_METRICS else float(values[mask].mean()))
            * (100.0 if name in ("pck", "auc") else 1.0)
            for name, values in per_pose.items()
        } | {"count": int(mask.sum())}

    summary = {"overall": mean(valid)}
    if groups is not None:
        names = sorted(set(groups[valid].tolist()))
        summary["groups"] = {str(name): mean(valid & (groups == name)) for name in names}
        average = {metric: _finite_mean if metric in MOTION_METRICS else np.mean for metric in per_pose}
        summary["group_average"] = {
            metric: float(average[metric](np.array([summary["groups"][str(n)][metric] for n in names]))) for metric in per_pose
        }
    if per_joint is not None:
        summary["per_joint"] = {name: values[valid].mean(0).tolist() for name, values in per_joint.items()}
    return summary


def evaluate_poses(
    pred: np.ndarray,
    target: np.ndarray,
    groups: np.ndarray | None = None,
    view_valid: np.ndarray | None = None,
    agreeing_joints: np.ndarray | None = None,
    sequences: np.ndarray | None = None,
    frames: np.ndarray | None = None,
) -> dict:
    """Evaluate [N, C, J, 3] predictions against [N, C, J, 3] targets; groups: per-sample labels [N].

    With `agreeing_joints` (indices), the summary also holds "agreeing_joints": the "overall" and
    "group_average" metrics of those joints alone, Procrustes-aligned on them (for a 2D source that
    defines the other joints differently from the ground truth).  With `sequences` and `frames` (per
    sample [N]), the motion metrics `MOTION_METRICS` too (`motion_errors`).
    """
    N, C = pred.shape[:2]
    per_pose, per_joint = compute_metrics(pred.reshape(N * C, *pred.shape[2:]), target.reshape(N * C, *target.shape[2:]))
    if sequences is not None and frames is not None:
        motion = motion_errors(pred, target, sequences, frames, view_valid)
        per_pose = per_pose | {name: values.reshape(N * C) for name, values in motion.items()}
    expanded_groups = None if groups is None else np.repeat(np.asarray(groups), C)
    valid = None if view_valid is None else view_valid.reshape(N * C)
    summary = summarize(per_pose, expanded_groups, valid, per_joint)
    if agreeing_joints is not None:
        subset = evaluate_poses(pred[..., agreeing_joints, :], target[..., agreeing_joints, :], groups, view_valid)
        summary["agreeing_joints"] = {k: subset[k] for k in ("overall", "group_average") if k in subset}
    return summary


def mean_pose_prediction(train: MultiViewDataset, chunk_size: int = 65536) -> np.ndarray:
    """The mean-pose baseline: the average training pseudo-label in camera frames [J, 3], over the
    samples whose root has one (without it the label is meaningless).  Summed `chunk_size` samples at
    a time: a large (memory-mapped) training set is never held in every view at once."""
    if train.samples.pseudo3d is None:
        raise ValueError("mean_pose_prediction needs the training pseudo-labels")
    labelled = np.flatnonzero(train.samples.pseudo3d_weight[:, ROOT] > 0)
    total = np.zeros((train.skeleton.num_joints, 3))
    for start in range(0, len(labelled), chunk_size):
        part = train.subset(labelled[start : start + chunk_size])
        total += poses_in_views(part, part.samples.pseudo3d).sum((0, 1), dtype=np.float64)
    return (total / (len(labelled) * train.num_views)).astype(np.float32)


def per_joint_table(rows: Mapping[str, Mapping], metric: str, joint_names: tuple[str, ...], title: str | None = None) -> str:
    """A table of the per-joint `metric` (mm): one row per method, one column per joint, then "All"."""
    lines = [] if title is None else [f"**{title}**", ""]
    lines += ["| " + " | ".join(["Method", *joint_names, "All"]) + " |", "|" + "---|" * (len(joint_names) + 2)]
    for method, summary in rows.items():
        values = summary["per_joint"][metric]
        cells = [f"{v:.1f}" for v in values] + [f"{np.mean(values):.1f}"]
        lines.append("| " + " | ".join([method, *cells]) + " |")
    return "\n".join(lines)


def markdown_table(rows: Mapping[str, Mapping], metric: str, title: str | None = None, digits: int = 1) -> str:
    """A table of `metric` with one row per method and one column per group plus "Avg." and "All".

    `rows` maps a method name to a `summarize` result.
    """
    groups = sorted({g for summary in rows.values() for g in summary.get("groups", {})})
    header = ["Method", *groups, "Avg.", "All"]
    lines = [] if title is None else [f"**{title}**", ""]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for method, summary in rows.items():
        def cell(value):
            return "-" if not np.isfinite(value) else f"{value:.{digits}f}"

        cells = [cell(summary["groups"][g][metric]) if g in summary.get("groups", {}) else "-" for g in groups]
        cells += [cell(summary.get("group_average", summary["overall"])[metric]), cell(summary["overall"][metric])]
        lines.append("| " + " | ".join([method, *cells]) + " |")
    return "\n".join(lines)
