"""The real-data entry points end to end on tiny fixture trees (tests/fixtures_real_data.py):
experiments.h36m (Martinez and VideoPose3D layouts), experiments.humaneva, experiments.mpi_inf_3dhp,
their presets, paper-layout tables, --help and missing-data errors."""

import dataclasses
import json
import os
import pathlib

import numpy as np
import pytest

from experiments import ablation, cli, h36m, humaneva, mpi_inf_3dhp, rig_from_h36m
from jaxpose.training.experiment import mocap_calibration, other_training_calibration
from help_text import assert_every_flag_documented, assert_help_documents_every_field
from jaxpose.formats.camera_file import load_cameras, save_cameras
from jaxpose.training.run_directory import RunDirectory
from jaxpose.formats.h36m_cameras import read_h36m_cameras
from jaxpose.datasets.h36m import CAMERA_NAMES
from fixtures_real_data import HUMANEVA_CAMERA_NAMES, H36M_SUBJECTS, TINY_TRAINING, write_humaneva_files
from fixtures_real_data import write_h36m_martinez_tree, write_h36m_videopose3d_files
from fixtures_real_data import write_mpi_inf_3dhp_test_set
from jaxpose.datasets.mpi_inf_3dhp import camera_intrinsics

TABLE_II_HEADER = "| Method | Dir. | Dis. | Eat | Greet | Phone | Photo | Pose | Purch. | Sit | SitD | Smoke | Wait | WalkD | Walk | WalkT | Avg |"
TABLE_III_HEADER = "| Method | Walking S1 | Walking S2 | Walking S3 | Jogging S1 | Jogging S2 | Jogging S3 | Avg |"


@pytest.fixture(scope="module")
def h36m_tree(tmp_path_factory):
    """S1 (train) and S9 (test) with Directions 1, TakingPhoto, WalkingDog 1, Walking 1 in both layouts."""
    root = tmp_path_factory.mktemp("h36m")
    fixture = write_h36m_martinez_tree(root / "martinez")
    write_h36m_videopose3d_files(root / "videopose3d", fixture)
    return root


@pytest.fixture(scope="module")
def sh_run(h36m_tree, tmp_path_factory):
    """Martinez layout, Stacked Hourglass 2D (16 joints), trained with full supervision."""
    run_dir = tmp_path_factory.mktemp("runs") / "h36m_sh"
    argv = ["--data.data-dir", str(h36m_tree / "martinez"), "--data.detections", "sh", "--supervision", "full"]
    report = h36m.main(argv + H36M_SUBJECTS + TINY_TRAINING + ["--run.run-dir", str(run_dir)])
    return run_dir, report


@pytest.fixture(scope="module")
def cpn_run(h36m_tree, tmp_path_factory):
    """VideoPose3D layout with CPN-named 2D (17 joints) and cameras.h5 from elsewhere, self-supervised."""
    run_dir = tmp_path_factory.mktemp("runs") / "h36m_cpn"
    argv = [
        "--data.data-dir", str(h36m_tree / "videopose3d"), "--data.detections", "cpn",
        "--data.cameras-path", str(h36m_tree / "martinez" / "cameras.h5"),
    ]
    report = h36m.main(argv + H36M_SUBJECTS + TINY_TRAINING + ["--run.run-dir", str(run_dir)])
    return run_dir, report


def _table_rows(path, header):
    """The rows of the first markdown table in `path` whose header line is `header`."""
    lines = path.read_text().splitlines()
    start = lines.index(header)
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows


def test_h36m_martinez_layout_supervised(sh_run):
    run_dir, report = sh_run
    assert "Lifter, supervised (3D ground truth)" in report["results"]
    assert (run_dir / "report.md").exists() and (run_dir / "report.json").exists()
    rows = _table_rows(RunDirectory(run_dir).paper_table, TABLE_II_HEADER)
    ours = rows[0]
    assert ours[0] == "Lifter, supervised (3D ground truth)"
    by_column = dict(zip(TABLE_II_HEADER.strip("| ").split(" | "), ours))
    for column in ("Dir.", "Photo", "WalkD", "Walk", "Avg"):  # the fixture's four actions
        float(by_column[column])
    assert by_column["Eat"] == "-"
    assert any(row[0] == "Paper: ours (self-supervised)" and row[-1] == "62.0" for row in rows)


