"""Search a recipe on your own data: a small grid of variants trained at one sample budget, ranked
without ground truth, in one resumable report.

    python -m experiments.search --dataset rig --data.root PROJECT \\
        --vary model.width 256 512 --vary model.dropout-rate 0.1 0.2 --seeds 0 1
    python -m experiments.search --dataset h36m --preset dev --data.data-dir DATA/h36m_s1 --vary model.stages 1 2

`--dataset` picks the entry point (rig by default; synthetic, h36m, humaneva) and `--preset` one of its
presets; every other flag is that entry point's and sets the base recipe.  Each `--vary NAME VALUE ...`
is one axis of the grid (NAME a flag of the entry point without its dashes, e.g. model.width or
train.augment.drop); every combination of the axes' values is a variant, trained once per `--seeds`
value.  All variants train at most the base's `--train.max-samples` (the preset's cap, or as given),
also a variant that changes the epochs or the batch, so that they are compared at the same number of
training samples; a variant that varies train.max-samples itself sets its own.  Without a cap in the
base, each variant trains its own epochs (the report says so).

Every (variant, seed) trains in its own run directory, <run_dir>/<variant>/seed<S> (default run_dir
runs/search_<dataset>_<preset>); one that holds a finished report of the same settings is read, not
trained again, so an interrupted search resumes where it stopped.  The report, <run_dir>/search.md (and
search.json), rewritten after every training, ranks the variants by the ground-truth-free reprojection
error (`jaxpose.training.self_consistency`: each view's lift placed and projected into the other views; on Human3.6M it
orders recipes as the true P-MPJPE does, docs/rig.md section 5), the mean over seeds, and picks the
lowest.  Where the held-out data have 3D ground truth, it also gives each variant's P-MPJPE and how well
the reprojection's ranking agrees with the true one (Spearman's rho and Kendall's tau) and what the pick
costs against the truly best variant.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import pathlib
import re
import sys
from collections.abc import Sequence
from typing import Annotated

import numpy as np
import tyro
from scipy.stats import kendalltau, spearmanr

from experiments import ablation, cli, rig
from jaxpose.training.experiment import ExperimentConfig
from jaxpose.training.run_directory import RunDirectory, check_resumable, check_study_folder, read_jsonl, write_study_file
from jaxpose.training.runner import run

EXPERIMENTS = ablation.EXPERIMENTS | {"rig": rig.EXPERIMENT}
PROG = "python -m experiments.search"
SELECTION_METRIC = "reprojection_px"
BASE = "base"


@dataclasses.dataclass(frozen=True)
class Variant:
    """One point of the grid: its name and the entry point's flags that make it."""

    name: str
    flags: tuple[str, ...]
    axes: tuple[str, ...] = ()
    """The flag names it varies (e.g. model.width)."""

    @property
    def directory(self) -> str:
        return re.sub(r"[^A-Za-z0-9._=,-]+", "_", self.name)


def grid(axes: Sequence[Sequence[str]]) -> list[Variant]:
    """Every combination of the axes' values; an axis is [NAME, VALUE, ...] (`--vary`)."""
    for axis in axes:
        if len(axis) < 2 or axis[0].startswith("-"):
            raise SystemExit(f"error: --vary {' '.join(axis)}: expected a flag name without dashes and its values, e.g. --vary model.width 256 512")
    if not axes:
        return [Variant(BASE, ())]
    variants = []
    for values in itertools.product(*(axis[1:] for axis in axes)):
        pairs = [(axis[0], value) for axis, value in zip(axes, values)]
        flags = tuple(token for name, value in pairs for token in (f"--{name}", value))
        variants.append(Variant(", ".join(f"{name}={value}" for name, value in pairs), flags, tuple(axis[0] for axis in axes)))
    return variants


