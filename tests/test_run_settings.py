"""Issue 52: a run's settings are the defaults of the commands that use it (`jaxpose.reconstruct`,
`jaxpose.predict`): every flag given wins, also one given at the command's own default; `--help` shows the
value that will be used; a given value that differs from the run's is said in one line.  And a run names its
project by an absolute, resolved path (defects 6, 7)."""

import dataclasses
import json
import pathlib
import re

import pytest

from experiments import rig as rig_job
from jaxpose import export, predict, reconstruct
from jaxpose.model import ModelConfig
from jaxpose.rig.config import RigProjectConfig, recorded_settings
from jaxpose.synthetic.project import ExampleProjectConfig, write_rig_project
from jaxpose.training.run_directory import RunDirectory, RunRecord, read_record, write_record

TRAINED = dict(min_confidence=0.3, sync="auto", max_sync_offset=4, frame_offsets=("cam02=3",), calibration_unit="m")


@pytest.fixture()
def run_dir(tmp_path):
    """A run folder whose record says it was trained with --data.min-confidence 0.3 --data.sync auto (and more)."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text('{"jaxpose_run": 1}\n')
    trained = RigProjectConfig(root=tmp_path / "project", calibration=tmp_path / "rig.toml", **TRAINED)
    write_record(RunDirectory(run), RunRecord(project=recorded_settings(trained, "coco17")))
    return run


def _reconstruct_args(run_dir, *flags):
    return reconstruct.parse(["--checkpoint", str(run_dir), "--output", str(run_dir.parent / "motion"), "--fps", "50", *flags])


def _help_default(help_text: str, flag: str) -> str:
    """The "(default: X)" of `flag`'s entry in tyro's help."""
    lines = [re.sub("[│╭╮╰╯─]", " ", line).strip() for line in help_text.splitlines()]
    first = next(i for i, line in enumerate(lines) if re.match(rf"{re.escape(flag)}( |$)", line))
    entry = [lines[first]]
    for line in lines[first + 1 :]:
        if not line or line.startswith("-"):
            break
        entry.append(line)
    return re.search(r"\(default: ([^)]*)\)", " ".join(entry)).group(1)


def test_reconstruct_flags_given_at_their_default_win_over_the_run(run_dir, capsys):
    """Defect 2: --data.min-confidence 0.1 and --data.sync given (the command's own defaults) were replaced by the
    run's 0.3 and auto without a word."""
    args = _reconstruct_args(run_dir, "--data.min-confidence", "0.1", "--data.sync", "given")
    assert args.data.min_confidence == 0.1 and args.data.sync == "given"
    assert args.data.max_sync_offset == 4 and args.data.frame_offsets == ("cam02=3",)  # the others: the run's
    err = capsys.readouterr().err.splitlines()
    assert "--data.min-confidence 0.1 given; the run was trained with 0.3" in err
    assert "--data.sync given given; the run was trained with auto" in err
    assert len([line for line in err if "the run was trained with" in line]) == 2


def test_reconstruct_flags_at_another_value_win_and_flags_not_given_are_the_runs(run_dir, tmp_path, capsys):
    args = _reconstruct_args(run_dir, "--data.min-confidence", "0.5")
    assert args.data.min_confidence == 0.5
    assert "--data.min-confidence 0.5 given; the run was trained with 0.3" in capsys.readouterr().err
    args = _reconstruct_args(run_dir)
    expected = RigProjectConfig(root=tmp_path / "project", calibration=tmp_path / "rig.toml", skeleton="coco17", **TRAINED)
    assert args.data == expected.resolved()
    assert "the run was trained with" not in capsys.readouterr().err


def test_reconstruct_help_shows_the_runs_values(run_dir, capsys):
    with pytest.raises(SystemExit) as stop:
        reconstruct.parse(["--checkpoint", str(run_dir), "--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert _help_default(text, "--data.min-confidence") == "0.3"
    assert _help_default(text, "--data.sync") == "auto"
    assert _help_default(text, "--data.max-sync-offset") == "4"


def test_reconstruct_of_a_run_without_a_record_takes_the_flags_as_given(tmp_path, capsys):
    run = tmp_path / "old_run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.json").write_text("{}")
    args = _reconstruct_args(run, "--data.root", str(tmp_path / "p"))
    assert args.data == RigProjectConfig(root=tmp_path / "p").resolved()
    assert "records no project settings" in capsys.readouterr().err


@pytest.fixture()
def predict_run(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text('{"jaxpose_run": 1}\n')
    write_record(RunDirectory(run), RunRecord(project=recorded_settings(RigProjectConfig(root=tmp_path / "project", min_confidence=0.2), "coco17")))
    return run


def _predict_args(run, *flags):
    argv = ["--checkpoint", str(run), "--input", "in.json", "--output", "out.json", *flags]
    args, run_dir, _ = predict.inference.parse_with_run(predict.PredictArgs, argv, predict.__doc__, "python -m jaxpose.predict")
    assert run_dir == RunDirectory.of(run)  # built once, from the command line, for the command
    return args


def test_predict_min_confidence_given_default_other_or_not(predict_run, capsys):
    """The same mechanism for predict: given at its own default (0.05), given at another value, not given."""
    assert _predict_args(predict_run, "--min-confidence", "0.05").min_confidence == 0.05
    assert "--min-confidence 0.05 given; the run was trained with 0.2" in capsys.readouterr().err
    assert _predict_args(predict_run, "--min-confidence", "0.4").min_confidence == 0.4
    assert "--min-confidence 0.4 given; the run was trained with 0.2" in capsys.readouterr().err
    assert _predict_args(predict_run).min_confidence == 0.2
    assert "trained with" not in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        _predict_args(predict_run, "--help")
    assert stop.value.code == 0
    assert _help_default(capsys.readouterr().out, "--min-confidence") == "0.2"


def _export_args(run, *flags):
    """export's command line of `flags`, with its positional RUN_DIR where "RUN" stands (else first)."""
    argv = [str(run) if flag == "RUN" else flag for flag in flags] if "RUN" in flags else [str(run), *flags]
    args, run_dir, _ = predict.inference.parse_with_run(export.ExportArgs, argv, export.__doc__, "python -m jaxpose.export", run_field="run_dir")
    assert run_dir == RunDirectory.of(run)
    return args


def test_export_min_confidence_given_default_other_or_not(predict_run, capsys):
    """The same mechanism for export, whose run is its positional RUN_DIR: it took None for "from the run" and
    its --help showed no value.  The run is found wherever it stands among the flags."""
    assert _export_args(predict_run, "--min-confidence", "0.05", "RUN").min_confidence == 0.05
    assert "--min-confidence 0.05 given; the run was trained with 0.2" in capsys.readouterr().err
    assert _export_args(predict_run, "--output", "x.onnx", "RUN", "--min-confidence", "0.4").min_confidence == 0.4
    assert "--min-confidence 0.4 given; the run was trained with 0.2" in capsys.readouterr().err
    assert _export_args(predict_run, "--flip", "RUN", "--output=x.onnx").min_confidence == 0.2
    assert _export_args(predict_run / "checkpoints").min_confidence == 0.2
    assert "trained with" not in capsys.readouterr().err
    with pytest.raises(SystemExit) as stop:
        export.main([str(predict_run), "--help"])
    assert stop.value.code == 0
    assert _help_default(capsys.readouterr().out, "--min-confidence") == "0.2"


def test_predict_of_a_run_without_a_record_uses_the_default_threshold(tmp_path):
    run = tmp_path / "old_run"
    (run / "checkpoints").mkdir(parents=True)
    assert _predict_args(run).min_confidence == predict.inference.DEFAULT_MIN_CONFIDENCE
    assert _export_args(run).min_confidence == predict.inference.DEFAULT_MIN_CONFIDENCE


def test_a_run_records_its_project_by_an_absolute_resolved_path(tmp_path, monkeypatch):
    """Defect 6: `--data.root project` was recorded as typed, so a reconstruct from another working directory
    read whatever project sat at that relative path there."""
    (tmp_path / "a" / "b").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "a" / "b")
    recorded = recorded_settings(RigProjectConfig(root=pathlib.Path("../project"), cache_dir=pathlib.Path("cache")), "coco17")
    assert recorded.root == tmp_path.resolve() / "a" / "project"
    assert recorded.cache_dir == tmp_path.resolve() / "a" / "b" / "cache"
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text('{"jaxpose_run": 1}\n')
    write_record(RunDirectory(run), RunRecord(project=recorded))
    monkeypatch.chdir(tmp_path)  # elsewhere: the same project
    args = _reconstruct_args(run.resolve())
    assert args.data.root == tmp_path.resolve() / "a" / "project"
    args = _reconstruct_args(run.resolve(), "--data.root", "a/project")  # named relatively: the same, said nothing
    assert args.data.root == tmp_path.resolve() / "a" / "project"


def test_an_old_run_record_still_loads(tmp_path):
    """A run.json written before the record was typed (its project a plain JSON object, a relative root) reads
    back as the typed record; the typed one round-trips."""
    run = tmp_path / "run"
    run.mkdir()
    project = {"root": "project", "calibration": None, "sync": "auto", "frame_offsets": ["cam02=3"], "skeleton": "coco17",
               "image_size": [1920, 1080], "min_confidence": 0.2}  # fmt: skip
    (run / "run.json").write_text(json.dumps({"jaxpose_run": 1, "trained_on": {"min_confidence": 0.2, "layout": "coco17", "project": project}}))
    record = read_record(RunDirectory.of(run / "checkpoints"))
    assert record.min_confidence == 0.2 and record == RunRecord(project=RigProjectConfig(
        root=pathlib.Path("project"), sync="auto", frame_offsets=("cam02=3",), skeleton="coco17", image_size=(1920, 1080), min_confidence=0.2
    ))  # fmt: skip
    typed = RunRecord(project=recorded_settings(RigProjectConfig(root=tmp_path, **TRAINED), "coco17"), skeleton="h36m17", model=ModelConfig(width=64),
                      recovered_rigs={"a": "recovered_sessions/a.json"},
                      sessions={"a": ["walking01"]})  # fmt: skip
    write_record(RunDirectory(run), typed)
    assert read_record(RunDirectory(run)) == typed
    assert json.loads((run / "run.json").read_text())["jaxpose_run"] == 1  # the marker kept


@pytest.mark.trains  # the shared synthetic run (tests/conftest.py)
def test_the_run_record_is_the_one_owner_of_the_network_the_checkpoints_repeat(trained_run):
    """Issue 52: what a run was trained on was written three times; run.json's record now holds the network too,
    and every checkpoint's `lifter` item is derived from it (a step must restore alone)."""
    from jaxpose.serving import inference
    from jaxpose.training import checkpoint

    run = RunDirectory(trained_run[0])
    record = read_record(run)
    restored = checkpoint.restore_lifter(run.checkpoints, inference.jax.sharding.SingleDeviceSharding(inference.jax.devices()[0]))
    assert record.skeleton == "h36m17" and record.lifter() == restored[1]
    assert record.model == ModelConfig(**json.loads(run.config.read_text())["model"])


def test_recovered_rigs_are_the_runs_assets_listed_by_its_record(tmp_path):
    """Issue 52: the recovered rig is stored with the run as an asset its record names; reconstruct reads it
    through the record (a run from before the record listed them: the files its folder holds)."""
    run = RunDirectory(tmp_path / "run")
    assert RunDirectory.recovered_rig_files(["s"]) == {"s": "recovered_cameras.json"}
    assert RunDirectory.recovered_rig_files(["a", "b"]) == {"a": "recovered_sessions/a.json", "b": "recovered_sessions/b.json"}
    record = RunRecord(recovered_rigs=RunDirectory.recovered_rig_files(["a", "b"]))
    assert run.recovered_rigs(record) == {"a": run.path / "recovered_sessions" / "a.json", "b": run.path / "recovered_sessions" / "b.json"}
    assert run.recovered_rigs(RunRecord()) == {}  # a calibrated project's run, from before the list: none found
    (run.path / "recovered_sessions").mkdir(parents=True)
    for name in ("b", "a"):
        (run.path / "recovered_sessions" / f"{name}.json").write_text("{}")
    assert run.recovered_rigs(None) == run.recovered_rigs(record)  # a run from before the list: the files it holds
    assert run.recovered_rigs(RunRecord(recovered_rigs={})) == {}  # a calibrated project's run: the record says none


def test_a_sessions_rig_limits_reconstruct_to_that_sessions_recordings(tmp_path, capsys):
    """Defect 3: after a run of two sessions (a = walking01, b = turning02), --data.calibration
    RUN/recovered_sessions/a.toml wrote turning02 in session a's world."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text('{"jaxpose_run": 1}\n')
    settings = recorded_settings(RigProjectConfig(root=tmp_path / "project"), "coco17")
    write_record(RunDirectory(run), RunRecord(project=settings, sessions={"a": ["walking01"], "b": ["turning02"]}))
    assert read_record(RunDirectory(run)).sessions == {"a": ["walking01"], "b": ["turning02"]}
    rig = str(run / "recovered_sessions" / "a.toml")
    assert _reconstruct_args(run, "--data.calibration", rig).data.recordings == ("walking01",)
    assert "the rig of session a: its recordings only (walking01)" in capsys.readouterr().err
    with pytest.raises(SystemExit, match=r"is the rig of session a \(recordings walking01\), not of turning02"):
        _reconstruct_args(run, "--data.calibration", rig, "--data.recordings", "walking01", "turning02")
    assert _reconstruct_args(run).data.recordings == ()  # the project's own rigs: every recording

@pytest.mark.slow  # prepares a small project twice (~10 s)
def test_the_same_project_named_by_another_path_keeps_its_cache(tmp_path, monkeypatch, caplog):
    """Defect 7: a project named by another path (relative from another working directory) was taken for one
    whose inputs changed: its prepared folder removed and prepared again."""
    project = write_rig_project(tmp_path / "p", ExampleProjectConfig(recordings=2, frames_per_recording=20))
    first = rig_job.load_splits(RigProjectConfig(root=project), progress=False)
    assert "read from the cache" not in first.notes[1]
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    again = rig_job.load_splits(RigProjectConfig(root=pathlib.Path("../p")), progress=False)
    assert "read from the cache" in again.notes[1]
    assert len([entry for entry in (project / ".jaxpose_cache").iterdir() if entry.is_dir() and entry.name.startswith("prepared")]) == 1
    assert dataclasses.asdict(again.record) == dataclasses.asdict(first.record)


@pytest.mark.slow  # recovers a rig (calibrate: ~40-60 s on 2 cores, most of it compiling)
def test_recovered_rig_files_state_the_world_they_are_in(tmp_path):
    """Defect 1: a rig recovered without a calibration is moved into the upright world (+Y up), yet its files and
    the report said "view 0's camera frame" and the limb prior's scale.  Also read back from the cache."""
    import tomllib

    from jaxpose.calibration.world import WORLD_FRAME as UPRIGHT
    from jaxpose.training.run_directory import RunDirectory

    project = write_rig_project(tmp_path / "p", ExampleProjectConfig(recordings=2, frames_per_recording=200, desync_camera=-1))
    for calibration in project.glob("calibration*"):
        calibration.unlink()
    config = RigProjectConfig(root=project, image_size=(1920, 1080), recovery_frames=200)
    for attempt in ("prepared", "from the cache"):
        splits = rig_job.load_splits(config, progress=False)
        assert ("read from the cache" in splits.notes[1]) == (attempt == "from the cache")
        run = RunDirectory(tmp_path / attempt)
        run.path.mkdir()
        (write_calibration,) = splits.artifacts
        write_calibration(run)
        assert list(run.recovered_rigs(splits.record).values()) == [run.recovered_cameras]  # the asset the record lists
        metadata = tomllib.loads(run.recovered_toml.read_text())["metadata"]
        assert metadata["world"] == UPRIGHT and metadata["up"] in ("normal of the floor the ankles stand on", "the subject's body axis")
        assert metadata["scale"].startswith("limb prior (")  # no height given, the limbs too few to rescale: the rig's own
        assert f"World frame: {UPRIGHT}" in run.recovered_cameras.read_text()
        assert f"World frame: {UPRIGHT}" in splits.notes[2] and "view 0's camera frame" not in splits.notes[2]
