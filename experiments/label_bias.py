"""Where the self-supervised lifter's gap to its supervised twin comes from on real detections: the
detector's joint definitions, or its frame-to-frame errors.

    python -m experiments.label_bias --data.data-dir DIR        # Human3.6M development split, ~15 min on 2 cores

An oracle study, not a method: it reads the 3D ground truth of the training half, which no
self-supervised row may, to measure what the pseudo-labels cost.

The error of each training pseudo-label (root-relative) is expressed in the body frame of the
motion-capture pose (x from the right to the left hip, z up the trunk towards the thorax, y = z x x).
Its mean per joint over the training half is the detector's *definition bias*: where the detector
puts a joint on the body against where the motion capture does (Stacked Hourglass was trained on
MPII: its "Spine" is MPII's thorax).  What is left varies from frame to frame.  The first table
gives each joint's bias and the pseudo-labels' P-MPJPE with and without it, on the training half
and, with the training half's bias, on the test half (on the development split these are other
trials of the same subject).

Then the lifter is trained as the chosen preset on three kinds of label, each with all four losses
and with L_in alone: the pseudo-labels; the definition bias only (ground truth + bias: the labels
without their frame-to-frame error); the pseudo-labels with the bias removed.  Then the first of
these lifters (pseudo-labels, all four losses) once more, its output mapped from the detector's
joint definitions to the ground truth's by a fixed offset per joint in the body frame of each
prediction (`definition_map`, the mean correction of the training labels in their own body frames).  And the
supervised twin.  Each row trains in its own sub-directory of --run.run-dir (default runs/label_bias_h36m_<preset>),
so an interrupted study resumes; the report is <run_dir>/label_bias.md.
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib
import sys

import numpy as np

from experiments import ablation, cli, h36m
from jaxpose.training.experiment import ExperimentConfig
from jaxpose.training.run_directory import check_study_folder, write_study_file
from jaxpose.training.runner import run
from jaxpose.training.splits import Splits
from jaxpose.training import evaluation, pseudo_labelling
from jaxpose.serving import inference
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.losses import TERMS
from jaxpose.skeleton import Skeleton

PROG = "python -m experiments.label_bias"
LABEL_KINDS = ("pseudo-labels", "definition bias only", "bias removed")
TERM_SETS = (("all four losses", TERMS), ("L_in", ("input_triangulation",)))


def body_frames(poses: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """f64[N, 3, 3]: per pose, the body axes (columns x, y, z) in the poses' own frame.

    x runs from the right to the left hip, z up the trunk (root to thorax, made orthogonal to x),
    y = z x x points backwards: a right-handed frame that turns and moves with the body.
    """
    joint = skeleton.index
    poses = np.asarray(poses, np.float64)
    x = poses[:, joint("LHip")] - poses[:, joint("RHip")]
    x /= np.linalg.norm(x, axis=-1, keepdims=True)
    up = poses[:, joint("Thorax")] - poses[:, joint("Hip")]
    z = up - np.sum(up * x, -1, keepdims=True) * x
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def _mean_in_body(vectors: np.ndarray, frames: np.ndarray, taught: np.ndarray) -> np.ndarray:
    """f64[J, 3]: the mean over the taught ([N, J] mask) of `vectors` [N, J, 3] in the body `frames` [N, 3, 3]."""
    in_body = np.einsum("nij,nki->nkj", frames, vectors)  # frames^T @ vector
    weight = np.asarray(taught, np.float64)[..., None]
    return (in_body * weight).sum(0) / np.maximum(weight.sum(0), 1.0)


def _root_relative_error(labels: np.ndarray, truth: np.ndarray) -> np.ndarray:
    labels, truth = np.asarray(labels, np.float64), np.asarray(truth, np.float64)
    return (labels - labels[:, :1]) - (truth - truth[:, :1])


def definition_bias(labels: np.ndarray, truth: np.ndarray, taught: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """f64[J, 3]: the mean root-relative error of the taught labels ([N, J] mask) per joint, in the
    body frame of the ground truth (mm; zero at the root)."""
    return _mean_in_body(_root_relative_error(labels, truth), body_frames(truth, skeleton), taught)


def definition_map(labels: np.ndarray, truth: np.ndarray, taught: np.ndarray, skeleton: Skeleton) -> np.ndarray:
    """f64[J, 3]: the offset, in the body frame of a pose *with the labels' joint definitions*, that
    moves it onto the ground truth's joints (`moved_in_body(pose, body_frames(pose), offset)`): the
    mean root-relative correction of the taught labels in their own body frames.  Exact where the
    two definitions differ by a body-fixed offset, whichever skeleton the frame is built from."""
    return _mean_in_body(-_root_relative_error(labels, truth), body_frames(labels, skeleton), taught)


def moved_in_body(poses: np.ndarray, frames: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """`poses` [N, J, 3] with `offset` [J, 3] (body-frame mm) added through each pose's `frames` [N, 3, 3]."""
    return np.asarray(poses, np.float64) + np.einsum("nij,kj->nki", frames, offset)


