"""Train, checkpoint, resume, evaluate and report: the loop every experiment entry point shares.

A run directory holds:
  config.json      the resolved config (what a resume checks it continues)
  metrics.jsonl    one line per `train.log_every` steps (appended across resumes)
  checkpoints/     Orbax CheckpointManager steps (the newest `train.keep_checkpoints`); each holds the
                   train state and, for `jaxpose.inference`, the variables and the network's record
  report.json/.md  the evaluation on the test split, with the reference rows
  plots/           loss curves and GT-vs-prediction skeletons (PNG)
Ctrl-C or SIGTERM saves a checkpoint before exit; starting again on the same directory resumes.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import pathlib
import shutil
import signal
import sys
import time
from collections.abc import Callable, Mapping
from typing import Any

import jax
import numpy as np
from tqdm.auto import tqdm

from experiments.config import ExperimentConfig, dumps, to_json_dict
from jaxpose import checkpoint, evaluation, parallel, pseudo_labelling, validation, viz
from jaxpose.data.batch import validate_batch
from jaxpose.data.dataset import MultiViewDataset, steps_per_epoch
from jaxpose.losses import TERMS
from jaxpose.train import (
    GRADIENT_SHARE_PREFIX,
    TrainState,
    init_train_state,
    jit_train_step,
    make_eval_step,
    make_train_step,
)

log = logging.getLogger("jaxpose")


@dataclasses.dataclass(frozen=True)
class Splits:
    """What an entry point's data loader returns."""

    train: MultiViewDataset
    test: MultiViewDataset
    group_label: str
    """The label that groups test results (e.g. "action", "motion")."""
    detector_specific_joints: tuple[str, ...] = ()
    """Joints that the 2D source defines differently from the 3D ground truth (e.g. Stacked
    Hourglass's MPII "Spine" and "Head" on Human3.6M).  The report adds every metric over the other
    joints (Procrustes-aligned on those joints alone), where the definitions agree."""
    camera_names: tuple[str, ...] = ()
    """The views' names, for the per-camera tables (default: view 0, 1, ...)."""
    notes: tuple[str, ...] = ()
    """Paragraphs for the top of the report: what the loader did to the data (e.g. a rig project's
    calibration, frame offsets and person choices)."""
    artifacts: Mapping[str, Callable[[pathlib.Path], None]] = dataclasses.field(default_factory=dict)
    """Files the loader made for the run directory: file name -> a function writing it to a path
    (e.g. the rig `jaxpose.calibrate` recovered)."""

    def view_names(self) -> tuple[str, ...]:
        return self.camera_names or tuple(f"view {c}" for c in range(self.test.num_views))

    def agreeing_joints(self) -> np.ndarray | None:
        """Indices of the joints not in `detector_specific_joints`; None when every joint agrees."""
        if not self.detector_specific_joints:
            return None
        names = self.test.skeleton.joint_names
        return np.array([i for i, name in enumerate(names) if name not in self.detector_specific_joints], dtype=int)


class Interrupted(Exception):
    """Raised inside the loop when SIGINT/SIGTERM arrived; the checkpoint is already saved."""


# Fields that must match for a run directory to be resumed (the rest may change between attempts).
_RESUME_KEYS = ("data", "model", "loss", "optimizer", "pseudo_labels")
_RESUME_TRAIN_KEYS = ("batch_size", "epochs", "seed")


def _identity(config_json: dict) -> dict:
    identity = {key: config_json.get(key) for key in _RESUME_KEYS}
    identity["train"] = {key: config_json.get("train", {}).get(key) for key in _RESUME_TRAIN_KEYS}
    return identity


def check_resumable(config: ExperimentConfig) -> None:
    """Fail early (before any data are loaded) if run_dir holds a run of a different config."""
    config_path = config.run.run_dir / "config.json"
    if config.run.overwrite or not config_path.exists():
        return
    if _identity(json.loads(config_path.read_text())) != _identity(to_json_dict(config)):
        raise SystemExit(
            f"{config.run.run_dir} holds a run with a different config ({config_path}); resume it with the same"
            " settings, pick another --run.run-dir, or pass --run.overwrite to start over."
        )


