"""One evaluator for the periodic evaluation during training and the final one of the report.

The held-out samples are pseudo-labelled once (their views' triangulation: the reference of the
ground-truth-free measures, `jaxpose.training.self_consistency`), and their ground truth, where they have
one, turned into each view's camera frame once; any variables are then lifted on every view and scored
the same way.  The periodic evaluation runs it on `--train.eval-samples` evenly spaced samples, the
report on all of them, with the reference rows beside the lifter (`results`); the report only formats.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable

import numpy as np

from jaxpose.data import ground_truth
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.flip import flip_averaged
from jaxpose.model import make_eval_step
from jaxpose.training import evaluation, pseudo_labelling, self_consistency
from jaxpose.training.experiment import ExperimentConfig
from jaxpose.training.splits import Splits

TRIANGULATION_ROW = "Input triangulation (multi-view, reference)"
MEAN_POSE_ROW = "Mean pose (baseline)"


@dataclasses.dataclass(frozen=True)
class Truth:
    """The ground truth of the samples in each view's camera frame, over the joints it has."""

    joints: np.ndarray
    """int[J'] the lifting skeleton's joints the ground truth has."""
    target: np.ndarray
    """f32[N, C, J', 3] mm, root-relative in each view's camera frame."""
    valid: np.ndarray
    """bool[N, C] the views it is defined in."""


@dataclasses.dataclass(frozen=True)
class Evaluator:
    """Held-out samples, pseudo-labelled, and how the lifter is run on them (see the module docstring)."""

    held_out: MultiViewDataset
    eval_step: Callable
    batch_size: int
    window: int
    truth: Truth | None

    @classmethod
    def of(cls, config: ExperimentConfig, held_out: MultiViewDataset, model, flip: bool = False) -> Evaluator:
        """The evaluator of `held_out` for `model` as `config` lifts it (with test-time flip where `flip`)."""
        labelled = pseudo_labelling.label(held_out, config.pseudo_labels)
        truth = None
        if labelled.samples.target3d is not None:
            joints = np.asarray(ground_truth.ground_truth_joints(labelled))
            target, valid = evaluation.ground_truth_in_views(labelled)
            truth = Truth(joints, target[..., joints, :], valid)
        eval_step = make_eval_step(model, config.model)
        if flip:
            eval_step = flip_averaged(eval_step, held_out.skeleton)
        return cls(labelled, eval_step, config.train.eval_batch_size, config.model.temporal_window, truth)

    def lift(self, variables) -> np.ndarray:
        """f32[N, C, J, 3]: every view's lifted pose, root-relative mm in its camera frame."""
        return evaluation.lift_every_view(self.eval_step, variables, self.held_out, self.batch_size, self.window)

    def ground_truth_free(self, pred: np.ndarray) -> dict:
        """The ground-truth-free measures of `pred` (`jaxpose.training.self_consistency`)."""
        held_out = self.held_out
        return self_consistency.self_consistency(pred, held_out, held_out.samples.pseudo3d, held_out.samples.pseudo3d_weight > 0)

    def overall(self, variables) -> dict:
        """The periodic record: eval_p_mpjpe / eval_mpjpe (mm) where there is ground truth, and the
        ground-truth-free measures overall (eval_disagreement_mm, eval_reprojection_px, ...)."""
        pred = self.lift(variables)
        record = {}
        if self.truth is not None:
            overall = evaluation.evaluate_poses(pred[..., self.truth.joints, :], self.truth.target, None, self.truth.valid)["overall"]
            record = {"eval_p_mpjpe": overall["p_mpjpe"], "eval_mpjpe": overall["mpjpe"]}
        return record | {f"eval_{name}": values["overall"] for name, values in self.ground_truth_free(pred).items()}

    @functools.cached_property
    def triangulation(self) -> np.ndarray:
        """f32[N, C, J, 3]: the samples' pseudo-labels (their views' triangulation) in each view, made once
        (the reference row and the report's figure both read it)."""
        return evaluation.poses_in_views(self.held_out, self.held_out.samples.pseudo3d)

    def results(self, pred: np.ndarray, method: str, splits: Splits) -> dict:
        """Per row (the lifter as `method`, the input triangulation, the mean pose of the training split), the
        metrics against the ground truth per group, per joint and overall (`evaluation.evaluate_poses`);
        {} without ground truth."""
        if self.truth is None:
            return {}
        samples, truth = self.held_out.samples, self.truth
        mean_pose = np.broadcast_to(evaluation.mean_pose_prediction(splits.train), pred.shape)
        # Each row with the views it is evaluated on: the triangulation is a reference only where its
        # root has a label (two agreeing views); elsewhere it is no estimate at all.
        predictions = {
            method: (pred, truth.valid),
            TRIANGULATION_ROW: (self.triangulation, truth.valid & (samples.pseudo3d_weight[:, None, 0] > 0)),
            MEAN_POSE_ROW: (np.ascontiguousarray(mean_pose), truth.valid),
        }
        groups = samples.labels.get(splits.group_label)
        agreeing = splits.agreeing_joints()
        sequences, frames = self.motion_axes()
        return {
            name: evaluation.evaluate_poses(poses[..., truth.joints, :], truth.target, groups, views, agreeing, sequences, frames)
            for name, (poses, views) in predictions.items()
        }

    def motion_axes(self) -> tuple[np.ndarray, np.ndarray]:
        """(sequence, frame) of every sample, which the motion metrics follow: every loader labels each sample
        with its subject, sequence and frame number (a sequence name such as "Walking 1" recurs across subjects)."""
        labels = self.held_out.samples.labels
        return np.char.add(np.char.add(labels["subject"].astype(str), "/"), labels["sequence"].astype(str)), labels["frame"]
