"""The report of a run: single-view evaluation of the final checkpoint on every test view,
report.{json,md} with the reference rows and the ground-truth-free measures, and the plots."""

from __future__ import annotations

import json

import jax
import numpy as np

from jaxpose.training.experiment import ExperimentConfig, to_json_dict
from jaxpose.training.run_directory import RunDirectory, read_jsonl
from jaxpose.training.splits import Splits
from jaxpose.training.stream import Budget
from jaxpose import viz
from jaxpose.training import evaluation, self_consistency
from jaxpose.training.evaluator import Evaluator
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.losses import TERMS
from jaxpose.training.step import GRADIENT_SHARE_PREFIX, TrainState


def evaluate_and_report(
    config: ExperimentConfig,
    splits: Splits,
    budget: Budget,
    state: TrainState,
    model,
    run: RunDirectory,
    method_name: str,
    wall_time: float,
) -> dict:
    """Single-view evaluation on every test view (with test-time flip where `train.eval_flip`): the
    ground-truth-free measures (`jaxpose.training.self_consistency`) always; where the test split has 3D ground truth,
    the metrics against it with the reference rows; report.{json,md}, plots.  `budget`: what the run trained."""
    test = splits.test
    evaluator = Evaluator.of(config, test, model, flip=config.train.eval_flip)
    pred = evaluator.lift(state.variables)
    consistency = evaluator.ground_truth_free(pred)
    rows = evaluator.results(pred, method_name, splits)
    excluded = splits.detector_specific_joints
    joint_names = test.skeleton.joint_names
    if rows:
        joint_names = tuple(joint_names[j] for j in evaluator.truth.joints)
        motion_step = f"between test samples {evaluation.frame_step(*evaluator.motion_axes())} frames apart"
    history = read_jsonl(run.metrics)
    last_train = next((r for r in reversed(history) if "loss" in r), {})
    shares = {k.removeprefix(GRADIENT_SHARE_PREFIX): v for k, v in last_train.items() if k.startswith(GRADIENT_SHARE_PREFIX)}
    report = {
        "method": method_name,
        "results": rows,
        "ground_truth_free": consistency,
        "camera_names": list(splits.view_names()),
        "joint_names": list(joint_names),
        "detector_specific_joints": list(excluded),
        "notes": list(splits.notes),
        "final_gradient_shares": shares,
        "train_steps": int(state.step),
        "training_budget": {"steps": budget.total_steps, "steps_per_epoch": budget.steps_per_epoch, "capped": budget.capped},
        "samples_per_person": {part: samples_per_person(dataset) for part, dataset in (("train", splits.train), ("test", test))},
        "test_time_flip": config.train.eval_flip,
        "wall_time_s": wall_time,
        "devices": [str(d) for d in jax.devices()],
        "config": to_json_dict(config),
    }
    if jax.process_index() == 0:
        run.report_json.write_text(json.dumps(report, indent=2))
        tables = [*splits.notes, *([f"Training budget: trained {budget.note()}."] if budget.capped else [])]
        if report["samples_per_person"]["train"]:
            tables.append(samples_per_person_table(report["samples_per_person"]))
        if config.train.eval_flip:
            tables.append("Test-time flip (--train.eval-flip): every view's pose and its mirror image lifted and averaged.")
        if rows:
            tables += [
                evaluation.markdown_table(rows, "p_mpjpe", f"P-MPJPE (mm) per {splits.group_label}"),
                evaluation.markdown_table(rows, "mpjpe", f"MPJPE (mm) per {splits.group_label}"),
                evaluation.markdown_table(rows, "n_mpjpe", f"N-MPJPE (mm) per {splits.group_label}"),
                evaluation.markdown_table(rows, "mpjve", f"Velocity error MPJVE (mm per frame, {motion_step}) per {splits.group_label}"),
                evaluation.markdown_table(rows, "accel_error", f"Acceleration error (mm per frame², {motion_step}) per {splits.group_label}"),
                *([agreeing_joints_table(rows, excluded, splits.group_label)] if excluded else []),
                evaluation.per_joint_table(rows, "p_mpjpe", joint_names, "P-MPJPE (mm) per joint"),
                evaluation.per_joint_table(rows, "mpjpe", joint_names, "MPJPE (mm) per joint"),
            ]
        tables.append(ground_truth_free_table(consistency, splits.view_names()))
        if shares:
            tables.append(gradient_share_table(shares, int(state.step)))
        run.report_md.write_text("\n\n".join(tables) + "\n")
        reference = evaluator.truth.target if rows and len(joint_names) == test.skeleton.num_joints else evaluator.triangulation
        _plots(config, test, pred, reference, run)
    return report


def samples_per_person(dataset: MultiViewDataset) -> dict[str, int]:
    """{person: samples} of a data set whose samples are people of recordings (label "person", named by
    "sequence": `jaxpose.rig.split.person_names`); {} for other data sets."""
    labels = dataset.samples.labels
    if "person" not in labels:
        return {}
    names, counts = np.unique(np.asarray(labels["sequence"]).astype(str), return_counts=True)
    return {str(name): int(count) for name, count in zip(names, counts)}