def prepare_run_dir(config: ExperimentConfig) -> pathlib.Path:
    """Create (or check, for a resume) the run directory and write config.json."""
    check_resumable(config)
    run_dir = config.run.run_dir
    if config.run.overwrite and run_dir.exists() and jax.process_index() == 0:
        shutil.rmtree(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "plots").mkdir(exist_ok=True)
    if jax.process_index() == 0:
        (run_dir / "config.json").write_text(dumps(config))
    return run_dir


class _SignalFlag:
    """Turns SIGINT/SIGTERM into a flag the loop polls, so the checkpoint is written between steps."""

    def __init__(self):
        self.received: int | None = None
        self._previous = {}

    def __enter__(self):
        for sig in (signal.SIGINT, signal.SIGTERM):
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, _frame):
        if self.received is not None:  # a second Ctrl-C: stop at once
            raise KeyboardInterrupt
        self.received = signum
        log.warning("signal %d received: saving a checkpoint before exit", signum)

    def __exit__(self, *exc):
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _append_jsonl(path: pathlib.Path, record: dict) -> None:
    if jax.process_index() == 0:
        with path.open("a") as f:
            f.write(json.dumps(record) + "\n")


def _truncate_log(path: pathlib.Path, step: int) -> None:
    """Drop log lines past `step`: a resumed run replays those steps and logs them again."""
    if jax.process_index() != 0 or not path.exists():
        return
    kept = [record for record in _read_jsonl(path) if record["step"] <= step]
    path.write_text("".join(json.dumps(record) + "\n" for record in kept))


class RunLog:
    """The run's metric lines: appended to metrics.jsonl and, where tensorboardX is installed, written
    as TensorBoard scalars (`<group>/<name>`) to <run_dir>/tensorboard.  Process 0 writes."""

    def __init__(self, run_dir: pathlib.Path, start_step: int, tensorboard: bool):
        self.path = run_dir / "metrics.jsonl"
        _truncate_log(self.path, start_step)
        self.writer = None
        if not tensorboard or jax.process_index() != 0:
            return
        try:
            from tensorboardX import SummaryWriter
        except ImportError:
            log.warning("no TensorBoard events: tensorboardX is not installed (pip install 'jaxpose[monitor]')")
            return
        # purge_step: a resumed run replays the steps after its checkpoint; TensorBoard drops their
        # first logging, as `_truncate_log` does for metrics.jsonl.
        self.writer = SummaryWriter(str(run_dir / "tensorboard"), purge_step=start_step or None, flush_secs=5)

    def write(self, group: str, record: dict) -> None:
        _append_jsonl(self.path, record)
        if self.writer is not None:
            for name, value in record.items():
                if name != "step":
                    self.writer.add_scalar(f"{group}/{name}", value, record["step"])
            self.writer.flush()

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def periodic_evaluation(config: ExperimentConfig, test: MultiViewDataset, model) -> Callable[[Any], dict]:
    """variables -> metrics on `config.train.eval_samples` evenly spaced test samples: the ground-truth-free
    `jaxpose.validation` measures (eval_disagreement_mm, eval_reprojection_px,
    eval_triangulation_p_mpjpe_mm) and, where the test split has 3D ground truth, eval_p_mpjpe / eval_mpjpe (mm)."""
    rows = np.unique(np.linspace(0, len(test) - 1, min(config.train.eval_samples, len(test))).astype(int))
    subset = pseudo_labelling.label(test.subset(rows), config.pseudo_labels)  # its views' triangulation, once
    truth = None
    if subset.target3d is not None:
        joints = evaluation.ground_truth_joints(subset)
        target, valid = evaluation.ground_truth_in_views(subset)
        truth = (joints, target[..., joints, :], valid)
    eval_step = make_eval_step(model, config.model)

    def evaluate(variables) -> dict:
        pred = evaluation.lift_every_view(eval_step, variables, subset, config.train.eval_batch_size, config.model.temporal_window)
        record = {}
        if truth is not None:
            joints, target, valid = truth
            overall = evaluation.evaluate_poses(pred[..., joints, :], target, None, valid)["overall"]
            record = {"eval_p_mpjpe": overall["p_mpjpe"], "eval_mpjpe": overall["mpjpe"]}
        consistency = validation.self_consistency(pred, subset, subset.pseudo3d, subset.pseudo3d_weight > 0)
        return record | {f"eval_{name}": values["overall"] for name, values in consistency.items()}

    return evaluate


