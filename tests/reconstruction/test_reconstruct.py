"""`python -m jaxpose.reconstruct` on the embedded example project (which has ground truth), with a tiny
lifter trained on it: gap-free motion where a camera sees the person, long gaps split into segments,
files that read back as they were written, no overwriting, and the recovered rig read from the run."""

import dataclasses
import shutil
from types import SimpleNamespace

import numpy as np
import pytest
from help_text import assert_every_flag_documented

from jaxpose import reconstruct
from jaxpose.serving import inference
from jaxpose.formats.camera_file import save_cameras
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.formats.trc import read_trc
from jaxpose.reconstruction.fusion import Provenance
from jaxpose.reconstruction.motion_files import (
    UP_AXES,
    camera_up_axis,
    opensim_rotation,
)
from jaxpose.reconstruction import recording
from jaxpose.rig.config import RigProjectConfig
from jaxpose.training.run_directory import RECOVERED_CAMERAS_FILE, RECOVERED_SESSIONS_DIR, RunDirectory, read_record, write_record

FPS = 50.0


@pytest.fixture(scope="module")
def project(rig_run):
    """The shared rig project (tests/conftest.py): its first recording has a gap of `rig_run.gap`."""
    return rig_run.project


@pytest.fixture(scope="module")
def run_dir(rig_run):
    return rig_run.run_dir


def _reconstruct(run_dir, root, output, *flags):
    return reconstruct.main(["--checkpoint", str(run_dir), "--data.root", str(root), "--output", str(output),
                             "--fps", str(FPS), "--no-progress", *flags])  # fmt: skip


@pytest.mark.trains
def test_every_seen_instant_is_reconstructed_and_the_files_agree(project, run_dir, rig_run, tmp_path):
    out = tmp_path / "out"
    report = _reconstruct(run_dir, project, out)
    assert report["up_axis"] == "+z"  # the simulated room's cameras stand upright in a Z-up world
    rotation = opensim_rotation("+z")
    first, second = report["recordings"]
    assert (first["segments"], second["segments"]) == (2, 1)  # the gap of 30 frames splits the first
    assert first["dropped_frames"] >= len(rig_run.gap)
    for row in report["recordings"]:
        saved = np.load(out / f"{row['recording']}.npz")
        points, provenance, seen = saved["points_mm"], saved["provenance"], saved["seen"]
        # No gap where a camera sees the person; nothing invented where none does, beyond --max-gap.
        assert np.isfinite(points[seen]).all()
        assert (provenance[~np.isfinite(points).any(-1)] == Provenance.NONE).all()
        # The trajectory bridges the instants no camera sees (up to --max-gap) with an uncertainty of its own.
        assert np.isfinite(saved["uncertainty_mm"][np.isfinite(points).all(-1)]).all()
        assert row["mean_acceleration_mm_per_frame2"] > 0 and row["acceleration_error_mm_per_frame2"] > 0
        assert len(row["limb_length_std_mm"]) == len(saved["joint_names"]) - 1  # a limb per joint but the root
        # The motion prior this recording set, per joint, inside the estimator's grid (mm/s^2).
        assert list(row["motion_prior_mm_s2"]) == [str(name) for name in saved["joint_names"]]
        assert all(100.0 <= value <= 1e6 for value in row["motion_prior_mm_s2"].values()) and row["impacts"] >= 0
        # Near the ground truth (the detections alone triangulate to ~19 mm on this project).
        truth = np.load(project / row["recording"] / "ground_truth.npz")
        names = [str(name) for name in saved["joint_names"]]
        common = [name for name in truth["joint_names"].tolist() if name in names]
        at = np.searchsorted(saved["frame"], truth["frames"])
        error = np.linalg.norm(points[at][:, [names.index(n) for n in common]] - truth["points3d"][:, [truth["joint_names"].tolist().index(n) for n in common]], axis=-1)
        assert np.nanmean(error) < 40.0
        # Each segment's .trc: Pose2Sim's layout, metres in OpenSim's axes, frames and times as the npz.
        for index, (start, stop) in enumerate(saved["segment_frames"]):
            name = row["recording"] + (f".seg{index}" if index else "") + ".trc"
            assert name in row["files"]
            trc = read_trc(out / name)
            rows = np.flatnonzero(saved["segment"] == index)
            assert trc.units == "m" and trc.rate == FPS and trc.marker_names == tuple(names)
            assert "X=y Y=z Z=x of the calibration's world, +z up" in trc.path_line
            np.testing.assert_array_equal(trc.frame_numbers, np.arange(start, stop))
            np.testing.assert_allclose(trc.times, trc.frame_numbers / FPS, atol=1e-6)
            np.testing.assert_allclose(trc.markers, points[rows] @ rotation.T / 1000.0, atol=1e-6)
            assert np.isfinite(trc.markers).all()
    assert "| triangulated | fused | lifted | interpolated | none |" in (out / "report.md").read_text()
    assert "solved over time (the trajectory)" in (out / "report.md").read_text()
    assert "| process noise, median (range) | impacts |" in (out / "report.md").read_text()

    # A second run refuses before any work and changes nothing; --overwrite replaces.
    before = {path: path.read_bytes() for path in out.iterdir()}
    with pytest.raises(SystemExit, match="--overwrite"):
        _reconstruct(run_dir, project, out)
    assert {path: path.read_bytes() for path in out.iterdir()} == before
    with pytest.raises(SystemExit, match="is inside this command's input folder"):
        _reconstruct(run_dir, project, project / "motion")
    again = _reconstruct(run_dir, project, out, "--overwrite", "--max-gap", "40")  # the gap is bridged now
    assert again["recordings"][0]["segments"] == 1 and again["recordings"][0]["dropped_frames"] < first["dropped_frames"]
    assert again["earlier_files_left"] == [str(out / f"{first['recording']}.seg1.trc")]  # named, as predict does


