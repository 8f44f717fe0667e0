"""MPI-INF-3DHP: a lifter trained on Human3.6M, evaluated on the MPI-INF-3DHP test set without any
training on it (the paper's Table V, "generalization").

    python -m experiments.mpi_inf_3dhp --run-dir runs/h36m_cpu --data-dir /data/mpi_inf_3dhp
    python -m experiments.mpi_inf_3dhp --help

The run directory must be one of `python -m experiments.h36m` trained with 17 joints (--data.detections
cpn, gt or a 17-joint npz): MPI-INF-3DHP's joints are matched index by index to H36M_17
(`jaxpose.skeleton.MPI_INF_3DHP_17`), so the 16-joint Stacked Hourglass model cannot be evaluated.

Protocol: single-view inference on every valid test frame, from the annotated 2D (annot2, as given)
and the test set's published intrinsics (`jaxpose.datasets.mpi_inf_3dhp.camera_intrinsics`); the
prediction is compared root-relative with the universal-skeleton 3D (univ_annot3), with no
rescaling or alignment, over all 17 joints.  PCK at 150 mm and AUC (PCK averaged over 0-150 mm in
5 mm steps) are the primary numbers, as in the paper; MPJPE and P-MPJPE are given as extras.
Results per activity, per sequence and over all frames go to <out-dir>/report.md and report.json.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np
import tyro

from jaxpose.training import evaluation

from jaxpose.serving import inference
from jaxpose.training.run_directory import RunDirectory, write_study_file
from jaxpose.training.checkpoint import CheckpointError
from jaxpose.data.dataset import consecutive_spans
from jaxpose.formats.errors import DataFormatError
from jaxpose.datasets.mpi_inf_3dhp import ACTIVITY_NAMES, SEQUENCES, load_mpi_inf_3dhp_test
from jaxpose.skeleton import H36M_17

# The paper's Table V row for its own method (trained on Human3.6M).
PAPER_RESULT = {"pck": 65.9, "auc": 32.5}
COLUMNS = (("PCK@150mm (%)", "pck"), ("AUC (%)", "auc"), ("MPJPE (mm)", "mpjpe"), ("P-MPJPE (mm)", "p_mpjpe"))


@dataclasses.dataclass(frozen=True)
class Mpi3dhpEvaluation:
    """Evaluate a Human3.6M-trained lifter on the MPI-INF-3DHP test set."""

    run_dir: pathlib.Path = pathlib.Path("runs/h36m_cpu")
    """Run directory of `python -m experiments.h36m` trained with 17 joints (or its checkpoints/)."""
    data_dir: pathlib.Path = pathlib.Path("data/mpi_inf_3dhp")
    """Folder holding the test set's TS1 ... TS6/annot_data.mat."""
    sequences: tuple[str, ...] = SEQUENCES
    """Test sequences to evaluate."""
    out_dir: pathlib.Path | None = None
    """Where report.md and report.json go (a folder of its own: never the run's); None = <run-dir>_mpi_inf_3dhp
    beside the run."""
    batch_size: int = 4096
    """Poses per inference call."""
    progress: bool = True
    """Show a progress bar while reading the annotation files."""


def evaluate(settings: Mpi3dhpEvaluation) -> dict:
    """Load the lifter and the test set, predict, score; returns the report (also written to disk)."""
    lifter = _load_h36m17_lifter(settings.run_dir, settings.batch_size)
    try:
        test = load_mpi_inf_3dhp_test(settings.data_dir, settings.sequences, progress=settings.progress)
    except DataFormatError as error:
        expected = f"{settings.data_dir}/<sequence>/annot_data.mat for sequences {' '.join(settings.sequences)}"
        raise SystemExit(f"error: {error}\nThis evaluation reads the MPI-INF-3DHP test set: {expected}") from None
    if lifter.model_config.temporal_window == 1:
        predictions = lifter.predict(test.keypoints2d, intrinsics=test.K)
    else:  # a temporal lifter reads each call as one sequence: one per stretch of consecutive valid frames
        predictions = np.empty((len(test), lifter.num_joints, 3), np.float32)
        for start, end in np.unique(consecutive_spans({"sequence": test.sequence, "frame": test.frame}), axis=0).tolist():
            predictions[start:end] = lifter.predict(test.keypoints2d[start:end], intrinsics=test.K[start:end])
    per_pose, per_joint = evaluation.compute_metrics(predictions, test.univ3d)
    report = {
        "run_dir": str(settings.run_dir),
        "checkpoint_step": lifter.step,
        "data_dir": str(settings.data_dir),
        "sequences": list(settings.sequences),
        "frames": len(test),
        "protocol": "single view, annot2 + published intrinsics, root-relative univ_annot3, no alignment, 17 joints",
        "by_activity": evaluation.summarize(per_pose, test.activity_name, per_joint=per_joint),
        "by_sequence": evaluation.summarize(per_pose, test.sequence),
        "paper": PAPER_RESULT,
    }
    write_study_file(output_folder(settings), "report.json", json.dumps(report, indent=2))
    write_study_file(output_folder(settings), "report.md", render(report) + "\n")
    return report


