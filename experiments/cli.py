"""The one command-line mechanism of the experiment entry points (`experiments.synthetic`, `h36m`,
`humaneva`, and `ablation` over them): tyro over a typed config, with presets.

Presets.  Each entry point is an `Experiment` holding complete `ExperimentConfig`s by name (its
`PRESETS`, the registry in the style of a named-config table).  `--preset NAME`
picks one (default: the first, "main" for synthetic and "cpu" for the real data sets); every other
flag overrides a field of it, and `--help` lists every flag with the chosen preset's values as
defaults:

    python -m experiments.h36m --preset paper --data.data-dir /data/h36m --train.epochs 100
    python -m experiments.h36m --preset paper --help

A preset flag rather than tyro subcommands: with subcommands, the flags would have to follow the
subcommand name and the top-level `--help` would not list them.

Data errors.  A missing or malformed data file ends the program with one message (what was expected
where, what was found, the files this run reads, and the manual's "Getting the data", docs/data.md) and a
non-zero exit status, not a traceback.  The runner loads the data before it creates the run
directory, so a failed start leaves nothing behind; a batch larger than the training set is refused there too.

The budget.  A preset may cap the samples a run sees (`--train.max-samples`, e.g. the rig preset's 5.0M,
the Human3.6M cpu recipe's time on a project of any size).  The cap is a value like any other: a config
means what its fields say, whatever the command line that made it; `--train.max-samples 0` lifts it, so
that `--train.epochs N` trains N full epochs.

Compiled programs are cached on disk for the next run (`jaxpose.compilation_cache`;
JAXPOSE_COMPILATION_CACHE=off to disable).
"""

from __future__ import annotations

import dataclasses
import functools
import pathlib
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Literal

import jax
import tyro

from experiments import paper_tables
from jaxpose.training.run_directory import RunDirectory
from jaxpose.training.experiment import ExperimentConfig, recipe_summary
from jaxpose.training.runner import run
from jaxpose.training.splits import Splits
from jaxpose.formats.errors import DataFormatError

SUPERVISED_SUFFIX = "_supervised"


@dataclasses.dataclass(frozen=True)
class Experiment:
    """One entry point of `experiments/`: its presets, its data loader and its paper table.

    Each entry module defines one (`EXPERIMENT`) and runs it with `main`; `experiments.ablation` finds
    them by name in its registry.  The first preset is the default.
    """

    name: str
    """The module name under `experiments.` ("synthetic", "h36m", "humaneva")."""
    presets: Mapping[str, ExperimentConfig]
    """Complete configurations by name: `--preset NAME` picks one."""
    preset_notes: Mapping[str, str]
    """One line per preset for `--help`, saying what its config does not (what it is for, how long it takes);
    the recipe itself is listed from the config (`jaxpose.training.experiment.recipe_summary`)."""
    load_splits: Callable[..., Splits]
    """The data config -> train and test splits; with `loads_with_run_settings`, also given the
    keyword `progress` (--run.progress)."""
    loads_with_run_settings: bool = False
    """Whether loading prepares the data for the run: its progress bars."""
    expected_files: Callable[[Any], str] | None = None
    """Real data: the files a data config reads, for the message when one is missing or malformed."""
    paper_table: paper_tables.PaperTable | None = None
    """The paper's table this experiment fills in (written as table_paper_layout.md)."""

    @property
    def prog(self) -> str:
        return f"python -m experiments.{self.name}"

    @property
    def config_type(self) -> type:
        """`ExperimentConfig[<this experiment's data config>]`, the type tyro parses."""
        return ExperimentConfig[type(next(iter(self.presets.values())).data)]

    def loader(self, config: ExperimentConfig | None = None) -> Callable[[Any], Splits]:
        """`load_splits` for the run `config` (None: loading's own defaults); for real data, its data
        errors end the program with one message and exit status 1."""
        load_splits = self.load_splits
        if self.loads_with_run_settings and config is not None:
            load_splits = functools.partial(load_splits, progress=config.run.progress)
        if self.expected_files is None:
            return load_splits
        expected_files = self.expected_files

        def guarded_load(data) -> Splits:
            try:
                return load_splits(data)
            # ValueError: the loaders' argument checks (an unknown --data.detections, a bad stride).
            except (DataFormatError, ValueError) as error:
                raise SystemExit(f"error: {error}\n{expected_files(data)}") from None

        return guarded_load


def choose(argv: Sequence[str], flag: str, choices: Sequence[str], default: str, prog: str) -> tuple[str, list[str]]:
    """(the value of `flag` among `choices`, the other arguments): a selector read by tyro before the rest
    is parsed, because it decides what the rest means (which preset supplies the defaults, which
    experiment's flags apply); `--help` is left to the second parse."""
    name = flag.lstrip("-").replace("-", "_")
    selector = dataclasses.make_dataclass("Selector", [(name, Literal[tuple(choices)], default)], frozen=True)
    chosen, rest = tyro.cli(selector, args=list(argv), prog=prog, return_unknown_args=True, add_help=False)
    return getattr(chosen, name), rest


def parse(
    experiment: Experiment,
    argv: Sequence[str] | None,
    description: str,
    prog: str | None = None,
    presets: Mapping[str, ExperimentConfig] | None = None,
) -> ExperimentConfig:
    """`--preset NAME` plus tyro flags over that preset -> the config.

    `presets` replaces the experiment's own (`experiments.ablation` moves their run directories).  A
    full-supervision run (`--supervision full`) left on the preset's run directory gets its own
    directory, `<run_dir>_supervised`, so that it neither resumes nor overwrites the self-supervised run.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    presets = experiment.presets if presets is None else presets
    prog = experiment.prog if prog is None else prog
    default_preset = next(iter(presets))
    name, rest = choose(argv, "--preset", list(presets), default_preset, prog)
    width = max(len(name) for name in presets)
    listing = "\n".join(
        f"  {preset:<{width}}  {experiment.preset_notes[preset]} ({presets[preset].run.run_dir})\n  {'':<{width}}  {recipe_summary(presets[preset])}"
        for preset in presets
    )
    text = (
        f"{description.rstrip()}\n\nPresets (--preset NAME, default {default_preset}; the defaults shown"
        f" below are those of --preset {name}):\n{listing}"
    )
    usage_prog = f"{prog} [--preset {{{','.join(presets)}}}]"
    preset = presets[name]
    config = tyro.cli(experiment.config_type, default=preset, args=rest, description=text, prog=usage_prog)
    if config.loss.supervision == "full" and config.run.run_dir == preset.run.run_dir:
        supervised_dir = pathlib.Path(f"{preset.run.run_dir}{SUPERVISED_SUFFIX}")
        config = dataclasses.replace(config, run=dataclasses.replace(config.run, run_dir=supervised_dir))
    return config


def main(experiment: Experiment, argv: Sequence[str] | None, description: str) -> dict:
    """An entry point's whole command: parse, `jaxpose.training.runner.run`, then the paper-layout table
    (when the experiment has one) written into, and printed from, the run directory."""
    config = parse(experiment, argv, description)
    report = run(config, experiment.loader(config))
    if experiment.paper_table is not None and jax.process_index() == 0:
        path = paper_tables.write(experiment.paper_table, report["results"], RunDirectory(config.run.run_dir))
        print(path.read_text())
    return report