@pytest.mark.trains
def test_some_recordings_are_read_from_the_whole_projects_prepared_folder(project, run_dir, tmp_path):
    """--data.recordings after training: the named recording's rows of the project training prepared, no
    folder of its own; the same motion as from the recording prepared alone (a copy without the cache)."""
    name = sorted(p.name for p in project.iterdir() if p.is_dir() and not p.name.startswith("."))[-1]
    folders = sorted((project / ".jaxpose_cache").glob("prepared-*"))
    report = _reconstruct(run_dir, project, tmp_path / "from_whole", "--data.recordings", name)
    assert [row["recording"] for row in report["recordings"]] == [name]
    assert sorted((project / ".jaxpose_cache").glob("prepared-*")) == folders
    alone = tmp_path / "alone"
    shutil.copytree(project, alone, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    _reconstruct(run_dir, alone, tmp_path / "from_alone", "--data.recordings", name)
    assert len(list((alone / ".jaxpose_cache").glob("prepared-*"))) == 1
    whole, single = (np.load(tmp_path / folder / f"{name}.npz") for folder in ("from_whole", "from_alone"))
    assert whole.files == single.files
    for array in whole.files:
        np.testing.assert_array_equal(whole[array], single[array], err_msg=array)


@pytest.mark.trains
def test_no_smoothing_gives_each_instants_own_estimate(project, run_dir, tmp_path):
    """--no-smoothing writes the per-instant motion (`lift_and_reconstruct` without a trajectory) as it is;
    the trajectory's motion accelerates less and its limbs keep their length better."""
    smooth = _reconstruct(run_dir, project, tmp_path / "smooth")
    plain = _reconstruct(run_dir, project, tmp_path / "plain", "--no-smoothing")
    assert plain["trajectory"] is None and "each instant alone" in (tmp_path / "plain" / "report.md").read_text()
    lifter = inference.load(run_dir)
    dataset = recording.load_every_instant(RigProjectConfig(root=project), RunDirectory.of(run_dir), progress=False).instants
    for inputs, row, smoothed in zip(recording.recording_inputs(dataset), plain["recordings"], smooth["recordings"]):
        motion, _ = recording.lift_and_reconstruct(lifter, inputs)
        saved = np.load(tmp_path / "plain" / f"{inputs.name}.npz")
        np.testing.assert_array_equal(saved["points_mm"], motion.points)
        np.testing.assert_array_equal(saved["provenance"], motion.provenance)
        assert np.isnan(saved["uncertainty_mm"][saved["provenance"] == Provenance.INTERPOLATED]).all()
        assert smoothed["mean_acceleration_mm_per_frame2"] < row["mean_acceleration_mm_per_frame2"]
        assert smoothed["acceleration_error_mm_per_frame2"] < row["acceleration_error_mm_per_frame2"]
        assert smoothed["mean_limb_length_std_mm"] < row["mean_limb_length_std_mm"]


@pytest.mark.trains
def test_an_uncalibrated_project_is_taken_in_the_runs_recovered_rig(project, run_dir, tmp_path):
    """Without a calibration, the rig recovered in the run (recovered_cameras.json) is read; without one
    either, the command refuses rather than recover another world frame."""
    root = tmp_path / "uncalibrated"
    shutil.copytree(project, root, ignore=shutil.ignore_patterns(".jaxpose_cache"))
    calibration = read_rig_calibration(root / "calibration.toml")
    (root / "calibration.toml").unlink()
    with pytest.raises(SystemExit, match=RECOVERED_CAMERAS_FILE):
        _reconstruct(run_dir, root, tmp_path / "refused", "--up-axis", "+z")
    sessions_run = RunDirectory(tmp_path / "sessions_run")  # a run of several sessions (its record lists their rigs): which file to pass is said
    shutil.copytree(run_dir, sessions_run.path)
    write_record(sessions_run, dataclasses.replace(read_record(sessions_run), recovered_rigs=RunDirectory.recovered_rig_files(["a", "b"])))
    with pytest.raises(SystemExit, match=f"one recovered rig per session .*--data.calibration .*{RECOVERED_SESSIONS_DIR}/SESSION.toml"):
        _reconstruct(sessions_run.path, root, tmp_path / "refused_sessions", "--up-axis", "+z")
    recovered_run = tmp_path / "recovered_run"
    shutil.copytree(run_dir, recovered_run)
    trained = RunDirectory(recovered_run)  # as trained on a recovered rig: its record lists it
    write_record(trained, dataclasses.replace(read_record(trained), recovered_rigs=RunDirectory.recovered_rig_files(["session1"])))
    # The "recovered" rig: the calibration's cameras turned and moved into another world frame.
    turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    cameras = calibration.cameras
    moved = dataclasses.replace(cameras, R=np.asarray(cameras.R) @ turn.T, t=np.asarray(cameras.t) + np.asarray(cameras.R) @ [0.0, 0.0, 100.0])
    save_cameras(recovered_run / RECOVERED_CAMERAS_FILE, {"rig": (list(calibration.camera_names), moved)})
    report = _reconstruct(recovered_run, root, tmp_path / "out", "--up-axis", "+z")
    assert report["calibration"].endswith(RECOVERED_CAMERAS_FILE)
    calibrated = _reconstruct(run_dir, project, tmp_path / "calibrated", "--up-axis", "+z")
    for row in calibrated["recordings"]:
        in_calibration = np.load(tmp_path / "calibrated" / f"{row['recording']}.npz")["points_mm"]
        in_recovered = np.load(tmp_path / "out" / f"{row['recording']}.npz")["points_mm"]
        # X_recovered = turn (X - (0, 0, 100)): the same motion in the recovered rig's world.
        np.testing.assert_allclose(in_recovered, (in_calibration - [0.0, 0.0, 100.0]) @ turn.T, atol=0.5)


def test_opensim_rotation_puts_every_up_axis_on_y():
    for axis in UP_AXES[1:]:
        rotation = opensim_rotation(axis)
        up = np.zeros(3)
        up["xyz".index(axis[1])] = 1.0 if axis[0] == "+" else -1.0
        np.testing.assert_allclose(rotation @ up, [0.0, 1.0, 0.0])
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3))
        assert np.linalg.det(rotation) == pytest.approx(1.0)
    # Pose2Sim's Z-up to Y-up: (X, Y, Z) = (y, z, x).
    np.testing.assert_array_equal(opensim_rotation("+z") @ [1.0, 2.0, 3.0], [2.0, 3.0, 1.0])


