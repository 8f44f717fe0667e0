"""The command line shared by the experiment entry points (`experiments.synthetic`, `h36m`, `humaneva`).

Presets.  Each entry point defines complete `ExperimentConfig`s by name (`PRESETS`).  `--preset NAME`
picks one (default: the first, "main" for synthetic and "cpu" for the real data sets); every other
flag overrides a field of it, and `--help` lists every flag with the chosen preset's values as
defaults:

    python -m experiments.h36m --preset paper --data.data-dir /data/h36m --train.epochs 100
    python -m experiments.h36m --preset paper --help

A preset flag rather than tyro subcommands: with subcommands, the flags would have to follow the
subcommand name and the top-level `--help` would not list them.

Data errors.  A missing or malformed data file ends the program with one message (what was expected
where, what was found, the files this run reads, and the README section "Getting the data") and a
non-zero exit status, not a traceback.  The runner loads the data before it creates the run
directory, so a failed start leaves nothing behind.
"""

from __future__ import annotations

import argparse
import dataclasses
import pathlib
import sys
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import jax
import tyro

from experiments import paper_tables
from experiments.config import ExperimentConfig
from experiments.runner import Splits, run
from jaxpose.data.errors import DataFormatError

SUPERVISED_SUFFIX = "_supervised"


def parse(
    config_type: type,
    presets: Mapping[str, ExperimentConfig],
    preset_notes: Mapping[str, str],
    argv: Sequence[str] | None,
    description: str,
    prog: str,
) -> ExperimentConfig:
    """`--preset NAME` plus tyro flags over that preset -> the config.

    A full-supervision run (`--supervision full`) left on the preset's run directory gets its own
    directory, `<run_dir>_supervised`, so that it neither resumes nor overwrites the self-supervised run.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    chooser = argparse.ArgumentParser(prog=prog, add_help=False, allow_abbrev=False)
    default_preset = next(iter(presets))
    chooser.add_argument("--preset", choices=list(presets), default=default_preset)
    chosen, rest = chooser.parse_known_args(argv)
    width = max(len(name) for name in presets)
    listing = "\n".join(f"  {name:<{width}}  {preset_notes[name]}" for name in presets)
    text = (
        f"{description.rstrip()}\n\nPresets (--preset NAME, default {default_preset}; the defaults shown"
        f" below are those of --preset {chosen.preset}):\n{listing}"
    )
    usage_prog = f"{prog} [--preset {{{','.join(presets)}}}]"
    preset = presets[chosen.preset]
    config = tyro.cli(config_type, default=preset, args=rest, description=text, prog=usage_prog)
    if config.loss.supervision == "full" and config.run.run_dir == preset.run.run_dir:
        supervised_dir = pathlib.Path(f"{preset.run.run_dir}{SUPERVISED_SUFFIX}")
        config = dataclasses.replace(config, run=dataclasses.replace(config.run, run_dir=supervised_dir))
    return config


def guard_data_errors(load_splits: Callable[[Any], Splits], expected_files: Callable[[Any], str]) -> Callable[[Any], Splits]:
    """`load_splits` whose data errors end the program with one message and exit status 1."""

    def guarded_load(data) -> Splits:
        try:
            return load_splits(data)
        # ValueError: the loaders' argument checks (an unknown --data.detections, a bad stride).
        except (DataFormatError, ValueError) as error:
            raise SystemExit(f"error: {error}\n{expected_files(data)}") from None

    return guarded_load


def run_experiment(
    config: ExperimentConfig,
    load_splits: Callable[[Any], Splits],
    expected_files: Callable[[Any], str],
    table: paper_tables.PaperTable,
) -> dict:
    """`experiments.runner.run` with data errors as one message (`guard_data_errors`), then the
    paper-layout table written into (and printed from) the run directory."""
    report = run(config, guard_data_errors(load_splits, expected_files))
    if jax.process_index() == 0:
        path = paper_tables.write(table, report["results"], config.run.run_dir)
        print(path.read_text())
    return report
