"""The run directory: the one place that knows a run folder's files (`RunDirectory`), the config a resume
must continue (config.json), the metric log (metrics.jsonl, TensorBoard), and the rule that a run folder is
only ever a run folder.

A run folder is marked at creation by its record, `run.json`.  A folder that holds anything a run did not
write (a project, a thesis) is refused before anything is written, with or without --run.overwrite, and
--run.overwrite removes only the entries a run writes (`RUN_ENTRIES`), never a nested run.  A study of
experiments/ writes its summary into a folder of its own, never into a run's (`write_study_file`).  A run
folder written before the record existed is recognised by its entries.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import pathlib
import shutil
import sys
import time
import typing
from collections.abc import Callable, Iterator, Mapping, Sequence
from typing import Any, TypeVar

import jax
import tyro

from jaxpose.formats.files import from_typed_json, typed_json
from jaxpose.formats.outputs import atomic_output, exclusive_folder
from jaxpose.model import ModelConfig
from jaxpose.rig.config import RigProjectConfig
from jaxpose.skeleton import get_skeleton
from jaxpose.training.checkpoint import LifterRecord
from jaxpose.training.experiment import ExperimentConfig, TrainConfig, dumps, to_json_dict

log = logging.getLogger("jaxpose")

T = TypeVar("T")


LOCK_FILE = "run.lock"
RECORD_FILE = "run.json"
RECOVERED_CAMERAS_FILE = "recovered_cameras.json"
RECOVERED_TOML_FILE = "recovered_cameras.toml"
RECOVERED_SESSIONS_DIR = "recovered_sessions"
PAPER_TABLE_FILE = "table_paper_layout.md"


@dataclasses.dataclass(frozen=True)
class RunDirectory:
    """The files of one run folder, by name: every module reads and writes them through this."""

    path: pathlib.Path

    @classmethod
    def of(cls, path: pathlib.Path) -> "RunDirectory":
        """The run whose folder, or whose checkpoints/ folder, `path` names (as the commands that use a run take it)."""
        path = pathlib.Path(path)
        return cls(path.parent if path.name == "checkpoints" and not (path / "checkpoints").is_dir() else path)

    @property
    def record(self) -> pathlib.Path:
        """run.json: the marker written at creation (`mark`)."""
        return self.path / RECORD_FILE

    @property
    def config(self) -> pathlib.Path:
        return self.path / "config.json"

    @property
    def metrics(self) -> pathlib.Path:
        return self.path / "metrics.jsonl"

    @property
    def checkpoints(self) -> pathlib.Path:
        return self.path / "checkpoints"

    @property
    def tensorboard(self) -> pathlib.Path:
        return self.path / "tensorboard"

    @property
    def report_json(self) -> pathlib.Path:
        return self.path / "report.json"

    @property
    def report_md(self) -> pathlib.Path:
        return self.path / "report.md"

    @property
    def recovered_cameras(self) -> pathlib.Path:
        """The rig recovered from the recordings (a jaxpose camera file), where the project had no calibration."""
        return self.path / RECOVERED_CAMERAS_FILE

    @property
    def recovered_toml(self) -> pathlib.Path:
        """The same rig as a Pose2Sim/Anipose calibration TOML (metres), for the other tools."""
        return self.path / RECOVERED_TOML_FILE

    @staticmethod
    def recovered_rig_files(sessions: Sequence[str]) -> dict[str, str]:
        """Where a run keeps the rigs recovered for `sessions` (`RunRecord.recovered_rigs`), by session: one
        session's as recovered_cameras.json, several as recovered_sessions/SESSION.json (paths in the run folder)."""
        if len(sessions) == 1:
            return {sessions[0]: RECOVERED_CAMERAS_FILE}
        return {session: f"{RECOVERED_SESSIONS_DIR}/{session}.json" for session in sessions}

    def recovered_rigs(self, record: RunRecord | None) -> dict[str, pathlib.Path]:
        """The run's recovered rigs by session (jaxpose camera files; the TOML beside each), as its record lists
        them; for a run from before the record listed them, the ones its folder holds."""
        if record is not None and record.recovered_rigs is not None:
            return {session: self.path / name for session, name in record.recovered_rigs.items()}
        if self.recovered_cameras.is_file():
            return {"": self.recovered_cameras}
        return {path.stem: path for path in sorted((self.path / RECOVERED_SESSIONS_DIR).glob("*.json"))}

    def session_of(self, calibration: pathlib.Path) -> str | None:
        """The session whose recovered rig `calibration` is (recovered_sessions/SESSION.json or .toml), or None."""
        folder = (self.path / RECOVERED_SESSIONS_DIR).resolve()
        calibration = calibration.resolve()
        return calibration.stem if calibration.parent == folder and calibration.suffix in (".json", ".toml") else None

    @property
    def paper_table(self) -> pathlib.Path:
        """The report's results in the paper's table layout (`experiments.paper_tables`), for the experiments of one."""
        return self.path / PAPER_TABLE_FILE

    @property
    def plots(self) -> pathlib.Path:
        return self.path / "plots"

    def plot(self, name: str) -> pathlib.Path:
        return self.plots / name


