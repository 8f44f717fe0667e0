"""Several trainings of one experiment side by side, in one report: the supervised twin, or the
paper's loss ablation (Table V).

    python -m experiments.ablation --dataset h36m --preset dev --data.data-dir DIR --rows twin
    python -m experiments.ablation --dataset h36m --preset dev --data.data-dir DIR        # Table V
    python -m experiments.ablation --dataset synthetic [config overrides ...]

`--dataset` picks the entry point (synthetic, h36m, humaneva) and `--preset` one of its presets;
every other flag is that entry point's (see `python -m experiments.<dataset> --help`).  Rows:
- `twin`: the configuration as given (self-supervised, all four losses) and its supervised twin
  (`--supervision full`: the same network, data and budget, trained on the 3D ground truth);
- `paper` (default): the paper's five loss configurations, L_in; L_proj; L_in + L_proj; + L_con;
  + L_out (all four), each keeping the configuration's weights for the terms it includes and
  zeroing the others, then the supervised twin.
Every row trains in its own sub-directory of --run.run-dir (default runs/comparison_<dataset>_<preset>),
so an interrupted comparison resumes where it stopped, and `--rows twin` then `--rows paper` on the
same directory train the self-supervised and supervised rows once.  The report, <run_dir>/comparison.md (and
.json), holds each row's P-MPJPE and MPJPE (average over groups), the same over the joints whose
detector definition agrees with the mocap (for Stacked Hourglass: all but "Spine" and "Head",
Procrustes-aligned on those joints alone),
the input-triangulation reference row, the per-joint P-MPJPE, and each term's final share of the
gradient with respect to the lifter output.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
import sys

import numpy as np

from experiments import cli, h36m, humaneva, synthetic
from jaxpose.training.experiment import ExperimentConfig
from jaxpose.training.run_directory import check_study_folder, write_study_file
from jaxpose.training.runner import run
from jaxpose.training import evaluation
from jaxpose.losses import TERMS

# The entry points an ablation can run, by their --dataset name.
EXPERIMENTS = {experiment.name: experiment for experiment in (synthetic.EXPERIMENT, h36m.EXPERIMENT, humaneva.EXPERIMENT)}
PROG = "python -m experiments.ablation"

# (row label, terms switched on) in the order of the paper's Table V.
CONFIGURATIONS = (
    ("L_in", ("input_triangulation",)),
    ("L_proj", ("reprojection",)),
    ("L_in + L_proj", ("input_triangulation", "reprojection")),
    ("L_in + L_proj + L_con", ("input_triangulation", "reprojection", "consistency")),
    ("L_in + L_proj + L_con + L_out", TERMS),
)
SELF_LABEL = "Self-supervised (all four losses)"
SUPERVISED_LABEL = "Supervised twin (3D ground truth)"
ROW_SETS = ("paper", "twin")


def ablation_configs(base: ExperimentConfig) -> list[tuple[str, ExperimentConfig]]:
    """One config per row of the paper's Table V, each in its own run sub-directory."""
    configs = []
    for index, (label, terms) in enumerate(CONFIGURATIONS):
        loss = dataclasses.replace(
            base.loss, supervision="self", **{term: (getattr(base.loss, term) if term in terms else 0.0) for term in TERMS}
        )
        run_dir = base.run.run_dir / _row_directory(index, terms)
        configs.append((label, dataclasses.replace(base, loss=loss, run=dataclasses.replace(base.run, run_dir=run_dir))))
    return configs


def _row_directory(index: int, terms: tuple[str, ...]) -> str:
    return f"{index + 1}_{'_'.join(t.split('_')[0] for t in terms)}"


def supervised_twin(base: ExperimentConfig) -> ExperimentConfig:
    """The same network, data and budget trained on the 3D ground truth."""
    run_dir = base.run.run_dir / "supervised"
    return dataclasses.replace(
        base, loss=dataclasses.replace(base.loss, supervision="full"), run=dataclasses.replace(base.run, run_dir=run_dir)
    )


def row_configs(base: ExperimentConfig, rows: str) -> list[tuple[str, ExperimentConfig]]:
    if rows == "twin":
        # The all-four-terms row of the ablation, in the same directory: a twin comparison and an
        # ablation on one --run.run-dir share their self-supervised and supervised trainings.
        _, own = ablation_configs(base)[-1]
        return [(SELF_LABEL, own), (SUPERVISED_LABEL, supervised_twin(base))]
    if rows == "paper":
        return ablation_configs(base) + [(SUPERVISED_LABEL, supervised_twin(base))]
    raise ValueError(f"unknown --rows {rows!r}; expected one of {ROW_SETS}")


