"""Pseudo-label quality per triangulation method on the synthetic data, and (with --train) the
lifter each one teaches.

    python -m experiments.pseudo_labels            # the pseudo-label table (a few minutes on 2 cores)
    python -m experiments.pseudo_labels --train    # + a lifter trained on each method's labels

Scenarios: the synthetic detector with its default faults (2% gross outliers, 1% left/right-swapped
views, 1% missing joints) and a harsh one (10% outliers, 5% swaps), each with the simulated detector
confidence and with the confidence withheld (1 for every detected joint, as the Human3.6M and
HumanEva-I files give: they carry no scores).  The synthetic confidence falls with the true error,
so it is close to an oracle; the withheld case shows what geometry alone can do.

Columns: errors of the pseudo-labels that are taught (weight > 0) against the ground truth on the
training split; the share of joints taught; the share of taught joints more than 100 mm off (what
teaches the lifter wrong); the time to compute them.  With --train: the P-MPJPE and MPJPE on the test
split of a lifter trained self-supervised on each method's pseudo-labels (by default with the main
job's budget: width 512, 8 epochs of 40,000 samples), each run in its own directory under `run_dir`.
"""

from __future__ import annotations

import dataclasses
import pathlib
import time

import numpy as np
import tyro

from jaxpose.training.experiment import RunConfig, TrainConfig
from jaxpose.training.run_directory import check_study_folder, write_study_file
from jaxpose.training.runner import run
from jaxpose.training.splits import Splits
from experiments.synthetic import DEFAULT, SyntheticData, load_splits
from jaxpose.training import pseudo_labelling
from jaxpose.training.config import PseudoLabelConfig
from jaxpose.model import ModelConfig
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.synthetic import SyntheticConfig
from jaxpose.robust import PseudoLabelMethod

SCENARIOS = ("default", "default-noconf", "harsh", "harsh-noconf")
LIFTER = "Lifter, self-supervised (ours)"


@dataclasses.dataclass(frozen=True)
class Study:
    """What to compare and the training budget of --train."""

    methods: tuple[PseudoLabelMethod, ...] = ("unweighted", "svd", "normal", "irls", "ransac")
    """Pseudo-label methods (see jaxpose.robust.pseudo_labels)."""
    scenarios: tuple[str, ...] = SCENARIOS
    """Detector scenarios for the pseudo-label table."""
    samples_per_subject: int = 8000
    """Synthetic samples per subject (5 training, 2 test subjects; the main job's 8000 by default)."""
    pseudo_labels: PseudoLabelConfig = PseudoLabelConfig()
    """Thresholds of the robust methods (its `method` is ignored: `methods` lists them)."""
    train: bool = False
    """Also train a lifter on the pseudo-labels of each of `train_runs`."""
    train_runs: tuple[str, ...] = (
        "harsh:unweighted", "harsh:svd", "harsh:ransac", "harsh-noconf:unweighted", "harsh-noconf:irls", "harsh-noconf:ransac",
    )  # fmt: skip
    """--train: the "scenario:method" pairs trained on: plain, confidence-weighted and robust labels
    (without confidence, "svd" is the plain DLT)."""
    width: int = 512
    """--train: lifter width (the main job's; the paper's is 1024)."""
    epochs: int = 8
    """--train: training epochs (the main job's)."""
    batch_size: int = 256
    """--train: samples per step."""
    run_dir: pathlib.Path = pathlib.Path("runs/pseudo_labels")
    """Where the table (table.md) and the training runs (<scenario>_<method>/) go."""


def generator_config(scenario: str, samples_per_subject: int) -> SyntheticConfig:
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; expected one of {SCENARIOS}")
    faults = dict(outlier_rate=0.1, swap_rate=0.05) if scenario.startswith("harsh") else {}
    return SyntheticConfig(samples_per_subject=samples_per_subject, **faults)


def withhold_confidence(dataset: MultiViewDataset) -> MultiViewDataset:
    """Confidence 1 for every detected joint (0 stays 0): a detector without scores."""
    return dataset.with_samples(confidence=(dataset.samples.confidence > 0).astype(np.float32))


def scenario_splits(scenario: str, data: SyntheticData) -> Splits:
    splits = load_splits(data)
    if scenario.endswith("-noconf"):
        train, test = withhold_confidence(splits.train), withhold_confidence(splits.test)
        splits = dataclasses.replace(splits, train=train, test=test)
    return splits