def samples_per_person_table(counts: dict[str, dict[str, int]]) -> str:
    """Markdown: the training and test samples of each person (every person's instants are samples)."""
    people = sorted(set(counts["train"]) | set(counts["test"]))
    lines = ["**Samples per person** (each person's instants, with their own pseudo-labels)", "", "| person | train | test |", "|---|---|---|"]
    lines += [f"| {name} | {counts['train'].get(name, 0)} | {counts['test'].get(name, 0)} |" for name in people]
    lines.append(f"| all | {sum(counts['train'].values())} | {sum(counts['test'].values())} |")
    return "\n".join(lines)


def ground_truth_free_table(consistency: dict, camera_names: tuple[str, ...]) -> str:
    """Markdown: the `jaxpose.training.self_consistency` measures per lifted camera and overall."""
    lines = [
        "**Without ground truth (jaxpose.training.self_consistency): single-view predictions against the other views**",
        "",
        "| Lifted view | disagreement with the other views (mm) | reprojection into the other views (px) | P-MPJPE vs triangulation (mm) |",
        "|---|---|---|---|",
    ]
    for c, name in enumerate(camera_names):
        lines.append("| " + " | ".join([name, *(f"{consistency[m]['per_camera'][c]:.1f}" for m in self_consistency.METRICS)]) + " |")
    lines.append("| all | " + " | ".join(f"{consistency[m]['overall']:.1f}" for m in self_consistency.METRICS) + " |")
    lines += [
        "",
        "Lower is better for all three. How well each ranks runs as the true error would: docs/rig.md, section 5.",
    ]
    return "\n".join(lines)


def agreeing_joints_table(rows: dict, excluded: tuple[str, ...], group_label: str) -> str:
    """Markdown: P-MPJPE and MPJPE over the joints whose definitions agree (`detector_specific_joints` left out)."""
    lines = [
        f"**Without {', '.join(excluded)} (joints defined differently by the 2D source), averaged over {group_label}s**",
        "",
        "| Method | P-MPJPE (mm) | MPJPE (mm) |",
        "|---|---|---|",
    ]
    for method, summary in rows.items():
        average = summary["agreeing_joints"].get("group_average", summary["agreeing_joints"]["overall"])
        lines.append(f"| {method} | {average['p_mpjpe']:.1f} | {average['mpjpe']:.1f} |")
    return "\n".join(lines)


def gradient_share_table(shares: dict[str, float], step: int) -> str:
    """Markdown: each loss term's share of the gradient w.r.t. the lifter output at `step`."""
    lines = [
        f"**Share of each term in the gradient w.r.t. the lifter output (step {step})**",
        "",
        "| " + " | ".join(shares) + " |",
        "|" + "---|" * len(shares),
        "| " + " | ".join(f"{100 * v:.1f}%" for v in shares.values()) + " |",
    ]
    return "\n".join(lines)


# The periodic evaluation's measures and their plot labels.
EVALUATION_LABELS = {
    "p_mpjpe": "P-MPJPE (mm)",
    "mpjpe": "MPJPE (mm)",
    "disagreement_mm": "disagreement between views (mm)",
    "reprojection_px": "reprojection into other views (px)",
    "triangulation_p_mpjpe_mm": "P-MPJPE vs triangulation (mm)",
}


def _plots(config, test: MultiViewDataset, pred, target, run: RunDirectory) -> None:
    records = read_jsonl(run.metrics)
    history = [r for r in records if "loss" in r]
    evaluations = [r for r in records if any(key.startswith("eval_") for key in r)]
    if evaluations:
        labels = {f"eval_{name}": label for name, label in EVALUATION_LABELS.items()}
        curves = {
            label: [(r["step"], r[key]) for r in evaluations if key in r] for key, label in labels.items() if key in evaluations[-1]
        }
        figure = viz.figure_loss_curves(curves, log_y=False)
        figure.suptitle("periodic evaluation on a test subset (monitoring only; the report is the final checkpoint)")
        viz.save_figure(figure, run.plot("periodic_evaluation.png"))
    if history:
        keys = [k for k in ("loss", *TERMS, "supervised") if k in history[-1]]
        curves = {k: [(r["step"], r[k]) for r in history if k in r] for k in keys}
        viz.save_figure(viz.figure_loss_curves(curves), run.plot("loss_curves.png"))
        share_keys = [f"{GRADIENT_SHARE_PREFIX}{term}" for term in TERMS if f"{GRADIENT_SHARE_PREFIX}{term}" in history[-1]]
        if share_keys:
            shares = {k.removeprefix(GRADIENT_SHARE_PREFIX): [(r["step"], r[k]) for r in history if k in r] for k in share_keys}
            figure = viz.figure_loss_curves(shares, log_y=False, overlay=True)
            viz.save_figure(figure, run.plot("gradient_shares.png"))
    count = min(config.run.plot_samples, len(test))
    if count:
        picks = np.linspace(0, len(test) - 1, count).astype(int)
        figure = viz.figure_gt_vs_prediction(target[picks, 0], pred[picks, 0], test.skeleton)
        viz.save_figure(figure, run.plot("gt_vs_prediction.png"))