def test_the_up_axis_of_upright_cameras():
    """A camera's image up (-y of its axes) in world axes is -R[1]: level or tilted 20 degrees, cameras of a
    Y-up world say +y; cameras whose ups differ by 90 degrees say nothing, and the flag is asked for."""
    tilt = np.radians(20.0)
    level = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # looking along -Z, image y = -Y
    tilted = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(tilt), -np.sin(tilt)], [0.0, np.sin(tilt), np.cos(tilt)]]) @ level
    assert camera_up_axis(SimpleNamespace(R=np.stack([level, tilted]))) == "+y"
    assert camera_up_axis(SimpleNamespace(R=(level @ opensim_rotation("+z"))[None])) == "+z"
    rolled = level @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # its up along world X
    with pytest.raises(ValueError, match="--up-axis"):
        camera_up_axis(SimpleNamespace(R=np.stack([level, rolled])))


@pytest.mark.trains
def test_opensims_reader_takes_the_trc_files(project, run_dir, tmp_path, monkeypatch):
    """OpenSim 4.6's own readers (where the package is installed; it is no dependency) read every segment's
    .trc with its markers, rate, unit and times."""
    monkeypatch.chdir(tmp_path)  # OpenSim writes its opensim.log into the working folder
    opensim = pytest.importorskip("opensim")
    first = sorted(p.name for p in project.iterdir() if p.is_dir() and not p.name.startswith("."))[0]
    report = _reconstruct(run_dir, project, tmp_path, "--data.recordings", first)
    names = [name for name in report["recordings"][0]["files"] if name.endswith(".trc")]
    assert len(names) == 2
    for name in names:
        ours = read_trc(tmp_path / name)
        table = opensim.TimeSeriesTableVec3(str(tmp_path / name))
        assert list(table.getColumnLabels()) == list(ours.marker_names)
        assert table.getTableMetaDataAsString("Units") == "m" and float(table.getTableMetaDataAsString("DataRate")) == FPS
        np.testing.assert_allclose(np.asarray(table.getIndependentColumn()), ours.times)
        rows = [table.getRowAtIndex(i) for i in range(table.getNumRows())]
        markers = np.array([[[row[m][k] for k in range(3)] for m in range(row.size())] for row in rows])
        np.testing.assert_allclose(markers, ours.markers, atol=1e-9)
        data = opensim.MarkerData(str(tmp_path / name))
        assert data.getNumFrames() == len(ours.times) and data.getStartFrameTime() == pytest.approx(ours.times[0])