def label_quality(train: MultiViewDataset, method: str, options: PseudoLabelConfig) -> dict[str, float]:
    """Errors (mm) of the taught pseudo-labels of `train` against its ground truth."""
    begin = time.perf_counter()
    labelled = pseudo_labelling.label(train, dataclasses.replace(options, method=method))
    seconds = time.perf_counter() - begin
    error = np.linalg.norm(labelled.samples.pseudo3d - labelled.samples.target3d, axis=-1)
    taught = labelled.samples.pseudo3d_weight > 0
    return {
        "mpjpe": float(error[taught].mean()),
        "median": float(np.median(error[taught])),
        "taught": float(100.0 * taught.mean()),
        "gross": float(100.0 * (error[taught] > 100.0).mean()),
        "seconds": seconds,
    }


def train_lifter(study: Study, scenario: str, method: str) -> dict[str, float]:
    """P-MPJPE and MPJPE (mm, test split) of a lifter trained on `method`'s pseudo-labels under `scenario`."""
    data = SyntheticData(generator=generator_config(scenario, study.samples_per_subject))
    config = dataclasses.replace(
        DEFAULT,
        data=data,
        model=ModelConfig(width=study.width),
        pseudo_labels=dataclasses.replace(study.pseudo_labels, method=method),
        train=TrainConfig(batch_size=study.batch_size, epochs=study.epochs, checkpoint_every=10_000),
        run=RunConfig(run_dir=study.run_dir / f"{scenario}_{method}", progress=False, plot_samples=0),
    )
    report = run(config, lambda data: scenario_splits(scenario, data))
    overall = report["results"][LIFTER]["overall"]
    return {"p_mpjpe": overall["p_mpjpe"], "lifter_mpjpe": overall["mpjpe"]}


def markdown(rows: list[dict], trained: bool) -> str:
    header = ["Scenario", "Method", "MPJPE (mm)", "Median (mm)", "Taught (%)", "> 100 mm (%)", "Time (s, with compile)"]
    header += ["Lifter P-MPJPE (mm)", "Lifter MPJPE (mm)"] if trained else []
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        cells = [row["scenario"], f"`{row['method']}`", f"{row['mpjpe']:.1f}", f"{row['median']:.1f}"]
        cells += [f"{row['taught']:.2f}", f"{row['gross']:.2f}", f"{row['seconds']:.1f}"]
        if trained:
            cells += [f"{row['p_mpjpe']:.1f}", f"{row['lifter_mpjpe']:.1f}"] if "p_mpjpe" in row else ["-", "-"]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> str:
    study = tyro.cli(Study, args=argv, description=__doc__)
    check_study_folder(study.run_dir)  # its runs train in sub-folders; its table is written into it
    if study.train:
        compared = {f"{scenario}:{method}" for scenario in study.scenarios for method in study.methods}
        unknown = [run for run in study.train_runs if run not in compared]
        if unknown:
            raise SystemExit(f"--train-runs: {unknown} not among the compared scenario:method pairs (--scenarios, --methods)")
    rows = []
    for scenario in study.scenarios:
        train = scenario_splits(scenario, SyntheticData(generator_config(scenario, study.samples_per_subject))).train
        for method in study.methods:
            row = {"scenario": scenario, "method": method, **label_quality(train, method, study.pseudo_labels)}
            print(f"{scenario:15s} {method:11s} MPJPE {row['mpjpe']:6.1f} mm, taught {row['taught']:6.2f}%", flush=True)
            rows.append(row)
    if study.train:
        for row in rows:
            if f"{row['scenario']}:{row['method']}" in study.train_runs:
                row.update(train_lifter(study, row["scenario"], row["method"]))
    budget = ""
    if study.train:
        budget = f"\n\n--train budget: width {study.width}, {study.epochs} epochs, batch {study.batch_size}."
    table = (
        f"Pseudo-labels of the synthetic training split ({study.samples_per_subject} samples x 5 subjects,"
        f" 4 views, threshold {study.pseudo_labels.threshold_px:g} px).{budget}\n\n" + markdown(rows, study.train)
    )
    print(table)
    print(f"written to {write_study_file(study.run_dir, 'table.md', table + chr(10))}")
    return table


if __name__ == "__main__":
    main()