def variant_config(experiment: cli.Experiment, argv: Sequence[str], base: ExperimentConfig, variant: Variant, seed: int) -> ExperimentConfig:
    """The base's flags and the variant's, parsed as the entry point parses them, at the base's sample cap
    and with `seed`, in <run_dir>/<variant>/seed<S>."""
    config = cli.parse(experiment, [*argv, *variant.flags], __doc__, PROG, _presets(experiment))
    train = dataclasses.replace(config.train, seed=seed)
    if not any(axis.replace("_", "-") == "train.max-samples" for axis in variant.axes):
        train = dataclasses.replace(train, max_samples=base.train.max_samples)
    run_dir = base.run.run_dir / variant.directory / f"seed{seed}"
    return dataclasses.replace(config, train=train, run=dataclasses.replace(config.run, run_dir=run_dir))


def _presets(experiment: cli.Experiment) -> dict[str, ExperimentConfig]:
    """The entry point's presets, each with its search directory."""
    return {
        name: dataclasses.replace(preset, run=dataclasses.replace(preset.run, run_dir=pathlib.Path(f"runs/search_{experiment.name}_{name}")))
        for name, preset in experiment.presets.items()
    }


def trained_report(experiment: cli.Experiment, config: ExperimentConfig, run_folder: RunDirectory) -> dict:
    """The run's report: read where its folder (`config.run.run_dir`'s) holds a finished one of these settings, else
    trained (or resumed) and evaluated by `jaxpose.training.runner.run`."""
    check_resumable(config)  # a directory holding another recipe's run is refused, naming it
    path = run_folder.report_json
    if path.exists():
        report = json.loads(path.read_text())
        if report.get("test_time_flip", False) == config.train.eval_flip:
            return report
    return run(config, experiment.loader(config))  # the run's progress bars and temporal window, for a rig project


def summary(report: dict, run_folder: RunDirectory) -> dict:
    """What the ranking reads of one run: the selection metric, P-MPJPE (group average; None without
    ground truth), samples trained, training samples/s (median of the log) and wall time."""
    results = report["results"]
    truth = None
    if results:
        own = results[report["method"]]
        truth = own.get("group_average", own["overall"])["p_mpjpe"]
    rates = [record["samples_per_s"] for record in read_jsonl(run_folder.metrics) if "samples_per_s" in record]
    batch = report["config"]["train"]["batch_size"]
    return {
        SELECTION_METRIC: report["ground_truth_free"][SELECTION_METRIC]["overall"],
        "p_mpjpe": truth,
        "samples": report["train_steps"] * batch,
        "samples_per_s": float(np.median(rates)) if rates else None,
        "wall_time_s": report["wall_time_s"],
    }


def ranking(rows: dict[str, list[dict]]) -> dict:
    """The variants ranked by the mean selection metric over their seeds; with ground truth, the rank
    correlations of that ranking with the true one and the P-MPJPE of the pick against the best."""
    means = {name: {key: _mean([run[key] for run in runs]) for key in (SELECTION_METRIC, "p_mpjpe")} for name, runs in rows.items()}
    order = sorted(means, key=lambda name: means[name][SELECTION_METRIC])
    result = {"order": order, "means": means, "selected": order[0]}
    truth = [means[name]["p_mpjpe"] for name in order]
    if all(value is not None for value in truth) and len(order) > 1:
        selection = [means[name][SELECTION_METRIC] for name in order]
        best = min(order, key=lambda name: means[name]["p_mpjpe"])
        result |= {
            "spearman": float(spearmanr(selection, truth).statistic),
            "kendall": float(kendalltau(selection, truth).statistic),
            "best_by_truth": best,
            "selection_cost_mm": means[order[0]]["p_mpjpe"] - means[best]["p_mpjpe"],
        }
    return result


def _mean(values: list) -> float | None:
    return None if any(v is None for v in values) else float(np.mean(values))