def test_help_documents_every_flag(capsys):
    from experiments import reconstruction_study, trajectory_tuning
    from jaxpose.reconstruction.fusion import FusionConfig
    from jaxpose.reconstruction.trajectory import TrajectoryConfig

    for main, args_type in (
        (reconstruct.main, reconstruct.ReconstructArgs), (reconstruction_study.main, reconstruction_study.StudyArgs),
        (trajectory_tuning.main, trajectory_tuning.TuningArgs),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as stop:
            main(["--help"])
        assert stop.value.code == 0
        nested = ("data", "fusion", "occlusion", "trajectory")
        flags = [f"--{f.name.replace('_', '-')}" for f in dataclasses.fields(args_type) if f.name not in nested]
        if any(f.name == "fusion" for f in dataclasses.fields(args_type)):
            flags += ["--fusion." + f.name.replace("_", "-") for f in dataclasses.fields(FusionConfig)]
            flags += ["--trajectory." + f.name.replace("_", "-") for f in dataclasses.fields(TrajectoryConfig)]
        assert_every_flag_documented(capsys.readouterr().out, flags)


@pytest.mark.trains
def test_c3d_files_hold_the_trc_markers(project, run_dir, tmp_path):
    """--c3d: a .c3d beside each .trc (ezc3d, the optional extra), the same markers in mm, rate, labels
    and first frame."""
    ezc3d = pytest.importorskip("ezc3d")
    second = sorted(p.name for p in project.iterdir() if p.is_dir() and not p.name.startswith("."))[1]
    report = _reconstruct(run_dir, project, tmp_path, "--data.recordings", second, "--c3d")
    assert f"{second}.c3d" in report["recordings"][0]["files"]
    ours = read_trc(tmp_path / f"{second}.trc")
    c3d = ezc3d.c3d(str(tmp_path / f"{second}.c3d"))
    assert list(c3d["parameters"]["POINT"]["LABELS"]["value"]) == list(ours.marker_names)
    assert c3d["parameters"]["POINT"]["UNITS"]["value"] == ["mm"] and c3d["parameters"]["POINT"]["RATE"]["value"][0] == FPS
    assert c3d["header"]["points"]["first_frame"] == ours.frame_numbers[0]
    np.testing.assert_allclose(c3d["data"]["points"][:3].transpose(2, 1, 0), ours.markers * 1000.0, atol=1e-3)



@pytest.mark.parametrize("fps", ["1e5", "1e9"])
def test_a_frame_rate_no_rig_records_is_refused_in_one_line(fps, tmp_path):
    """--fps 1e5..1e9 (a typo, or frames numbered in microseconds): refused before any work, naming the flag
    and the largest rate taken (issue 52: every marker 0 at 1e9, the pelvis from 1592 to -522 mm at 1e5)."""
    with pytest.raises(SystemExit, match=r"--fps .* at most 10000"):
        reconstruct.main(["--checkpoint", str(tmp_path / "run"), "--data.root", str(tmp_path / "project"),
                          "--output", str(tmp_path / "out"), "--fps", fps, "--no-progress"])  # fmt: skip
    assert not (tmp_path / "out").exists()