@dataclasses.dataclass(frozen=True)
class RunRecord:
    """What a run was trained on, kept in run.json: the one record of it.  The commands that use the run
    (`jaxpose.predict`, `reconstruct`, `export`) take their defaults from it (`parse_over_run`), each applying
    them unless overridden and saying in one line where an override differs.  config.json holds the settings as
    they were given, which a resume must continue (`check_resumable`); each checkpoint repeats the network
    (`lifter`, derived from this record) because a step must restore alone."""

    project: RigProjectConfig | None = None
    """A rig project's settings (`jaxpose.rig.config.recorded_settings`: sync, frame offsets, calibration and
    its unit, score threshold, the detector layout as `skeleton`, ..., the paths resolved; its recordings and
    split left at their defaults); None for the other data sets."""
    sessions: Mapping[str, Sequence[str]] | None = None
    """A rig project of several sessions without a calibration: each session's recordings, by session name;
    None otherwise."""
    recovered_rigs: Mapping[str, str] | None = None
    """The rigs recovered from the recordings of a project without a calibration, stored with the run as its
    assets (`RunDirectory.recovered_rig_files`): by session, the jaxpose camera file's path in the run folder,
    the Pose2Sim/Anipose TOML beside it with the suffix .toml.  Empty for a calibrated project; None for the
    other data sets or a run from before the record listed them (`RunDirectory.recovered_rigs` finds them)."""
    skeleton: str | None = None
    """The joints the lifter lifts (a `jaxpose.skeleton` name); None for a run from before the record held it."""
    model: ModelConfig | None = None
    """The lifter's network; None for a run from before the record held it."""

    @property
    def min_confidence(self) -> float | None:
        """Keypoints scored below this were missing in training: the rig project's --data.min-confidence (None:
        the data set's 2D taken as given)."""
        return None if self.project is None else self.project.min_confidence

    def lifter(self) -> LifterRecord:
        """The network, as each checkpoint repeats it (its `lifter` item)."""
        return LifterRecord(get_skeleton(self.skeleton), self.model)


def write_record(run: RunDirectory, record: RunRecord) -> None:
    """Add `record` to the run's run.json (atomically: a failed write keeps the marker as it was)."""
    path = run.record
    content = json.loads(path.read_text()) if path.exists() else {"jaxpose_run": 1}
    content["trained_on"] = typed_json(record)
    with atomic_output(path) as temporary:
        temporary.write_text(json.dumps(content, indent=1, default=str) + "\n")  # default: the paths as text


def read_record(run: RunDirectory) -> RunRecord | None:
    """The record of the run, or None for a run written before records existed."""
    path = run.record
    if not path.is_file():
        return None
    try:
        fields = json.loads(path.read_text()).get("trained_on")
        return None if fields is None else from_typed_json(RunRecord, fields)  # a record of before the codec reads so too
    except (ValueError, TypeError, AttributeError) as error:
        raise ValueError(f"{path}: not a run record jaxpose wrote ({error})") from None


def parse_over_run(
    args_type: type[T], argv: Sequence[str] | None, run_defaults: Callable[[RunRecord | None], Mapping[str, Any]],
    description: str, prog: str, run_field: str = "checkpoint",
) -> tuple[T, RunDirectory | None, RunRecord | None]:
    """The command line of a command that uses a run (`jaxpose.predict`, `export`, `reconstruct`): the run it
    names (its `run_field`: --checkpoint RUN, or export's positional RUN_DIR) is read before the command line is
    parsed, and `run_defaults(record)` (field name: value, from the run's record; None for a run from before
    records) are the command's defaults, so `--help` shows the values that will be used and every flag given
    wins, also one given at the command's own default.  Returns (the arguments, the run's `RunDirectory`,
    built once here for the whole command, its record); (args, None, None) where the command line names no run."""
    argv = list(sys.argv[1:] if argv is None else argv)
    named = _named_run(argv, args_type, run_field)
    run = None if named is None else RunDirectory.of(pathlib.Path(named))
    try:
        record = None if run is None else read_record(run)
    except ValueError as error:
        raise SystemExit(f"{prog}: error: {error}") from None
    required = {
        field.name: tyro.MISSING for field in dataclasses.fields(args_type)
        if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING
    }  # fmt: skip
    default = args_type(**(required | dict(run_defaults(record))))
    return tyro.cli(args_type, default=default, args=argv, description=description, prog=prog), run, record


