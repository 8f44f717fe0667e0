"""The paper's loss ablation (Table V): five loss configurations trained in sequence, one table.

    python -m experiments.ablation --dataset synthetic [config overrides ...]
    python -m experiments.ablation --dataset h36m --data.data-dir data/h36m

`--dataset` picks the entry point (synthetic, h36m, humaneva); every other flag is that entry
point's (see `python -m experiments.<dataset> --help`).  Each configuration trains in its own
sub-directory of --run.run-dir (default runs/ablation_<dataset>), so an interrupted ablation
resumes where it stopped; the table is written to <run_dir>/ablation.md.  The configurations keep
the base config's weights for the terms they include and zero the others:
L_in; L_proj; L_in + L_proj; + L_con; + L_out (all four).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import pathlib
import sys

import tyro

from experiments import cli
from experiments.config import ExperimentConfig
from experiments.runner import run

DATASETS = {"synthetic": "experiments.synthetic", "h36m": "experiments.h36m", "humaneva": "experiments.humaneva"}

# (row label, terms switched on) in the order of the paper's Table V.
CONFIGURATIONS = (
    ("L_in", ("input_triangulation",)),
    ("L_proj", ("reprojection",)),
    ("L_in + L_proj", ("input_triangulation", "reprojection")),
    ("L_in + L_proj + L_con", ("input_triangulation", "reprojection", "consistency")),
    ("L_in + L_proj + L_con + L_out", ("input_triangulation", "reprojection", "consistency", "output_triangulation")),
)
TERMS = ("input_triangulation", "reprojection", "consistency", "output_triangulation")


def ablation_configs(base: ExperimentConfig) -> list[tuple[str, ExperimentConfig]]:
    """One config per row, each in its own run sub-directory."""
    configs = []
    for index, (label, terms) in enumerate(CONFIGURATIONS):
        loss = dataclasses.replace(
            base.loss, supervision="self", **{term: (getattr(base.loss, term) if term in terms else 0.0) for term in TERMS}
        )
        run_dir = base.run.run_dir / f"{index + 1}_{'_'.join(t.split('_')[0] for t in terms)}"
        configs.append((label, dataclasses.replace(base, loss=loss, run=dataclasses.replace(base.run, run_dir=run_dir))))
    return configs


def ablation_table(results: list[tuple[str, dict]]) -> str:
    lines = ["| Loss functions | P-MPJPE (mm) | MPJPE (mm) | N-MPJPE (mm) |", "|---|---|---|---|"]
    for label, report in results:
        summary = report["results"][report["method"]]
        average = summary.get("group_average", summary["overall"])
        lines.append(f"| {label} | {average['p_mpjpe']:.1f} | {average['mpjpe']:.1f} | {average['n_mpjpe']:.1f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> str:
    argv = sys.argv[1:] if argv is None else list(argv)
    selector = argparse.ArgumentParser(add_help=False)
    selector.add_argument("--dataset", choices=sorted(DATASETS), default="synthetic")
    chosen, rest = selector.parse_known_args(argv)
    module = importlib.import_module(DATASETS[chosen.dataset])
    default = module.DEFAULT
    default = dataclasses.replace(default, run=dataclasses.replace(default.run, run_dir=pathlib.Path(f"runs/ablation_{chosen.dataset}")))
    description = __doc__ + f"\nFlags below are those of experiments.{chosen.dataset}."
    base = tyro.cli(ExperimentConfig[type(default.data)], default=default, args=rest, description=description)
    load_splits = module.load_splits
    if hasattr(module, "expected_files"):  # real data: a missing file is one message, not a traceback
        load_splits = cli.guard_data_errors(load_splits, module.expected_files)
    results = [(label, run(config, load_splits)) for label, config in ablation_configs(base)]
    table = ablation_table(results)
    base.run.run_dir.mkdir(parents=True, exist_ok=True)
    (base.run.run_dir / "ablation.md").write_text(table + "\n")
    (base.run.run_dir / "ablation.json").write_text(json.dumps({label: r["results"] for label, r in results}, indent=2))
    print(table)
    return table


if __name__ == "__main__":
    main()
