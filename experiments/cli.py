"""The command line shared by the real-data entry points (`experiments.h36m`, `experiments.humaneva`).

Presets.  Each entry point defines complete `ExperimentConfig`s by name (`PRESETS`).  `--preset NAME`
picks one (default "cpu"); every other flag overrides a field of it, and `--help` lists every flag
with the chosen preset's values as defaults:

    python -m experiments.h36m --preset paper --data.data-dir /data/h36m --train.epochs 100
    python -m experiments.h36m --preset paper --help

A preset flag rather than tyro subcommands: with subcommands, the flags would have to follow the
subcommand name and the top-level `--help` would not list them.

Data errors.  A missing or malformed data file ends the program with one message (what was expected
where, what was found, the files this run reads, and the README section "Getting the data") and a
non-zero exit status, not a traceback.  A run directory that this failed start created is removed
again, so that a corrected command does not trip over the config it recorded.
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

DEFAULT_PRESET = "cpu"
SUPERVISED_SUFFIX = "_supervised"


class _DataUnavailable(Exception):
    """Raised by the guarded loader: the data could not be loaded (message ready to print)."""


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
    chooser.add_argument("--preset", choices=list(presets), default=DEFAULT_PRESET)
    chosen, rest = chooser.parse_known_args(argv)
    width = max(len(name) for name in presets)
    listing = "\n".join(f"  {name:<{width}}  {preset_notes[name]}" for name in presets)
    text = (
        f"{description.rstrip()}\n\nPresets (--preset NAME, default {DEFAULT_PRESET}; the defaults shown"
        f" below are those of --preset {chosen.preset}):\n{listing}"
    )
    usage_prog = f"{prog} [--preset {{{','.join(presets)}}}]"
    preset = presets[chosen.preset]
    config = tyro.cli(config_type, default=preset, args=rest, description=text, prog=usage_prog)
    if config.loss.supervision == "full" and config.run.run_dir == preset.run.run_dir:
        supervised_dir = pathlib.Path(f"{preset.run.run_dir}{SUPERVISED_SUFFIX}")
        config = dataclasses.replace(config, run=dataclasses.replace(config.run, run_dir=supervised_dir))
    return config


def run_experiment(
    config: ExperimentConfig,
    load_splits: Callable[[Any], Splits],
    expected_files: Callable[[Any], str],
    table: paper_tables.PaperTable,
) -> dict:
    """`experiments.runner.run`, with data errors turned into one message and exit status 1, then
    the paper-layout table written into (and printed from) the run directory."""

    def guarded_load(data) -> Splits:
        try:
            return load_splits(data)
        # ValueError: the loaders' argument checks (an unknown --data.detections, a bad stride).
        except (DataFormatError, ValueError) as error:
            raise _DataUnavailable(f"error: {error}\n{expected_files(data)}") from None

    run_dir = config.run.run_dir
    # The outermost folder this start will create (run_dir itself, or a missing parent such as runs/).
    created = next((p for p in reversed([run_dir, *run_dir.parents]) if not p.exists()), None)
    try:
        report = run(config, guarded_load)
    except _DataUnavailable as stop:
        if created is not None:
            _remove_unstarted_run(run_dir, created)
        raise SystemExit(str(stop)) from None
    if jax.process_index() == 0:
        path = paper_tables.write(table, report["results"], run_dir)
        print(path.read_text())
    return report


def _remove_unstarted_run(run_dir: pathlib.Path, created: pathlib.Path) -> None:
    """Undo what the runner wrote before loading the data: config.json and the folders from `created`
    down to run_dir/plots, as long as they are empty (nothing else is ever deleted)."""
    if (run_dir / "checkpoints").exists():  # cannot happen before training, but never delete a run
        return
    (run_dir / "config.json").unlink(missing_ok=True)
    folders = [run_dir / "plots", run_dir, *run_dir.parents]
    for folder in folders[: folders.index(created) + 1]:
        if not folder.is_dir() or any(folder.iterdir()):
            return
        folder.rmdir()
