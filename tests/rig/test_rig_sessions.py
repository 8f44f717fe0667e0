"""A project without calibration whose cameras moved between recordings: the sessions, each with its own
recovered rig (`jaxpose.rig.recovered`), through the real loader (`load_rig_project`).

The project: the simulated room (rig A) and the same room with every camera moved by 100-500 mm and turned
by 1-3 degrees (rig B, `jaxpose.synthetic.sessions.moved_rig`); recordings of one subject written as
detections.npz (the default detector: 3-8 px noise, outliers, swaps, missing joints; K given) with their
ground truth.
"""

from __future__ import annotations

import numpy as np
import pytest

from jaxpose.calibration import compare_rigs
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.rig_folder import DETECTIONS_NPZ, GROUND_TRUTH_NPZ, write_ground_truth
from jaxpose.rig.project import load_rig_project
from jaxpose.rig.config import RigProjectConfig
from jaxpose.rig.recovered import parse_sessions
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic import SyntheticConfig, make_rig, sample_bone_lengths, sample_motion
from jaxpose.synthetic.sessions import moved_rig, record

CONFIG = SyntheticConfig()
CAMERAS = ("c0", "c1", "c2", "c3")
PLAN = (("a1", "A", "walking"), ("a2", "A", "turning"), ("b1", "B", "walking"))


def write_project(root, plan=PLAN, frames: int = 160, seed: int = 3):
    """The two-rig project of `plan` [(recording, rig letter, motion)]; returns the rigs {letter: Cameras}."""
    rng = np.random.default_rng([seed, 43])
    rigs = {"A": make_rig(rng, CONFIG)}
    rigs["B"] = moved_rig(rng, rigs["A"])
    bones = sample_bone_lengths(rng)
    for name, letter, motion in plan:
        poses = sample_motion(rng, motion, bones, frames, CONFIG).poses
        keypoints, confidence = record(rng, rigs[letter], poses, CONFIG)
        (root / name).mkdir(parents=True)
        np.savez(
            root / name / DETECTIONS_NPZ, keypoints=keypoints, confidence=confidence, camera_names=np.array(CAMERAS),
            frames=np.arange(frames), image_size=np.full((4, 2), 1000), skeleton=np.array(H36M_17.name),
            K=np.asarray(rigs["A"].K, np.float64),
        )  # fmt: skip
        write_ground_truth(root / name / GROUND_TRUTH_NPZ, poses, np.arange(frames), H36M_17.joint_names)
    return rigs


def rig_of(project, recording: str):
    """The cameras (R, t) the loader gave `recording`."""
    rows = np.flatnonzero(project.train.samples.labels["recording"] == recording)
    index = int(project.train.samples.rig_index[rows[0]])
    return np.asarray(project.train.rigs.R[index], np.float64), np.asarray(project.train.rigs.t[index], np.float64)


def test_session_entries_are_parsed_and_checked(tmp_path):
    root = tmp_path / "project"
    write_project(root, frames=10)
    assert parse_sessions(["day1=a1,a2", "day2=b1"], ["a1", "a2", "b1"], root) == {"a1": "day1", "a2": "day1", "b1": "day2"}
    assert parse_sessions(["day1=a1,a2", "day2=b1"], ["a1", "b1"], root) == {"a1": "day1", "b1": "day2"}  # a2 not loaded
    with pytest.raises(ValueError, match=r"--data.sessions day1=z9: .* has no recording 'z9'; the closest is"):
        parse_sessions(["day1=a1,a2,z9", "day2=b1"], ["a1", "b1"], root)  # z9 in no folder: a typo, not left out
    with pytest.raises(ValueError, match=r"no session for the recordings \['b1'\]"):
        parse_sessions(["day1=a1,a2"], ["a1", "a2", "b1"], root)
    with pytest.raises(ValueError, match="'a1' is in sessions 'day1' and 'day2'"):
        parse_sessions(["day1=a1", "day2=a1,b1"], ["a1", "b1"], root)
    for entry in ("a1,a2", "day 1=a1", "../x=a1", "day1="):
        with pytest.raises(ValueError, match="SESSION=RECORDING"):
            parse_sessions([entry], ["a1"], root)


@pytest.mark.slow  # three loads (the sessions found, the cache, one rig): 2.9-7.2 min on 2 shared cores
def test_sessions_are_found_and_each_gets_its_own_rig(tmp_path):
    rigs = write_project(tmp_path / "project")
    config = RigProjectConfig(root=tmp_path / "project", recovery_frames=120, validation_fraction=0.25)
    project = load_rig_project(config, progress=False)
    assert [(s.name, s.recordings, s.found) for s in project.sessions] == [("session1", ("a1", "a2"), "data"), ("session2", ("b1",), "data")]
    assert project.recovered_calibration is None  # several sessions: no one rig
    assert all(session.reprojection_px < 8.0 for session in project.sessions)  # the detector's 3-8 px noise
    assert len(project.train.rigs.R) == 2
    for recording, letter in (("a1", "A"), ("a2", "A"), ("b1", "B")):
        R, t = rig_of(project, recording)
        truth = rigs[letter]
        comparison = compare_rigs(R, t, np.asarray(truth.R, np.float64), np.asarray(truth.t, np.float64))
        assert comparison.rotation_deg.max() < 0.5 and comparison.centre_mm.max() < 40.0, (recording, comparison)
    np.testing.assert_array_equal(*(rig_of(project, name)[0] for name in ("a1", "a2")))
    # The ground truth moved into each recording's own rig's world: the triangulation agrees with it.
    assert project.validation.samples.target3d is not None
    # Read back from the cache: the same sessions and rigs.
    again = load_rig_project(config, progress=False)
    assert again.prepared.startswith("read from the cache")
    assert [s.summary() for s in again.sessions] == [s.summary() for s in project.sessions]
    for first, second in zip(project.sessions, again.sessions):
        np.testing.assert_array_equal(first.calibration.cameras.R, second.calibration.cameras.R)
    # Forced to one rig: today's behaviour, one session of every recording.
    # The run writes one rig file per session, in the Pose2Sim/Anipose TOML and jaxpose's camera file.
    from experiments.rig import load_splits
    from jaxpose.formats.calibration_files import read_rig_calibration
    from jaxpose.training.run_directory import RunDirectory

    run = RunDirectory(tmp_path / "run")
    run.path.mkdir()
    splits = load_splits(config, progress=False)
    for write in splits.artifacts:
        write(run)
    assert not run.recovered_toml.exists() and not run.recovered_cameras.exists()
    rigs = run.recovered_rigs(splits.record)  # the run's assets, as its record lists them
    assert rigs == {session.name: run.path / "recovered_sessions" / f"{session.name}.json" for session in project.sessions}
    for session in project.sessions:
        for path in (rigs[session.name].with_suffix(".toml"), rigs[session.name]):
            written = read_rig_calibration(path)
            assert written.camera_names == CAMERAS
            np.testing.assert_allclose(written.cameras.R, session.calibration.cameras.R, atol=1e-6)
    one = load_rig_project(RigProjectConfig(root=tmp_path / "project", recovery_frames=120, validation_fraction=0.25, find_sessions=False), progress=False)
    assert [(s.recordings, s.found) for s in one.sessions] == [(("a1", "a2", "b1"), "one")] and len(one.train.rigs.R) == 1