def _read_jsonl(path: pathlib.Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def train(
    config: ExperimentConfig, train_set: MultiViewDataset, run_dir: pathlib.Path, test_set: MultiViewDataset | None = None
) -> tuple[TrainState, Any]:
    """Train (or resume) on `train_set`, which must carry pseudo-labels.  Returns (state, model).
    With `train.eval_every`, a subset of `test_set` is evaluated every so many steps (monitoring only).

    Data parallel over `config.parallel.data` devices of all processes (`jaxpose.parallel`); the
    returned state is this process's copy, on one local device.
    """
    cfg = config.train
    per_epoch = steps_per_epoch(len(train_set), cfg.batch_size)
    total_steps = per_epoch * cfg.epochs
    stop_step = min(total_steps, cfg.max_steps) if cfg.max_steps > 0 else total_steps
    model = config.model.build(train_set.skeleton.num_joints)
    optimizer = config.optimizer.build(total_steps)
    mesh = parallel.data_mesh(config.parallel.data)
    init_key, dropout_key = jax.random.split(jax.random.key(cfg.seed))
    state, dropout_key = parallel.replicate((init_train_state(model, optimizer, init_key), dropout_key), mesh)
    manager = checkpoint.checkpoint_manager(run_dir / "checkpoints", cfg.keep_checkpoints)
    lifter = checkpoint.LifterRecord(train_set.skeleton, config.model)
    restored = checkpoint.restore_latest(manager, state, discard_unreadable=True)
    if restored is not None:
        state = restored
        log.info("resumed from step %d of %d", int(state.step), total_steps)
    run_log = RunLog(run_dir, int(jax.device_get(state.step)), config.run.tensorboard)
    learning_rate = config.optimizer.learning_rate_schedule(total_steps)
    evaluate = periodic_evaluation(config, test_set, model) if cfg.eval_every > 0 and test_set is not None else None
    step_fn = jit_train_step(
        make_train_step(
            model, config.model, optimizer, config.loss, total_steps, cfg.log_every, stop_step, cfg.augment,
            train_set.skeleton.left_right_pairs,
        ),
        mesh,
    )
    start = int(state.step)
    views = train_set.num_views
    log.info(
        "training: %d samples x %d views, batch %d over %d devices (%d processes), %d steps/epoch,"
        " %d epochs (%d steps), from step %d",
        len(train_set), views, cfg.batch_size, mesh.size, jax.process_count(), per_epoch, cfg.epochs, total_steps, start,
    )
    bar = tqdm(total=stop_step, initial=start, desc="train", unit="step", disable=not config.run.progress or jax.process_index() != 0)
    last_time, last_step = time.perf_counter(), start
    with _SignalFlag() as interrupt:
        batches = parallel.process_batches(train_set, cfg.batch_size, cfg.seed, mesh, start, config.model.temporal_window)
        for step, batch in batches:
            if step >= stop_step:
                break
            state, metrics = step_fn(state, batch, dropout_key)
            done = step + 1
            bar.update(1)
            if done % cfg.log_every == 0 or done == stop_step:
                metrics = {k: float(v) for k, v in jax.device_get(metrics).items()}
                now = time.perf_counter()
                rate = (done - last_step) * cfg.batch_size / max(now - last_time, 1e-9)
                last_time, last_step = now, done
                record = {"step": done, "epoch": done / per_epoch, "samples_per_s": rate, **metrics}
                run_log.write("train", record | {"learning_rate": float(learning_rate(step))})
                bar.set_postfix(loss=f"{metrics['loss']:.4g}", samples_s=f"{rate:.0f}")
            if evaluate is not None and (done % cfg.eval_every == 0 or done == stop_step):
                run_log.write("eval", {"step": done, **evaluate(parallel.local_replica(state).variables)})
            if done % cfg.checkpoint_every == 0 or done == stop_step or interrupt.received is not None:
                checkpoint.save(manager, state, lifter)
            if interrupt.received is not None:
                manager.wait_until_finished()
                bar.close()
                run_log.close()
                raise Interrupted(f"stopped by signal {interrupt.received} at step {done}; checkpoint saved in {run_dir}")
    bar.close()
    run_log.close()
    checkpoint.save(manager, state, lifter)
    manager.wait_until_finished()
    return parallel.local_replica(state), model


def evaluate_and_report(
    config: ExperimentConfig,
    splits: Splits,
    state: TrainState,
    model,
    run_dir: pathlib.Path,
    method_name: str,
    wall_time: float,
) -> dict:
    """Single-view evaluation on every test view: the ground-truth-free measures (`jaxpose.validation`)
    always; where the test split has 3D ground truth, the metrics against it with the reference rows;
    report.{json,md}, plots."""
    test = splits.test
    eval_step = make_eval_step(model, config.model)
    pred = evaluation.lift_every_view(eval_step, state.variables, test, config.train.eval_batch_size, config.model.temporal_window)
    groups = test.labels.get(splits.group_label)
    test_triangulated = pseudo_labelling.label(test, config.pseudo_labels)
    triangulation = evaluation.poses_in_views(test, test_triangulated.pseudo3d)
    consistency = validation.self_consistency(pred, test_triangulated, test_triangulated.pseudo3d, test_triangulated.pseudo3d_weight > 0)
    excluded = splits.detector_specific_joints
    rows, joint_names = {}, test.skeleton.joint_names
    if test.target3d is not None:
        joints = evaluation.ground_truth_joints(test)
        joint_names = tuple(joint_names[j] for j in joints)
        target, valid = evaluation.ground_truth_in_views(test)
        mean_pose = np.broadcast_to(evaluation.mean_pose_prediction(splits.train), pred.shape)
        # Each row with the views it is evaluated on: the triangulation is a reference only where its
        # root has a label (two agreeing views); elsewhere it is no estimate at all.
        predictions = {
            method_name: (pred, valid),
            "Input triangulation (multi-view, reference)": (triangulation, valid & (test_triangulated.pseudo3d_weight[:, None, 0] > 0)),
            "Mean pose (baseline)": (np.ascontiguousarray(mean_pose), valid),
        }
        agreeing = splits.agreeing_joints()
        # Every loader labels each sample with its subject, sequence and frame number: the motion metrics
        # follow them (a sequence name such as "Walking 1" recurs across subjects).
        sequences = np.char.add(np.char.add(test.labels["subject"].astype(str), "/"), test.labels["sequence"].astype(str))
        frames = test.labels["frame"]
        motion_step = f"between test samples {evaluation.frame_step(sequences, frames)} frames apart"
        rows = {
            name: evaluation.evaluate_poses(poses[..., joints, :], target[..., joints, :], groups, views, agreeing, sequences, frames)
            for name, (poses, views) in predictions.items()
        }
    history = _read_jsonl(run_dir / "metrics.jsonl")
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
        "wall_time_s": wall_time,
        "devices": [str(d) for d in jax.devices()],
        "config": to_json_dict(config),
    }
    if jax.process_index() == 0:
        (run_dir / "report.json").write_text(json.dumps(report, indent=2))
        tables = list(splits.notes)
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
        (run_dir / "report.md").write_text("\n\n".join(tables) + "\n")
        reference = target if rows and len(joint_names) == test.skeleton.num_joints else triangulation
        _plots(config, test, pred, reference, run_dir)
    return report