def test_h36m_videopose3d_layout_self_supervised(cpn_run):
    run_dir, report = cpn_run
    assert "Lifter, self-supervised (ours)" in report["results"]
    assert set(report["results"]["Lifter, self-supervised (ours)"]["groups"]) == {"Directions", "Photo", "WalkDog", "Walking"}
    config = json.loads((run_dir / "config.json").read_text())
    assert config["data"]["detections"] == "cpn" and config["model"]["width"] == 32
    text = (RunDirectory(run_dir).paper_table).read_text()
    assert TABLE_II_HEADER in text and "MPJPE (mm, root-relative, no alignment" in text


@pytest.mark.trains
def test_humaneva_table_iii_layout(tmp_path):
    files = write_humaneva_files(tmp_path / "humaneva", subjects=("S1", "S2"))
    run_dir = tmp_path / "run"
    argv = [
        "--data.data-dir", str(files.root), "--data.train-subjects", "Train/S1", "Train/S2",
        "--data.test-subjects", "Validate/S1", "Validate/S2", "--run.run-dir", str(run_dir),
    ]
    report = humaneva.main(argv + TINY_TRAINING)
    groups = report["results"]["Lifter, self-supervised (ours)"]["groups"]
    assert set(groups) == {"Walk S1", "Walk S2", "Jog S1", "Jog S2"}  # no Gestures: the protocol tests Walk, Jog
    assert (run_dir / "report.md").exists()
    ours = _table_rows(RunDirectory(run_dir).paper_table, TABLE_III_HEADER)[0]
    assert [cell == "-" for cell in ours[1:7]] == [False, False, True, False, False, True]
    float(ours[7])


@pytest.mark.trains
def test_mpi_inf_3dhp_evaluation_of_an_h36m17_run(cpn_run, tmp_path):
    run_dir, _ = cpn_run
    K = {name: camera_intrinsics(name) for name in ("TS1", "TS5")}
    data = write_mpi_inf_3dhp_test_set(tmp_path / "3dhp", {"TS1": "v7.3", "TS5": "v5"}, K=K)
    out = tmp_path / "out"
    argv = ["--run-dir", str(run_dir), "--data-dir", str(data.root), "--sequences", "TS1", "TS5", "--out-dir", str(out)]
    report = mpi_inf_3dhp.main(argv + ["--no-progress"])
    frames = sum(int(valid.sum()) for valid in data.valid.values())
    assert report["frames"] == frames == report["by_activity"]["overall"]["count"]
    assert set(report["by_sequence"]["groups"]) == {"TS1", "TS5"}
    for summary in report["by_activity"]["groups"].values():
        assert 0.0 <= summary["pck"] <= 100.0 and 0.0 <= summary["auc"] <= summary["pck"] + 1e-6
    assert json.loads((out / "report.json").read_text())["checkpoint_step"] == report["checkpoint_step"]
    text = (out / "report.md").read_text()
    assert "| Activity | Frames | PCK@150mm (%) | AUC (%) | MPJPE (mm) | P-MPJPE (mm) |" in text
    assert "| Paper: ours (self-supervised) | 2935 | 65.9 | 32.5 | - | - |" in text


@pytest.mark.trains
def test_mpi_inf_3dhp_rejects_a_16_joint_model(sh_run, tmp_path):
    run_dir, _ = sh_run
    with pytest.raises(SystemExit) as stop:
        mpi_inf_3dhp.main(["--run-dir", str(run_dir), "--data-dir", str(tmp_path), "--no-progress"])
    assert "16 joints" in str(stop.value.code) and "--data.detections sh" in str(stop.value.code)


@pytest.mark.trains
def test_mpi_inf_3dhp_missing_data(cpn_run, tmp_path):
    with pytest.raises(SystemExit) as stop:
        mpi_inf_3dhp.main(["--run-dir", str(cpn_run[0]), "--data-dir", str(tmp_path / "none"), "--no-progress"])
    assert "annot_data.mat" in str(stop.value.code) and "Getting the data" in str(stop.value.code)


