"""Which ground-truth-free measure should a user select models by?  Measured where the truth is known.

    python -m experiments.rig_from_h36m --data-dir DATA/h36m --output runs/h36m_s1_rig
    python -m experiments.selection_study --data.root runs/h36m_s1_rig --data.train-stride 5 \\
        --data.validation-stride 5 --data.validation-recordings 'Directions 1' ... (as rig_from_h36m prints)

Trains `experiments.rig` (preset cpu) in several recipes that differ in accuracy, each evaluated every
`--eval-every` steps on a fixed subset of the validation recordings, with the ground truth (P-MPJPE)
and without it (`jaxpose.training.self_consistency`).  Then, for each ground-truth-free measure, Spearman's rank
correlation with the true P-MPJPE:
- across checkpoints: within each recipe, over its periodic evaluations (mean over recipes);
- across recipes: over the recipes' final reports (the whole validation split);
- pooled: over every (recipe, checkpoint) evaluation at once, the choice a user faces.
The table goes to `<run-root>/validation_study.md` (and is printed).  A recipe whose run directory
holds a finished run is not trained again.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib
from collections.abc import Sequence
from typing import Literal

import numpy as np
import tyro
from scipy.stats import spearmanr

from experiments import rig as rig_job
from jaxpose.training.experiment import ExperimentConfig
from jaxpose.training.run_directory import RunDirectory, check_study_folder, write_study_file
from jaxpose.training.runner import run
from jaxpose.training import self_consistency
from jaxpose.training.config import LossConfig, PseudoLabelConfig
from jaxpose.rig.config import RigProjectConfig

Recipe = Literal["cpu", "dropout_0.5", "plain_dlt_labels", "input_triangulation_only", "paper_loss_weights"]


def recipe_config(base: ExperimentConfig, recipe: Recipe) -> ExperimentConfig:
    """The rig cpu preset changed in one place each: recipes of different accuracy."""
    if recipe == "dropout_0.5":
        return dataclasses.replace(base, model=dataclasses.replace(base.model, dropout_rate=0.5))
    if recipe == "plain_dlt_labels":
        loss = dataclasses.replace(base.loss, label_robust_scale_mm=0.0)
        return dataclasses.replace(base, loss=loss, pseudo_labels=PseudoLabelConfig(method="svd"))
    if recipe == "input_triangulation_only":
        loss = dataclasses.replace(base.loss, reprojection=0.0, consistency=0.0, output_triangulation=0.0)
        return dataclasses.replace(base, loss=loss)
    if recipe == "paper_loss_weights":
        return dataclasses.replace(base, loss=dataclasses.replace(LossConfig(), label_robust_scale_mm=base.loss.label_robust_scale_mm))
    return base


@dataclasses.dataclass(frozen=True)
class StudyArgs:
    """Rank correlations of the ground-truth-free measures with the true P-MPJPE (see the module docstring)."""

    data: RigProjectConfig
    """The rig project, with ground truth in its validation recordings."""
    run_root: pathlib.Path = pathlib.Path("runs/validation_study")
    """One run directory per recipe below it, and validation_study.md."""
    recipes: tuple[Recipe, ...] = ("cpu", "dropout_0.5", "plain_dlt_labels", "input_triangulation_only", "paper_loss_weights")
    """The recipes trained (each the rig cpu preset changed in one place)."""
    eval_every: int = 100
    """Steps between periodic evaluations (the checkpoints compared)."""
    eval_samples: int = 1000
    """Validation instants (all their views) in each periodic evaluation."""
    progress: bool = True
    """Show progress bars."""


def study(args: StudyArgs) -> str:
    base = dataclasses.replace(rig_job.CPU, data=args.data)
    finals, series = {}, {}
    for recipe in args.recipes:
        config = recipe_config(base, recipe)
        config = dataclasses.replace(
            config,
            train=dataclasses.replace(config.train, eval_every=args.eval_every, eval_samples=args.eval_samples),
            run=dataclasses.replace(config.run, run_dir=args.run_root / recipe, progress=args.progress, tensorboard=False),
        )
        report = run(config, rig_job.EXPERIMENT.loader())
        summary = report["results"]["Lifter, self-supervised (ours)"]
        finals[recipe] = {"p_mpjpe": summary["overall"]["p_mpjpe"]} | {
            name: report["ground_truth_free"][name]["overall"] for name in self_consistency.METRICS
        }
        lines = RunDirectory(config.run.run_dir).metrics.read_text().splitlines()
        series[recipe] = [record for record in map(json.loads, lines) if "eval_p_mpjpe" in record]
    text = report_table(finals, series)
    write_study_file(args.run_root, "validation_study.md", text)
    print(text)
    return text


def _rank_correlation(a: Sequence[float], b: Sequence[float]) -> float:
    return float(spearmanr(a, b).statistic) if len(a) > 2 else float("nan")


def report_table(finals: dict[str, dict], series: dict[str, list[dict]]) -> str:
    """Markdown: each recipe's final numbers, then each measure's rank correlations with P-MPJPE."""
    lines = [
        "**Recipes: P-MPJPE on the validation recordings (ground truth) and the ground-truth-free measures**",
        "",
        "| Recipe | P-MPJPE (mm) | disagreement (mm) | reprojection (px) | P-MPJPE vs triangulation (mm) |",
        "|---|---|---|---|---|",
    ]
    for recipe, values in finals.items():
        lines.append(f"| {recipe} | {values['p_mpjpe']:.1f} | " + " | ".join(f"{values[m]:.1f}" for m in self_consistency.METRICS) + " |")
    lines += [
        "",
        "**Spearman rank correlation with the true P-MPJPE (1 = the measure orders models exactly as the truth does)**",
        "",
        "| Measure | across checkpoints (mean over recipes) | across recipes (final) | pooled (every recipe and checkpoint) |",
        "|---|---|---|---|",
    ]
    pooled = [record for records in series.values() for record in records]
    for measure in self_consistency.METRICS:
        key = f"eval_{measure}"
        within = [_rank_correlation([r[key] for r in records], [r["eval_p_mpjpe"] for r in records]) for records in series.values()]
        across = _rank_correlation([v[measure] for v in finals.values()], [v["p_mpjpe"] for v in finals.values()])
        together = _rank_correlation([r[key] for r in pooled], [r["eval_p_mpjpe"] for r in pooled])
        lines.append(f"| {measure} | {np.nanmean(within):+.2f} | {across:+.2f} | {together:+.2f} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> str:
    args = tyro.cli(StudyArgs, args=argv, prog="python -m experiments.selection_study", description=__doc__.split("\n\n")[0])
    check_study_folder(args.run_root)  # its runs train in sub-folders; its table is written into it
    return study(args)


if __name__ == "__main__":
    main()