def ground_truth_free_table(consistency: dict, camera_names: tuple[str, ...]) -> str:
    """Markdown: the `jaxpose.validation` measures per lifted camera and overall."""
    lines = [
        "**Without ground truth (jaxpose.validation): single-view predictions against the other views**",
        "",
        "| Lifted view | disagreement with the other views (mm) | reprojection into the other views (px) | P-MPJPE vs triangulation (mm) |",
        "|---|---|---|---|",
    ]
    for c, name in enumerate(camera_names):
        lines.append("| " + " | ".join([name, *(f"{consistency[m]['per_camera'][c]:.1f}" for m in validation.METRICS)]) + " |")
    lines.append("| all | " + " | ".join(f"{consistency[m]['overall']:.1f}" for m in validation.METRICS) + " |")
    lines += [
        "",
        "Lower is better for all three. To compare runs without ground truth, use the reprojection: on Human3.6M it"
        " ranks checkpoints and recipes as the true P-MPJPE does (docs/rig.md, section 5).",
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


def _plots(config, test: MultiViewDataset, pred, target, run_dir: pathlib.Path) -> None:
    records = _read_jsonl(run_dir / "metrics.jsonl")
    history = [r for r in records if "loss" in r]
    evaluations = [r for r in records if any(key.startswith("eval_") for key in r)]
    if evaluations:
        labels = {f"eval_{name}": label for name, label in EVALUATION_LABELS.items()}
        curves = {
            label: [(r["step"], r[key]) for r in evaluations if key in r] for key, label in labels.items() if key in evaluations[-1]
        }
        figure = viz.figure_loss_curves(curves, log_y=False)
        figure.suptitle("periodic evaluation on a test subset (monitoring only; the report is the final checkpoint)")
        viz.save_figure(figure, run_dir / "plots" / "periodic_evaluation.png")
    if history:
        keys = [k for k in ("loss", *TERMS, "supervised") if k in history[-1]]
        curves = {k: [(r["step"], r[k]) for r in history if k in r] for k in keys}
        viz.save_figure(viz.figure_loss_curves(curves), run_dir / "plots" / "loss_curves.png")
        share_keys = [f"{GRADIENT_SHARE_PREFIX}{term}" for term in TERMS if f"{GRADIENT_SHARE_PREFIX}{term}" in history[-1]]
        if share_keys:
            shares = {k.removeprefix(GRADIENT_SHARE_PREFIX): [(r["step"], r[k]) for r in history if k in r] for k in share_keys}
            figure = viz.figure_loss_curves(shares, log_y=False, overlay=True)
            viz.save_figure(figure, run_dir / "plots" / "gradient_shares.png")
    count = min(config.run.plot_samples, len(test))
    if count:
        picks = np.linspace(0, len(test) - 1, count).astype(int)
        figure = viz.figure_gt_vs_prediction(target[picks, 0], pred[picks, 0], test.skeleton)
        viz.save_figure(figure, run_dir / "plots" / "gt_vs_prediction.png")


def run(
    config: ExperimentConfig,
    load_data: Callable[[Any], Splits],
    replace_labels: Callable[[MultiViewDataset], MultiViewDataset] | None = None,
) -> dict:
    """The whole job: data -> pseudo-labels -> train (or resume) -> evaluate -> report.

    `replace_labels` maps the labelled training set to the one trained on: a diagnostic hook for
    studies of what the labels cost (`experiments.label_bias`), never part of a method.
    """
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s", stream=sys.stderr)
    # Before anything touches a device: a multi-host run connects its processes first.
    parallel.initialize(config.parallel.coordinator_address, config.parallel.num_processes, config.parallel.process_id)
    begin = time.perf_counter()
    check_resumable(config)
    # Data first: a missing or malformed file then leaves no run directory behind (and an
    # --run.overwrite start does not delete the previous run before the data are known to load).
    splits = load_data(config.data)
    run_dir = prepare_run_dir(config)
    if jax.process_index() == 0:
        for name, write in splits.artifacts.items():
            write(run_dir / name)
    log.info("data: %d train / %d test samples, %d views, %d joints", len(splits.train), len(splits.test), splits.train.num_views, splits.train.skeleton.num_joints)
    usable = splits.train.usable_view_count() >= config.pseudo_labels.min_views
    if not usable.all():
        log.warning("dropping %d training samples with fewer than %d usable views", int((~usable).sum()), config.pseudo_labels.min_views)
    train_set = splits.train.subset(np.flatnonzero(usable))
    train_set = pseudo_labelling.label(train_set, config.pseudo_labels)
    if replace_labels is not None:
        train_set = replace_labels(train_set)
    validate_batch(train_set.batch(np.arange(len(train_set)), config.model.temporal_window))
    splits = dataclasses.replace(splits, train=train_set)
    try:
        state, model = train(config, train_set, run_dir, splits.test)
    except Interrupted as stop:
        log.warning("%s", stop)
        raise SystemExit(130) from None
    method = "Lifter, supervised (3D ground truth)" if config.loss.supervision == "full" else "Lifter, self-supervised (ours)"
    report = evaluate_and_report(config, splits, state, model, run_dir, method, time.perf_counter() - begin)
    if jax.process_index() == 0:
        print((run_dir / "report.md").read_text())
        print(f"run directory: {run_dir}  (wall time {time.perf_counter() - begin:.0f} s)")
    return report