def relabelled(kind: str, train: MultiViewDataset) -> MultiViewDataset:
    """The labelled training set with the pseudo-labels of `kind` (one of `LABEL_KINDS`)."""
    if kind == "pseudo-labels":
        return train
    if train.samples.target3d is None:
        raise ValueError("the label-bias study needs the training half's 3D ground truth (a reference calibration)")
    bias = training_bias(train)
    frames = body_frames(train.samples.target3d, train.skeleton)
    if kind == "definition bias only":
        labels = moved_in_body(train.samples.target3d, frames, bias)
    elif kind == "bias removed":
        labels = moved_in_body(train.samples.pseudo3d, frames, -bias)
    else:
        raise ValueError(f"unknown label kind {kind!r}; expected one of {LABEL_KINDS}")
    return train.with_samples(pseudo3d=labels.astype(np.float32))


def label_errors(dataset: MultiViewDataset, labels: np.ndarray, group_label: str, joints: np.ndarray | None = None) -> float:
    """P-MPJPE (mm) of [N, J, 3] `labels` against `dataset`'s ground truth over `joints` (default all),
    averaged over the groups of `group_label`, as the reports average their rows."""
    joints = np.arange(labels.shape[1]) if joints is None else joints
    per_pose, _ = evaluation.compute_metrics(labels[:, joints].astype(np.float32), dataset.samples.target3d[:, joints].astype(np.float32))
    return evaluation.summarize(per_pose, dataset.samples.labels.get(group_label))["group_average"]["p_mpjpe"]


def training_bias(train: MultiViewDataset) -> np.ndarray:
    """f64[J, 3]: the definition bias of a labelled training set's taught pseudo-labels."""
    return definition_bias(train.samples.pseudo3d, train.samples.target3d, train.samples.pseudo3d_weight > 0, train.skeleton)


def label_table(train: MultiViewDataset, test: MultiViewDataset, splits: Splits, bias: np.ndarray) -> str:
    """Markdown: the definition `bias` per joint, and the pseudo-labels' P-MPJPE (of the labelled
    `train` and `test` halves) with and without it."""
    names = train.skeleton.joint_names
    lines = [
        "**Definition bias per joint (body frame, mm; estimated on the training half)**",
        "",
        "| " + " | ".join(["", *names]) + " |",
        "|" + "---|" * (len(names) + 1),
        "| length | " + " | ".join(f"{v:.0f}" for v in np.linalg.norm(bias, axis=-1)) + " |",
    ]
    for axis, label in enumerate(("x (to the left hip)", "y (backwards)", "z (up the trunk)")):
        lines.append(f"| {label} | " + " | ".join(f"{v:+.0f}" for v in bias[:, axis]) + " |")
    agreeing = splits.agreeing_joints()
    header = ["Half", "Pseudo-labels", "Bias removed"]
    if agreeing is not None:
        excluded = ", ".join(splits.detector_specific_joints)
        header += [f"Pseudo-labels, without {excluded}", f"Bias removed, without {excluded}"]
    lines += [
        "",
        f"**Pseudo-labels against the ground truth, P-MPJPE (mm, average over {splits.group_label}s); the training half's bias removed from both halves**",
        "",
        "| " + " | ".join(header) + " |",
        "|" + "---|" * len(header),
    ]
    for half, dataset in (("training", train), ("test", test)):
        removed = moved_in_body(dataset.samples.pseudo3d, body_frames(dataset.samples.target3d, dataset.skeleton), -bias)
        cells = [label_errors(dataset, labels, splits.group_label) for labels in (dataset.samples.pseudo3d, removed)]
        if agreeing is not None:
            cells += [label_errors(dataset, labels, splits.group_label, agreeing) for labels in (dataset.samples.pseudo3d, removed)]
        lines.append(f"| {half} | " + " | ".join(f"{v:.1f}" for v in cells) + " |")
    return "\n".join(lines)