def report_table(rows: dict[str, list[dict]], seeds: Sequence[int], cap: int) -> str:
    """Markdown: the variants in the reprojection's order, per seed and on average; the agreement with
    the truth where there is one."""
    ranked = ranking(rows)
    has_truth = all(run["p_mpjpe"] is not None for runs in rows.values() for run in runs)
    budget = f"at most {cap:,} training samples each" if cap else "no sample cap: each variant trains its own epochs"
    lines = [
        f"**Recipe search: {len(rows)} variants x seeds {', '.join(map(str, seeds))}, {budget}; ranked by the reprojection"
        " into the other views (ground-truth-free, lower is better)**",
        "",
        "| Rank | Variant | reprojection (px): mean (per seed) |"
        + (" P-MPJPE (mm): mean (per seed) | true rank |" if has_truth else "")
        + " samples trained | training samples/s | wall time (s) |",
        "|---|---|---|" + ("---|---|" if has_truth else "") + "---|---|---|",
    ]
    true_order = sorted(rows, key=lambda name: ranked["means"][name]["p_mpjpe"]) if has_truth else []
    for rank, name in enumerate(ranked["order"], 1):
        runs = rows[name]
        cells = [str(rank), name, _cell([run[SELECTION_METRIC] for run in runs])]
        if has_truth:
            cells += [_cell([run["p_mpjpe"] for run in runs]), str(true_order.index(name) + 1)]
        rates = [run["samples_per_s"] for run in runs if run["samples_per_s"] is not None]
        cells += [f"{runs[0]['samples']:,}", f"{np.median(rates):.0f}" if rates else "-", f"{np.mean([run['wall_time_s'] for run in runs]):.0f}"]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", f"Selected without ground truth: **{ranked['selected']}**."]
    if "spearman" in ranked:
        lines.append(
            f"With the ground truth: the reprojection's ranking against the true P-MPJPE's, Spearman's rho {ranked['spearman']:+.2f},"
            f" Kendall's tau {ranked['kendall']:+.2f} ({len(rows)} variants); the truly best is {ranked['best_by_truth']},"
            f" and the pick costs {ranked['selection_cost_mm']:.1f} mm of P-MPJPE against it."
        )
    return "\n".join(lines) + "\n"


def _cell(values: list[float]) -> str:
    mean = f"{np.mean(values):.1f}"
    return mean if len(values) == 1 else f"{mean} ({' / '.join(f'{v:.1f}' for v in values)})"


@dataclasses.dataclass(frozen=True)
class SearchFlags:
    """The search's own flags; the others are the entry point's (the base recipe)."""

    vary: Annotated[tuple[tuple[str, ...], ...], tyro.conf.UseAppendAction] = ()
    """NAME VALUE [VALUE ...]: one axis of the grid (repeatable)."""
    seeds: tuple[int, ...] = ()
    """Seeds each variant trains with; empty = the base's --train.seed."""


def main(argv: Sequence[str] | None = None) -> str:
    argv = sys.argv[1:] if argv is None else list(argv)
    dataset, argv = cli.choose(argv, "--dataset", list(EXPERIMENTS), "rig", PROG)
    searched, argv = tyro.cli(SearchFlags, args=argv, prog=PROG, return_unknown_args=True, add_help=False)
    experiment = EXPERIMENTS[dataset]
    description = (
        f"{__doc__}\n--dataset {dataset}: the search's own flags are --vary NAME VALUE [VALUE ...] (one axis of the"
        f" grid, repeatable) and --seeds SEED [SEED ...] (default: the base's --train.seed); the flags below are"
        f" those of {experiment.prog}, the base recipe."
    )
    base = cli.parse(experiment, argv, description, f"{PROG} --dataset {dataset}", _presets(experiment))
    check_study_folder(base.run.run_dir)  # the variants train in its sub-folders; the ranking is written into it
    seeds = searched.seeds or [base.train.seed]
    variants = grid(searched.vary)
    rows: dict[str, list[dict]] = {}
    for variant in variants:
        for seed in seeds:
            config = variant_config(experiment, argv, base, variant, seed)
            run_folder = RunDirectory(config.run.run_dir)
            rows.setdefault(variant.name, []).append(summary(trained_report(experiment, config, run_folder), run_folder))
            text = report_table(rows, seeds, base.train.max_samples)
            write_study_file(base.run.run_dir, "search.md", text)
            write_study_file(base.run.run_dir, "search.json", json.dumps({"runs": rows, "ranking": ranking(rows)}, indent=2))
    print(text)
    return text


if __name__ == "__main__":
    main()