def comparison_table(results: list[tuple[str, dict]]) -> str:
    """One line per row: P-MPJPE / MPJPE / N-MPJPE (group averages), P-MPJPE / MPJPE over the joints
    whose definitions agree (when the 2D source defines some differently), and each term's final
    gradient share; then the input-triangulation reference row of the first run."""
    first = results[0][1]
    excluded = first.get("detector_specific_joints", [])
    header = ["Rows", "P-MPJPE (mm)", "MPJPE (mm)", "N-MPJPE (mm)", "MPJVE (mm/frame)", "accel. error (mm/frame²)"]
    if excluded:
        header += [f"P-MPJPE without {', '.join(excluded)}", f"MPJPE without {', '.join(excluded)}"]
    header += [f"share {term}" for term in TERMS]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]

    def cells(summary: dict) -> list[str]:
        average = summary.get("group_average", summary["overall"])
        values = [average["p_mpjpe"], average["mpjpe"], average["n_mpjpe"], average.get("mpjve"), average.get("accel_error")]
        digits = [1, 1, 1, 1, 2]
        if excluded:
            agreeing = summary["agreeing_joints"].get("group_average", summary["agreeing_joints"]["overall"])
            values += [agreeing["p_mpjpe"], agreeing["mpjpe"]]
            digits += [1, 1]
        # A row's motion metrics are missing where its report predates them (a resumed comparison).
        return ["-" if v is None or not np.isfinite(v) else f"{v:.{d}f}" for v, d in zip(values, digits)]

    for label, report in results:
        shares = report.get("final_gradient_shares", {})
        share_cells = [f"{100 * shares[term]:.1f}%" if term in shares else "-" for term in TERMS]
        lines.append("| " + " | ".join([label, *cells(report["results"][report["method"]]), *share_cells]) + " |")
    reference = next(name for name in first["results"] if name.startswith("Input triangulation"))
    lines.append("| " + " | ".join([reference, *cells(first["results"][reference]), *["-"] * len(TERMS)]) + " |")
    return "\n".join(lines)


def per_joint_rows(results: list[tuple[str, dict]]) -> dict[str, dict]:
    rows = {label: report["results"][report["method"]] for label, report in results}
    first = results[0][1]
    reference = next(name for name in first["results"] if name.startswith("Input triangulation"))
    return rows | {reference: first["results"][reference]}


def main(argv: list[str] | None = None) -> str:
    argv = sys.argv[1:] if argv is None else list(argv)
    dataset, argv = cli.choose(argv, "--dataset", list(EXPERIMENTS), "synthetic", PROG)
    rows, argv = cli.choose(argv, "--rows", ROW_SETS, "paper", PROG)
    experiment = EXPERIMENTS[dataset]
    presets = {
        name: dataclasses.replace(
            preset, run=dataclasses.replace(preset.run, run_dir=pathlib.Path(f"runs/comparison_{dataset}_{name}"))
        )
        for name, preset in experiment.presets.items()
    }
    description = f"{__doc__}\n--dataset {dataset} --rows {rows}: flags below are those of {experiment.prog}."
    prog = f"{PROG} --dataset {dataset} --rows {rows}"
    base = cli.parse(experiment, argv, description, prog, presets)
    check_study_folder(base.run.run_dir)  # the rows train in its sub-folders; the comparison is written into it
    load_splits = experiment.loader()
    results = [(label, run(config, load_splits)) for label, config in row_configs(base, rows)]
    joint_names = tuple(results[0][1]["joint_names"])
    text = "\n\n".join(
        [
            comparison_table(results),
            evaluation.per_joint_table(per_joint_rows(results), "p_mpjpe", joint_names, "P-MPJPE (mm) per joint"),
            evaluation.per_joint_table(per_joint_rows(results), "mpjpe", joint_names, "MPJPE (mm) per joint"),
        ]
    )
    write_study_file(base.run.run_dir, "comparison.md", text + "\n")
    write_study_file(base.run.run_dir, "comparison.json", json.dumps({label: r["results"] for label, r in results}, indent=2))
    print(text)
    return text


if __name__ == "__main__":
    main()