@pytest.mark.slow  # two calibrations: 20-28 s on 2 shared cores
def test_sessions_given_by_the_user_are_taken_as_given(tmp_path):
    write_project(tmp_path / "project")
    config = RigProjectConfig(root=tmp_path / "project", recovery_frames=120, sessions=("monday=a1,a2", "tuesday=b1"))
    project = load_rig_project(config, progress=False)
    assert [(s.name, s.recordings, s.found) for s in project.sessions] == [("monday", ("a1", "a2"), "labels"), ("tuesday", ("b1",), "labels")]
    assert not np.array_equal(rig_of(project, "a1")[0], rig_of(project, "b1")[0])


def test_a_session_entry_naming_no_recording_is_refused_before_any_calibration(tmp_path):
    write_project(tmp_path / "project", frames=30)
    with pytest.raises(ValueError, match=r"no session for the recordings \['b1'\]"):
        load_rig_project(RigProjectConfig(root=tmp_path / "project", sessions=("monday=a1,a2",)), progress=False)


def test_a_recording_no_rig_explains_is_refused_in_one_line(tmp_path, monkeypatch):
    """A recording that fits no rig (here: a third rig, and too short to calibrate on) is named, with the two ways out."""
    from jaxpose.calibration import sessions as calibration_sessions
    from jaxpose.calibration.sessions import SessionGrouping, Session

    write_project(tmp_path / "project", frames=30)
    unfitted = SessionGrouping((Session("session1", ("a1", "a2"), 4.0),), ("b1",), "data", ("a1", "a2", "b1"), failures={"b1": "too few frames"})
    monkeypatch.setattr(calibration_sessions, "find_sessions", lambda *args, **kwargs: unfitted)
    with pytest.raises(DataFormatError) as error:
        load_rig_project(RigProjectConfig(root=tmp_path / "project"), progress=False)
    message = str(error.value)
    assert "\n" not in message and "recording 'b1' fits no rig (its own: too few frames)" in message
    assert "--data.sessions" in message and "--data.recordings" in message


def _calibration(shift_mm: float):
    """A recovered rig of four cameras on a circle (numbers a calibration could give)."""
    from jaxpose.calibration import Calibration
    from jaxpose.calibration.lens import LensEstimate
    from jaxpose.calibration.scale import MetricScale
    from jaxpose.camera import Cameras
    from scipy.spatial.transform import Rotation

    R = Rotation.from_euler("y", [[0], [90], [180], [270]], degrees=True).as_matrix()
    t = np.array([[0.0, 0.0, 5000.0 + shift_mm]] * 4)
    K = np.array([[[1100.0, 0, 500], [0, 1100.0, 500], [0, 0, 1]]] * 4)
    states = np.array([["estimated", "prior", "prior", "prior", "prior", "prior", "prior"]] * 4)
    return Calibration(
        cameras=Cameras(K=K, R=R, t=t), camera_names=CAMERAS, image_size=np.full((4, 2), 1000), reprojection_median_px=np.full(4, 4.0),
        reprojection_p90_px=np.full(4, 9.0), inlier_fraction=np.full(4, 0.9), scale=MetricScale(1.0, {"thigh": 450.0}, {"thigh": 450.0}),
        focal_estimated=True, frames_used=120, seconds=3.0, residual_scale=1.0,
        lens=LensEstimate(value=np.zeros((4, 7)), sigma=np.ones((4, 7)), prior_mean=np.zeros((4, 7)), prior_sigma=np.ones((4, 7)), state=states),
    )  # fmt: skip


def test_the_report_lists_the_sessions_and_each_rigs_reprojection():
    from experiments.rig import session_notes
    from jaxpose.rig.recovered import RecoveredSession

    sessions = (RecoveredSession("session1", ("a1", "a2"), 4.25, "data", _calibration(0.0)), RecoveredSession("session2", ("b1",), 5.5, "data", _calibration(300.0)))
    notes = session_notes(sessions)
    assert "2 sessions (found from the data" in notes
    assert "| session1 | a1, a2 | 4.25 |" in notes and "| session2 | b1 | 5.50 |" in notes
    assert notes.count("Rig recovered from the person") == 2  # each session's own calibration report