def _named_run(argv: Sequence[str], args_type: type, field: str) -> str | None:
    """The value `argv` gives the field `field` of `args_type`: its flag's (--checkpoint RUN or --checkpoint=RUN,
    the last one given, as the parser takes it), else the first positional argument (every flag but a bool's
    takes one value)."""
    flag = "--" + field.replace("_", "-")
    given = [
        argument.split("=", 1)[1] if argument.startswith(flag + "=") else argv[index + 1]
        for index, argument in enumerate(argv)
        if argument.startswith(flag + "=") or (argument == flag and index + 1 < len(argv))
    ]  # fmt: skip
    if given:
        return given[-1]
    hints = typing.get_type_hints(args_type)
    takes_value = {"--" + name.replace("_", "-") for name, hint in hints.items() if hint is not bool}
    expects_value = False
    for argument in argv:
        if argument.startswith("-"):
            expects_value = argument in takes_value
        elif expects_value:
            expects_value = False
        else:
            return argument
    return None


# What a run writes into its folder, and what --run.overwrite may remove.
RUN_ENTRIES = frozenset({RECORD_FILE, LOCK_FILE, "config.json", "metrics.jsonl", "checkpoints", "tensorboard", "report.json", "report.md", "plots", PAPER_TABLE_FILE, RECOVERED_CAMERAS_FILE, RECOVERED_TOML_FILE, RECOVERED_SESSIONS_DIR})


def check_study_folder(folder: pathlib.Path) -> None:
    """Refuse a run folder as a study's folder (`write_study_file`): called by a study before it trains anything."""
    if (folder / RECORD_FILE).is_file() or ((folder / "config.json").is_file() and (folder / "checkpoints").is_dir()):
        raise SystemExit(f"{folder}: is a run folder, which holds only its run; give the study a folder of its own (its --run.run-dir)")


def write_study_file(folder: pathlib.Path, name: str, text: str) -> pathlib.Path:
    """Write a study's summary (experiments/: comparison.md, search.md, ...) into the study's own folder, the one
    that holds the runs it trained, each in a sub-folder: never into a run folder, which only the training that
    owns it writes (through `RunDirectory`).  Atomic; rewritten as the study goes on."""
    check_study_folder(folder)
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_output(folder / name) as temporary:
        temporary.write_text(text)
    return folder / name


def _written_by_jaxpose(entry: pathlib.Path) -> bool:
    """A nested run (its record, or a pre-record run's config and checkpoints), or a folder of nothing but such runs."""
    if not entry.is_dir() or entry.is_symlink():
        return False
    if (entry / RECORD_FILE).is_file() or ((entry / "config.json").is_file() and (entry / "checkpoints").is_dir()):
        return True
    children = list(entry.iterdir())
    return bool(children) and all(_written_by_jaxpose(child) for child in children)


def foreign_entries(run_dir: pathlib.Path) -> list[str]:
    """The names in `run_dir` that no jaxpose run wrote (none where it does not exist)."""
    if not run_dir.is_dir():
        return []
    return sorted(
        entry.name for entry in run_dir.iterdir()
        if entry.name not in RUN_ENTRIES and not _written_by_jaxpose(entry)
    )  # fmt: skip


def check_run_folder(run_dir: pathlib.Path) -> None:
    """Refuse, before anything is written, a --run.run-dir that is a file or holds what a run did not write."""
    if run_dir.exists() and not run_dir.is_dir():
        raise SystemExit(f"--run.run-dir {run_dir}: is a file, not a folder; choose a new or empty folder")
    foreign = foreign_entries(run_dir)
    if foreign:
        shown = ", ".join(foreign[:4]) + (f" and {len(foreign) - 4} more" if len(foreign) > 4 else "")
        raise SystemExit(
            f"--run.run-dir {run_dir}: holds {len(foreign)} entr{'y' if len(foreign) == 1 else 'ies'} that no jaxpose run wrote"
            f" ({shown}); a run folder holds only a run, so nothing was changed: choose a new or empty folder"
        )

