"""HumanEva-I loading from fixture files in VideoPose3D's layout (tests/fixtures_real_data.py)."""

import logging
import shutil
import warnings

import numpy as np
import pytest

from fixtures_real_data import HUMANEVA_SEQUENCES, opencv_project, write_humaneva_files
from jaxpose.camera import project
from jaxpose.formats.errors import DataFormatError
from jaxpose.datasets.humaneva import TEST_ACTIONS, load_humaneva
from jaxpose.skeleton import HUMANEVA_15


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return write_humaneva_files(tmp_path_factory.mktemp("humaneva"), subjects=("S1", "S2"))


def _load(fixture, split, **kwargs):
    partition = "Train" if split == "train" else "Validate"
    return load_humaneva(fixture.root, split, subjects=(f"{partition}/S1", f"{partition}/S2"), progress=False, **kwargs)


def _check(dataset, fixture, partition, stride):
    for (key, sequence), poses in fixture.poses.items():
        subject = key.split("/")[1]
        if not key.startswith(partition) or sequence not in set(dataset.samples.labels["sequence"]):
            continue
        rows = np.flatnonzero((dataset.samples.labels["subject"] == subject) & (dataset.samples.labels["sequence"] == sequence))
        expected_frames = [f for f in range(0, len(poses), stride) if f not in fixture.invalid[key, sequence]]
        np.testing.assert_array_equal(dataset.samples.labels["frame"][rows], expected_frames)
        np.testing.assert_allclose(dataset.samples.target3d[rows], poses[expected_frames], atol=2e-3)  # metres -> mm
        for view, camera in enumerate(fixture.cameras[subject]):
            reference = opencv_project(camera, poses[expected_frames])
            np.testing.assert_allclose(dataset.samples.keypoints2d[rows, view], reference, atol=1e-3)
    cameras = dataset.cameras_for(np.arange(len(dataset)))
    np.testing.assert_allclose(np.asarray(project(cameras, dataset.samples.target3d[:, None])), dataset.samples.keypoints2d, atol=1e-3)


def test_train_split_all_actions_with_2d_file(files, caplog):
    with caplog.at_level(logging.INFO, logger="jaxpose.datasets.humaneva"):
        dataset = _load(files, "train", detections="detectron_pt_coco")
    assert dataset.skeleton == HUMANEVA_15 and dataset.num_views == 3
    assert set(dataset.samples.labels["action"]) == {"Walk", "Jog", "Box"}
    assert set(dataset.samples.labels["sequence"]) == set(HUMANEVA_SEQUENCES["Train"])
    assert set(dataset.samples.labels["subject"]) == {"S1", "S2"}
    dropped = 2 * len(HUMANEVA_SEQUENCES["Train"]) * 2  # frames 2 and 5 of every sequence
    assert f"dropped {dropped} of" in caplog.text
    assert np.isfinite(dataset.samples.target3d).all() and not (dataset.samples.target3d == 0).all(-1).any()
    _check(dataset, files, "Train", 1)


def test_test_split_walk_and_jog_only_ground_truth_2d(files):
    dataset = _load(files, "test", detections="gt", stride=2)
    assert set(dataset.samples.labels["action"]) == set(TEST_ACTIONS)
    assert set(dataset.samples.labels["sequence"]) == {"Walk 1 chunk0", "Jog 1 chunk0"}
    _check(dataset, files, "Validate", 2)
    path = files.root / "data_2d_humaneva15_detectron_pt_coco.npz"
    from_file = _load(files, "test", detections=str(path), stride=2)
    np.testing.assert_allclose(from_file.samples.keypoints2d, dataset.samples.keypoints2d, atol=1e-3)


def test_missing_views_get_confidence_zero_and_orphans_are_skipped(files, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(files.root, root)
    positions = np.load(root / "data_2d_humaneva15_detectron_pt_coco.npz", allow_pickle=True)["positions_2d"].item()
    positions["Train/S1"]["Walk 1 chunk0"] = positions["Train/S1"]["Walk 1 chunk0"][:2]
    positions["Train/S1"]["ThrowCatch 1 chunk0"] = positions["Train/S1"]["Box 1 chunk0"]
    np.savez(root / "data_2d_humaneva15_mine.npz", positions_2d=positions)
    with pytest.warns(UserWarning) as record:
        dataset = load_humaneva(root, "train", detections="mine", subjects=("Train/S1",), progress=False)
    messages = [str(warning.message) for warning in record]
    assert any("1 sequences miss some views" in m and "Train/S1 'Walk 1 chunk0' (no 2D for cameras ['C3'])" in m for m in messages)
    assert any("skipped 1 sequences" in m and "Train/S1 'ThrowCatch 1 chunk0' (2D without 3D)" in m for m in messages)
    walk = dataset.samples.labels["sequence"] == "Walk 1 chunk0"
    assert walk.any()
    np.testing.assert_array_equal(dataset.samples.confidence[walk, 2], 0.0)
    np.testing.assert_array_equal(dataset.samples.confidence[walk, :2], 1.0)
    np.testing.assert_array_equal(dataset.samples.confidence[~walk], 1.0)


def test_errors(files, tmp_path):
    def expect(match, root, split="train", **kwargs):
        kwargs.setdefault("subjects", ("Train/S1", "Train/S2") if split == "train" else ("Validate/S1",))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with pytest.raises(DataFormatError, match=match) as error:
                load_humaneva(root, split, progress=False, **kwargs)
        assert "Getting the data" in str(error.value)

    expect("cameras.json: expected a jaxpose camera file; found no such file", tmp_path)
    expect(r"cameras.json: expected cameras of subject 'S3'; found subjects \['S1', 'S2'\]", files.root, subjects=None)
    root = tmp_path / "copy"
    shutil.copytree(files.root, root)
    expect("data_2d_humaneva15_cpn.npz: expected .*no such file", root, detections="cpn")
    (root / "data_3d_humaneva15.npz").write_bytes(b"PK\x03\x04 truncated")
    expect(r"data_3d_humaneva15.npz: expected VideoPose3D HumanEva-I 3D poses \(an .npz file\)", root)
    np.savez(root / "data_3d_humaneva15.npz", positions_3d={"Train/S1": {"Walk 1 chunk0": np.zeros((4, 15, 2))}})
    expect(r"\['Train/S1'\]\['Walk 1 chunk0'\]: expected f\[N, 15, 3\] metres", root)
    expect(r"expected subject 'Validate/S1'", root, "test")


def test_argument_checks(files):
    with pytest.raises(ValueError, match="split"):
        load_humaneva(files.root, "validation")
    with pytest.raises(ValueError, match="subjects of the test split"):
        load_humaneva(files.root, "test", subjects=("Train/S1",))


def test_walking_spelled_either_way_is_a_walk_test_action():
    from jaxpose.datasets.humaneva import _action

    assert _action("Walk 1 chunk0") == _action("Walking 1 chunk3") == "Walk"
    assert _action("Jog 1 chunk0") == "Jog" and _action("ThrowCatch 1 chunk0") == "ThrowCatch"
