"""`python -m jaxpose.reconstruct` on recordings of several people: one set of files per person,
``<recording>.person<k>.*`` (k in order of first appearance), the report listing each person's frames, coverage
and limb lengths, the log saying how many people were found; each person's motion what it is reconstructed
alone; and Pose2Sim's multi-person demo written as its real person and its ghost."""

from __future__ import annotations

import contextlib
import dataclasses
import io

import numpy as np
import pytest

from experiments import rig as rig_job
from jaxpose import reconstruct
from jaxpose.synthetic import ExampleProjectConfig, write_rig_project
from tests.paths import FORMATS

FPS = 50.0
# The shared run's layout and cameras (tests/conftest.py); no passer-by, false person or occlusion, so that
# person 0's detections are those of the same project with person 0 alone (tests/synthetic/test_people_project.py).
TWO = ExampleProjectConfig(recordings=1, frames_per_recording=60, people=2, second_person_rate=0.0, desync_camera=-1)
DEMO = FORMATS / "openpose-json" / "pose2sim_demo_multiperson_body25b"
DEMO_CALIBRATION = FORMATS / "pose2sim-calib-toml" / "pose2sim_demo_Calib_qualisys.toml"


def _reconstruct(run_dir, root, output, *flags, fps: float = FPS) -> tuple[dict, str]:
    log = io.StringIO()
    with contextlib.redirect_stderr(log):
        report = reconstruct.main(["--checkpoint", str(run_dir), "--data.root", str(root), "--output", str(output),
                                   "--fps", str(fps), "--no-progress", *flags])  # fmt: skip
    return report, log.getvalue()


@pytest.mark.trains
def test_each_person_has_their_files_and_row_and_moves_as_alone(rig_run, tmp_path):
    two = write_rig_project(tmp_path / "two", TWO)
    alone = write_rig_project(tmp_path / "alone", dataclasses.replace(TWO, people=1))
    name = TWO.recording_names[0]
    report, log = _reconstruct(rig_run.run_dir, two, tmp_path / "out")
    assert f"recording {name}: 2 people found" in log
    assert report["people"][name]["found"] == 2
    rows = report["recordings"]
    assert [(row["recording"], row["of_recording"], row["person"]) for row in rows] == [
        (f"{name}.person1", name, 1), (f"{name}.person2", name, 2)
    ]  # fmt: skip
    written = sorted(path.name for path in (tmp_path / "out").iterdir())
    assert written == sorted([f"{name}.person{k}{suffix}" for k in (1, 2) for suffix in (".csv", ".npz", ".trc")] + ["report.json", "report.md"])
    for row in rows:
        assert (row["first_frame"], row["last_frame"], row["coverage"]) == (0, 59, 1.0)
        assert all(value is not None and 30.0 < value < 700.0 for value in row["limb_length_mm"].values())
    markdown = (tmp_path / "out" / "report.md").read_text()
    assert f"| {name}.person2 | {name} | 2 | 0 | 59 | 100.0% |" in markdown
    single, log = _reconstruct(rig_run.run_dir, alone, tmp_path / "alone_out")
    assert f"recording {name}: 1 person found" in log and (tmp_path / "alone_out" / f"{name}.trc").is_file()  # today's names
    by_itself = np.load(tmp_path / "alone_out" / f"{name}.npz")["points_mm"]
    people = [np.load(tmp_path / "out" / f"{name}.person{k}.npz")["points_mm"] for k in (1, 2)]
    # Person 0 among two is reconstructed as alone: within 1 mm per joint (its detections are the same).
    distance = [np.nanmean(np.linalg.norm(points - by_itself, axis=-1)) for points in people]
    assert min(distance) < 1.0 and max(distance) > 300.0, distance


@pytest.mark.trains
def test_a_second_person_is_refused_over_the_files_of_an_earlier_run(rig_run, tmp_path):
    """Files of a person of an earlier run are that recording's: no --overwrite, no work."""
    two = write_rig_project(tmp_path / "two", TWO)
    out = tmp_path / "out"
    out.mkdir()
    (out / f"{TWO.recording_names[0]}.person2.trc").write_text("earlier")
    with pytest.raises(SystemExit, match=r"person2.trc of these recordings; pass --overwrite"):
        _reconstruct(rig_run.run_dir, two, out)


@pytest.mark.slow
@pytest.mark.trains
@pytest.mark.skipif(not (DEMO.exists() and DEMO_CALIBRATION.exists()), reason="Pose2Sim's demo is not in ../shared/data")
def test_pose2sim_multiperson_demo_writes_its_real_person_and_its_ghost(tmp_path):
    """A tiny lifter trained on the demo itself (BODY_25B), then reconstructed: two people, each one identity
    from the first frame to the last with its files; the false detections' track left out and counted."""
    project = tmp_path / "project"
    (project / "demo").mkdir(parents=True)
    for camera in range(1, 5):  # the calibration names its cameras cam_01 .. cam_04
        (project / "demo" / f"cam_0{camera}_json").symlink_to(DEMO / f"cam0{camera}_json")
    data = ["--data.root", str(project), "--data.calibration", str(DEMO_CALIBRATION), "--data.skeleton", "body25b",
            "--data.cache-dir", str(tmp_path / "cache")]  # fmt: skip
    run_dir = tmp_path / "run"
    with contextlib.redirect_stderr(io.StringIO()):
        rig_job.main([*data, "--run.run-dir", str(run_dir), "--model.width", "32", "--train.batch-size", "32", "--train.epochs", "1",
                      "--train.max-steps", "4", "--train.eval-every", "4", "--train.eval-samples", "8", "--run.no-progress",
                      "--run.plot-samples", "0", "--run.no-tensorboard"])  # fmt: skip
    report, log = _reconstruct(run_dir, project, tmp_path / "out", *data[2:], fps=30.0)
    assert "recording demo: 2 people found; " in log and "tracks the detector scored low left out" in log
    assert report["people"]["demo"]["found"] == 2 and report["people"]["demo"]["tracks_left_out"] >= 1
    rows = report["recordings"]
    assert [row["recording"] for row in rows] == ["demo.person1", "demo.person2"]
    for row in rows:
        assert (row["first_frame"], row["last_frame"], row["coverage"]) == (0, 99, 1.0)
        assert (tmp_path / "out" / "demo.person{}.trc".format(row["person"])).is_file()