# Fields that must match for a run directory to be resumed (the rest may change between attempts).
_RESUME_KEYS = ("data", "model", "loss", "optimizer", "pseudo_labels")
_RESUME_TRAIN_KEYS = ("batch_size", "epochs", "max_samples", "seed")
# A config.json written before a field existed holds its default (max_samples: no cap).
_TRAIN_DEFAULTS = to_json_dict(TrainConfig())


def _identity(config_json: dict) -> dict:
    identity = {key: config_json.get(key) for key in _RESUME_KEYS}
    train = config_json.get("train", {})
    identity["train"] = {key: train.get(key, _TRAIN_DEFAULTS[key]) for key in _RESUME_TRAIN_KEYS}
    return identity


def holds_a_run(files: RunDirectory) -> bool:
    """Whether run_dir holds something a different config must not take over: a committed checkpoint
    (Orbax names them by step) or a finished run's report.  A start that failed before its first
    checkpoint (a batch larger than the data, a crash while compiling) left nothing to resume."""
    committed = files.checkpoints.is_dir() and any(entry.name.isdigit() for entry in files.checkpoints.iterdir())
    return committed or files.report_json.exists()


def check_resumable(config: ExperimentConfig) -> RunDirectory:
    """Fail early (before any data are loaded) if run_dir is not a run folder, or holds a run of a different
    config; returns its `RunDirectory`."""
    check_run_folder(config.run.run_dir)
    files = RunDirectory(config.run.run_dir)
    config_path = files.config
    if config.run.overwrite or not config_path.exists() or not holds_a_run(files):
        return files
    if _identity(json.loads(config_path.read_text())) != _identity(to_json_dict(config)):
        raise SystemExit(
            f"{config.run.run_dir} holds a run with a different config ({config_path}); resume it with the same"
            " settings, pick another --run.run-dir, or pass --run.overwrite to start over."
        )
    return files


@contextlib.contextmanager
def exclusive(run_dir: pathlib.Path) -> Iterator[None]:
    """Hold the run directory for one run: a second run started on it stops at once, naming the first
    (`exclusive_folder`, on `run_dir/run.lock`).  A directory made only to hold the lock is removed again if
    the run ends before writing anything (a data file that fails to load leaves no run directory behind)."""
    if jax.process_index() != 0:  # one lock per run: process 0 writes the directory
        yield
        return
    with exclusive_folder(run_dir, LOCK_FILE, "--run.run-dir", "run"):
        yield


def prepare_run_dir(config: ExperimentConfig) -> RunDirectory:
    """Create (or check, for a resume) the run directory, mark it, and write config.json.  Returns its
    `RunDirectory`, which the run passes on to everything that writes or reads its files."""
    files = check_resumable(config)
    run_dir = files.path
    if config.run.overwrite and run_dir.exists() and jax.process_index() == 0:
        for entry in run_dir.iterdir():  # what a run wrote, but the lock this run holds
            if entry.name in RUN_ENTRIES and entry.name != LOCK_FILE:
                shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
    run_dir.mkdir(parents=True, exist_ok=True)
    files.plots.mkdir(exist_ok=True)
    if jax.process_index() == 0:
        if not files.record.exists():
            files.record.write_text(json.dumps({"jaxpose_run": 1, "created": time.strftime("%Y-%m-%d %H:%M:%S")}, indent=1) + "\n")
        files.config.write_text(dumps(config))
    return files


def _append_jsonl(path: pathlib.Path, record: dict) -> None:
    if jax.process_index() == 0:
        with path.open("a") as f:
            f.write(json.dumps(record) + "\n")


def _truncate_log(path: pathlib.Path, step: int) -> None:
    """Drop log lines past `step`: a resumed run replays those steps and logs them again."""
    if jax.process_index() != 0 or not path.exists():
        return
    kept = [record for record in read_jsonl(path) if record["step"] <= step]
    path.write_text("".join(json.dumps(record) + "\n" for record in kept))


class RunLog:
    """The run's metric lines: appended to metrics.jsonl and, where tensorboardX is installed, written
    as TensorBoard scalars (`<group>/<name>`) to <run_dir>/tensorboard.  Process 0 writes."""

    def __init__(self, run: RunDirectory, start_step: int, tensorboard: bool):
        self.path = run.metrics
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
        self.writer = SummaryWriter(str(run.tensorboard), purge_step=start_step or None, flush_secs=5)

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


def read_jsonl(path: pathlib.Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