def output_folder(settings: Mpi3dhpEvaluation) -> pathlib.Path:
    """--out-dir, else a folder beside the run: a run folder holds only what its training wrote."""
    run = RunDirectory.of(settings.run_dir).path
    return settings.out_dir or run.with_name(f"{run.name}_mpi_inf_3dhp")


def render(report: dict) -> str:
    """report.md: a table per activity (in the data set's activity order) and per sequence."""
    by_activity, by_sequence = report["by_activity"], report["by_sequence"]
    activity_order = [name for name in ACTIVITY_NAMES.values() if name in by_activity["groups"]]
    activity_order += sorted(set(by_activity["groups"]) - set(activity_order))
    paper_row = ("Paper: ours (self-supervised)", {**PAPER_RESULT, "count": 2935})
    header = (
        f"**MPI-INF-3DHP test set, lifter of {report['run_dir']} (step {report['checkpoint_step']}),"
        f" {report['frames']} valid frames of {' '.join(report['sequences'])}**\n\n"
        f"Protocol: {report['protocol']}."
    )
    per_activity = _table(
        "Activity",
        [(name, by_activity["groups"][name]) for name in activity_order]
        + [("All frames", by_activity["overall"]), ("Activity average", by_activity["group_average"]), paper_row],
    )
    sequences = [(name, by_sequence["groups"][name]) for name in sorted(by_sequence["groups"])]
    per_sequence = _table("Sequence", sequences + [("All frames", by_sequence["overall"])])
    return "\n\n".join([header, per_activity, per_sequence])


def _table(first: str, rows: list[tuple[str, dict]]) -> str:
    header = [first, "Frames", *(name for name, _ in COLUMNS)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for name, values in rows:
        frames = str(values["count"]) if "count" in values else "-"
        cells = [f"{values[key]:.1f}" if key in values else "-" for _, key in COLUMNS]
        lines.append("| " + " | ".join([name, frames, *cells]) + " |")
    return "\n".join(lines)


def _load_h36m17_lifter(run_dir: pathlib.Path, batch_size: int) -> inference.Lifter3D:
    """The run's lifter, which must lift H36M_17 (the joints MPI_INF_3DHP_17 corresponds to)."""
    try:
        lifter = inference.load(run_dir, batch_size=batch_size)
    except (FileNotFoundError, ValueError, CheckpointError) as error:
        raise SystemExit(f"error: cannot load a lifter from --run-dir {run_dir}: {error}") from None
    if lifter.skeleton != H36M_17:
        hint = (
            " It was trained on the 16-joint Stacked Hourglass detections (--data.detections sh), which lack the"
            " nose/neck joint." if lifter.num_joints == 16 else ""
        )
        raise SystemExit(
            f"error: the lifter in {run_dir} lifts {lifter.num_joints} joints (skeleton {lifter.skeleton.name});"
            f" MPI-INF-3DHP is evaluated with a Human3.6M lifter of the 17-joint H36M_17 layout.{hint}"
            " Train one with `python -m experiments.h36m --data.detections cpn` (or gt)."
        )
    return lifter


def main(argv: list[str] | None = None) -> dict:
    settings = tyro.cli(Mpi3dhpEvaluation, args=argv, description=__doc__, prog="python -m experiments.mpi_inf_3dhp")
    report = evaluate(settings)
    print(output_folder(settings).joinpath("report.md").read_text())
    return report


if __name__ == "__main__":
    main()