@pytest.mark.parametrize("module, data_dir", [(h36m, "data/h36m"), (humaneva, "data/humaneva")])
def test_missing_data_is_one_message_and_leaves_no_run_dir(module, data_dir, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        module.main([])
    message = stop.value.code
    assert isinstance(message, str) and message.startswith("error: ")  # printed to stderr, exit status 1
    assert '"Getting the data" (docs/data.md)' in message and f"--data.data-dir {data_dir}" in message
    assert not (tmp_path / "runs").exists()


@pytest.mark.parametrize("module, data_type", [(h36m, h36m.H36MData), (humaneva, humaneva.HumanEvaData)])
def test_help_lists_presets_and_documents_every_data_flag(module, data_type, capsys):
    with pytest.raises(SystemExit) as stop:
        module.main(["--preset", "paper", "--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert "--preset {" + ",".join(module.PRESETS) + "}" in text and "defaults shown below are those of --preset paper" in text
    assert_every_flag_documented(text, ["--data." + f.name.replace("_", "-") for f in dataclasses.fields(data_type)])


def test_ablation_help_is_the_chosen_experiments_with_its_presets(capsys):
    with pytest.raises(SystemExit) as stop:
        ablation.main(["--dataset", "h36m", "--rows", "twin", "--preset", "dev", "--help"])
    assert stop.value.code == 0
    text = capsys.readouterr().out
    assert "--dataset h36m --rows twin [--preset {cpu,paper,dev}]" in text and "those of --preset dev" in text
    assert "runs/comparison_h36m_dev" in text
    assert_every_flag_documented(text, ["--data." + f.name.replace("_", "-") for f in dataclasses.fields(h36m.H36MData)])
    with pytest.raises(SystemExit) as stop:
        ablation.main(["--dataset", "mpi"])
    assert stop.value.code == 2 and "invalid choice 'mpi' for argument '--dataset'" in capsys.readouterr().err


def test_mpi_inf_3dhp_help(capsys):
    assert_help_documents_every_field(capsys, mpi_inf_3dhp.main, mpi_inf_3dhp.Mpi3dhpEvaluation)


@pytest.mark.parametrize("module", [h36m, humaneva])
def test_presets(module):
    assert module.DEFAULT is module.PRESETS["cpu"] and module.EXPERIMENT.presets is module.PRESETS
    paper = cli.parse(module.EXPERIMENT, ["--preset", "paper"], "")
    assert paper == module.PRESETS["paper"]
    assert (paper.optimizer.learning_rate, paper.optimizer.schedule, paper.optimizer.warmup_steps) == (1e-3, "constant", 0)
    assert (paper.train.batch_size, paper.train.epochs) == ((8192, 500) if module is h36m else (1600, 5000))
    assert paper.model == type(paper.model)() and paper.loss == type(paper.loss)()
    weights = (paper.loss.input_triangulation, paper.loss.reprojection, paper.loss.consistency, paper.loss.output_triangulation)
    assert weights == (1.0, 1.0, 0.001, 0.01) and paper.loss.output_triangulation_start == 0.9
    supervised = cli.parse(module.EXPERIMENT, ["--supervision", "full"], "")
    assert supervised.loss.supervision == "full"
    assert str(supervised.run.run_dir) == f"{module.DEFAULT.run.run_dir}_supervised"


def test_h36m_dev_preset_is_the_cpu_recipe_at_a_proportional_budget():
    dev, cpu = h36m.PRESETS["dev"], h36m.PRESETS["cpu"]
    assert (dev.model, dev.loss, dev.pseudo_labels, dev.train) == (cpu.model, cpu.loss, cpu.pseudo_labels, cpu.train)
    assert (dev.data.train_subjects, dev.data.test_subjects, dev.data.split, dev.data.detections) == (("S1",), (), "trials", "sh")
    # The same share of the steps warms up: S1's first trials are ~1/13 of the five training subjects.
    assert 0 < dev.optimizer.warmup_steps < cpu.optimizer.warmup_steps / 10
    # Every term acts: the recipe's L_con and L_out weights are not the paper's near-zero ones.
    assert cpu.loss.consistency >= 0.01 and cpu.loss.output_triangulation >= 0.1


def test_humaneva_trains_on_another_calibration_and_tests_on_the_reference(tmp_path):
    """As for Human3.6M: --data.cameras-path reaches the Train partition only, and Validate keeps
    <data-dir>/cameras.json (--data.reference-cameras-path), the frame of its ground truth."""
    files = write_humaneva_files(tmp_path / "humaneva", subjects=("S1",))
    reference = load_cameras(files.cameras_path)
    names, cameras = reference["S1"]
    moved = cameras.replace(t=cameras.t + np.float32(300.0))
    recovered = tmp_path / "recovered.json"
    save_cameras(recovered, {"S1": (names, moved)})
    data = humaneva.HumanEvaData(data_dir=files.root, train_subjects=("Train/S1",), test_subjects=("Validate/S1",),
                                 cameras_path=recovered)  # fmt: skip
    splits = humaneva.load_splits(data)
    order = [names.index(name) for name in HUMANEVA_CAMERA_NAMES]
    np.testing.assert_allclose(splits.train.cameras_for(np.arange(2)).t, np.broadcast_to(moved.t[order], (2, 3, 3)))
    assert splits.train.samples.target3d is None
    np.testing.assert_allclose(splits.test.cameras_for(np.arange(2)).t, np.broadcast_to(cameras.t[order], (2, 3, 3)))
    assert splits.test.samples.target3d is not None
    assert "--data.reference-cameras-path):  " + str(files.cameras_path) in humaneva.expected_files(data)
    # The reference named explicitly is the same; the recovered file named as the reference is no recalibration.
    explicit = dataclasses.replace(data, reference_cameras_path=files.cameras_path)
    assert humaneva.load_splits(explicit).train.samples.target3d is None
    assert humaneva.load_splits(dataclasses.replace(data, reference_cameras_path=recovered)).train.samples.target3d is not None
    # Without <data-dir>/cameras.json, --data.cameras-path alone is the calibration of both halves.
    files.cameras_path.rename(tmp_path / "elsewhere.json")
    alone = humaneva.load_splits(data)
    assert alone.train.samples.target3d is not None
    np.testing.assert_allclose(alone.test.cameras_for(np.arange(2)).t, np.broadcast_to(moved.t[order], (2, 3, 3)))


def test_the_reference_and_the_training_calibration(tmp_path):
    """`mocap_calibration`: the given file, else the data set's own where it exists, else the
    training calibration; `other_training_calibration`: None for the reference itself, however spelled."""
    own, recovered, given = tmp_path / "cameras.h5", tmp_path / "recovered.json", tmp_path / "mocap.json"
    assert mocap_calibration(given, own, recovered) == given
    assert mocap_calibration(None, own, recovered) == recovered  # no <data-dir> calibration
    assert mocap_calibration(None, own, None) == own  # the missing-file error names it later
    own.write_bytes(b"")
    assert mocap_calibration(None, own, recovered) == own
    assert other_training_calibration(recovered, own) == recovered
    assert other_training_calibration(None, own) is None
    spelled = pathlib.Path(os.path.relpath(own))
    assert other_training_calibration(spelled, own) is None


def test_h36m_trains_on_another_calibration_and_tests_on_the_reference(h36m_tree, tmp_path):
    """--data.cameras-path (e.g. a rig recovered by jaxpose.calibrate) reaches the training subjects
    only; the test subjects keep <data-dir>/cameras.h5, the frame of their ground truth."""
    data_dir = h36m_tree / "martinez"
    reference = read_h36m_cameras(data_dir / "cameras.h5")
    names, cameras = reference["S1"]
    moved = cameras.replace(t=cameras.t + np.float32(250.0))  # a different calibration of the same views
    recovered = tmp_path / "recovered.json"
    save_cameras(recovered, {"S1": (names, moved)})
    data = h36m.H36MData(data_dir=data_dir, detections="sh", train_subjects=("S1",), test_subjects=("S9",),
                         cameras_path=recovered)  # fmt: skip
    splits = h36m.load_splits(data)
    order = [names.index(name) for name in CAMERA_NAMES]
    np.testing.assert_allclose(splits.train.cameras_for(np.arange(2)).t, np.broadcast_to(moved.t[order], (2, 4, 3)))
    assert splits.train.samples.target3d is None  # the mocap frame's ground truth does not fit the new rig
    test_names, test_cameras = reference["S9"]
    np.testing.assert_allclose(
        splits.test.cameras_for(np.arange(2)).t,
        np.broadcast_to(test_cameras.t[[test_names.index(name) for name in CAMERA_NAMES]], (2, 4, 3)),
    )
    assert splits.test.samples.target3d is not None
    # The reference itself, however spelled, is no recalibration: the ground truth stays.
    same = dataclasses.replace(data, cameras_path=pathlib.Path(os.path.relpath(data_dir / "cameras.h5")))
    assert h36m.load_splits(same).train.samples.target3d is not None


def test_rig_from_h36m_never_writes_over_a_project_or_its_input(h36m_tree, tmp_path):
    data_dir, output = h36m_tree / "martinez", tmp_path / "rig"
    rig_from_h36m.main(["--data-dir", str(data_dir), "--output", str(output)])
    assert (output / "calibration.toml").is_file() and list(output.glob("*/detections.npz"))
    before = {path: path.read_bytes() for path in output.rglob("*") if path.is_file()}
    with pytest.raises(SystemExit, match=r"holds a project already .*pass --overwrite"):
        rig_from_h36m.main(["--data-dir", str(data_dir), "--output", str(output)])
    with pytest.raises(SystemExit, match="is this command's input --data-dir"):
        rig_from_h36m.main(["--data-dir", str(data_dir), "--output", str(data_dir), "--overwrite"])
    assert {path: path.read_bytes() for path in output.rglob("*") if path.is_file()} == before
    rig_from_h36m.main(["--data-dir", str(data_dir), "--output", str(output), "--overwrite"])
    assert {path: path.read_bytes() for path in output.rglob("*") if path.is_file()} == before  # same input, same bytes
    assert not list(output.rglob("*.partial*"))


def test_rig_from_h36m_writes_the_moved_session_through_the_moved_rig(h36m_tree, tmp_path):
    """--moved: those recordings' detections are the mocap through the moved cameras plus the detector's own
    residual (so the residual to the mocap's projection is the same through either rig); the others are
    written as without it, and moved_rig.npz holds a rig moved by 100-500 mm and turned by 1-3 degrees."""
    from jaxpose.calibration import compare_rigs
    from jaxpose.camera import Cameras, camera_centres, project
    from jaxpose.formats.calibration_files import read_rig_calibration

    data_dir = h36m_tree / "martinez"
    rig_from_h36m.main(["--data-dir", str(data_dir), "--output", str(tmp_path / "plain"), "--no-calibration"])
    rig_from_h36m.main(["--data-dir", str(data_dir), "--output", str(tmp_path / "moved"), "--no-calibration", "--moved", "Walk*"])
    with pytest.raises(SystemExit, match="matches no recording"):
        rig_from_h36m.main(["--data-dir", str(data_dir), "--output", str(tmp_path / "none"), "--moved", "Jumping*"])
    moved_file = np.load(tmp_path / "moved" / rig_from_h36m.MOVED_RIG_NPZ)
    true = read_rig_calibration(data_dir / "cameras.h5", subject="S1").select(CAMERA_NAMES, "test").cameras
    moved = Cameras(K=moved_file["K"], R=moved_file["R"], t=moved_file["t"], dist=moved_file["dist"], distortion_model=str(moved_file["distortion_model"]))
    shift = np.linalg.norm(camera_centres(moved.R, moved.t) - camera_centres(np.asarray(true.R, np.float64), np.asarray(true.t, np.float64)), axis=-1)
    turn = np.degrees(np.arccos(np.clip((np.einsum("cij,cij->c", moved.R, np.asarray(true.R, np.float64)) - 1) / 2, -1, 1)))
    assert ((100 <= shift) & (shift <= 500)).all() and ((1 <= turn) & (turn <= 3 + 1e-6)).all()
    np.testing.assert_array_equal(moved.K, np.asarray(true.K, np.float64))
    assert compare_rigs(moved.R, moved.t, np.asarray(true.R, np.float64), np.asarray(true.t, np.float64)).rotation_deg.max() > 0.5
    names = sorted(path.name for path in (tmp_path / "plain").iterdir() if path.is_dir())
    assert sorted(moved_file["recordings"].tolist()) == [name for name in names if name.startswith("Walk")] != []
    for name in names:
        plain, through = (np.load(tmp_path / kind / name / "detections.npz") for kind in ("plain", "moved"))
        truth = np.load(tmp_path / "plain" / name / "ground_truth.npz")["points3d"]
        if not name.startswith("Walk"):
            np.testing.assert_array_equal(plain["keypoints"], through["keypoints"])
            continue
        residual_true = plain["keypoints"] - np.asarray(project(true, truth[:, None]))
        residual_moved = through["keypoints"] - np.asarray(project(moved, truth[:, None]))
        np.testing.assert_allclose(residual_moved, residual_true, atol=0.05)
        assert np.abs(through["keypoints"] - plain["keypoints"]).max() > 10  # the cameras did move