def mapped_output_report(config: ExperimentConfig, splits: Splits, offset: np.ndarray, label: str) -> dict:
    """The lifter of `config`'s run evaluated with each output joint moved by `offset` (a
    `definition_map`) in the body frame of the prediction itself: the detector's joint definitions
    mapped to the ground truth's after training.  A report shaped like the runner's, for
    `ablation.comparison_table`."""
    test = splits.test
    target, valid = evaluation.ground_truth_in_views(test)
    lifter = inference.load(config.run.run_dir)
    pred = evaluation.lift_every_view(
        lifter.eval_step, lifter.variables, test, config.train.eval_batch_size, lifter.model_config.temporal_window
    )
    flat = pred.reshape(-1, *pred.shape[2:])
    mapped = moved_in_body(flat, body_frames(flat, test.skeleton), offset).reshape(pred.shape).astype(np.float32)
    summary = evaluation.evaluate_poses(mapped, target, test.samples.labels.get(splits.group_label), valid, splits.agreeing_joints())
    return {"method": label, "results": {label: summary}}


def row_configs(base: ExperimentConfig) -> list[tuple[str, str, ExperimentConfig]]:
    """(row label, label kind, config) for every kind of label and set of terms, each in its own directory."""
    rows = []
    for kind in LABEL_KINDS:
        for terms_label, terms in TERM_SETS:
            loss = dataclasses.replace(base.loss, **{term: (getattr(base.loss, term) if term in terms else 0.0) for term in TERMS})
            directory = f"{kind.replace(' ', '_')}__{terms_label.replace(' ', '_')}"
            run_config = dataclasses.replace(base, loss=loss, run=dataclasses.replace(base.run, run_dir=base.run.run_dir / directory))
            rows.append((f"{kind}, {terms_label}", kind, run_config))
    return rows


def main(argv: list[str] | None = None) -> str:
    # "dev" first: the first preset is the default.
    presets = {
        name: dataclasses.replace(preset, run=dataclasses.replace(preset.run, run_dir=pathlib.Path(f"runs/label_bias_h36m_{name}")))
        for name, preset in {"dev": h36m.DEV, **h36m.PRESETS}.items()
    }
    base = cli.parse(h36m.EXPERIMENT, sys.argv[1:] if argv is None else argv, __doc__, PROG, presets)
    if base.loss.supervision != "self":
        raise SystemExit("error: the label-bias study trains self-supervised rows (and adds the supervised twin itself): leave --supervision self")
    check_study_folder(base.run.run_dir)  # its rows train in sub-folders; the study's report is written into it
    load_splits = h36m.EXPERIMENT.loader()
    splits = load_splits(base.data)
    if splits.train.samples.target3d is None:
        raise SystemExit("error: the label-bias study needs the training half's 3D ground truth: leave --data.cameras-path unset")
    train = pseudo_labelling.label(splits.train, base.pseudo_labels)
    test = pseudo_labelling.label(splits.test, base.pseudo_labels)
    labels = label_table(train, test, splits, training_bias(train))
    print(labels, flush=True)
    results: list[tuple[str, dict]] = []
    for label, kind, config in row_configs(base):
        results.append((label, run(config, load_splits, replace_labels=functools.partial(relabelled, kind))))
    # The first row's lifter, unchanged, its output mapped to the ground truth's joint definitions.
    first_label, _, first_config = row_configs(base)[0]
    offset = definition_map(train.samples.pseudo3d, train.samples.target3d, train.samples.pseudo3d_weight > 0, train.skeleton)
    mapped_label = f"{first_label}, output mapped to the mocap's joints"
    results.append((mapped_label, mapped_output_report(first_config, splits, offset, mapped_label)))
    results.append((ablation.SUPERVISED_LABEL, run(ablation.supervised_twin(base), load_splits)))
    joint_names = tuple(results[0][1]["joint_names"])
    text = "\n\n".join(
        [
            labels,
            "**Lifters trained on each kind of label (test half)**",
            ablation.comparison_table(results),
            evaluation.per_joint_table(ablation.per_joint_rows(results), "p_mpjpe", joint_names, "P-MPJPE (mm) per joint"),
        ]
    )
    write_study_file(base.run.run_dir, "label_bias.md", text + "\n")
    print(text)
    return text


if __name__ == "__main__":
    main()
