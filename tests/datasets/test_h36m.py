"""Human3.6M loading from fixture trees written in the real formats (tests/fixtures_real_data.py)."""

import shutil
import warnings

import h5py
import numpy as np
import pytest

from fixtures_real_data import (
    H36M_MOCAP_17,
    h36m_canonical_name,
    h36m_project,
    write_h36m_martinez_tree,
    write_h36m_videopose3d_files,
)
from jaxpose.camera import project
from jaxpose.formats.camera_file import convert_h36m_cameras
from jaxpose.formats.errors import DataFormatError
from jaxpose.datasets.h36m import CAMERA_NAMES, TEST_SUBJECTS, TRAIN_SUBJECTS, load_h36m, sequence_action
from jaxpose.skeleton import H36M_16, H36M_17

MOCAP_16 = [index for index, name in zip(H36M_MOCAP_17, H36M_17.joint_names) if name != "Neck/Nose"]


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    """S1 (training) and S9 (test); S9 'Walking 1' lacks camera 54138969, S9 has SH files
    'Eating_2' with no 3D file."""
    return write_h36m_martinez_tree(
        tmp_path_factory.mktemp("h36m"),
        missing_views={("S9", "Walking 1"): ("54138969",)},
        orphan_2d=(("S9", "Eating_2"),),
    )


def _load(root, **kwargs):
    kwargs.setdefault("subjects", ("S1", "S9"))
    return load_h36m(root, progress=False, **kwargs)


def _check_against_fixture(dataset, fixture, mocap_joints, strides):
    """Every sample's 3D is the fixture's mocap at its frame, and its 2D is the documented
    projection of that 3D (so joint order, units, camera conventions and distortion all agree)."""
    for subject, stride in strides.items():
        for (fixture_subject, sequence), mocap in fixture.mocap.items():
            if fixture_subject != subject:
                continue
            rows = np.flatnonzero((dataset.samples.labels["subject"] == subject) & (dataset.samples.labels["sequence"] == sequence))
            if not len(rows):
                continue
            frames = dataset.samples.labels["frame"][rows]
            np.testing.assert_array_equal(frames, np.arange(0, len(mocap), stride))
            expected3d = mocap[frames][:, mocap_joints]
            np.testing.assert_allclose(dataset.samples.target3d[rows], expected3d, atol=2e-3)
            for view, camera in enumerate(fixture.cameras[subject]):
                present = dataset.samples.confidence[rows, view, 0] > 0  # a missing view's file was not written
                reference = h36m_project(camera, expected3d[present])
                np.testing.assert_allclose(dataset.samples.keypoints2d[rows[present], view], reference, atol=1e-3)
    # The loaded cameras reproduce the 2D from the 3D through jaxpose.camera.project.
    cameras = dataset.cameras_for(np.arange(len(dataset)))
    projected = np.asarray(project(cameras, dataset.samples.target3d[:, None]))
    present = dataset.samples.confidence > 0
    np.testing.assert_allclose(projected[present], dataset.samples.keypoints2d[present], atol=1e-3)


def test_martinez_stacked_hourglass(tree):
    with pytest.warns(UserWarning) as record:
        dataset = _load(tree.root, train_stride=5, test_stride=2)
    messages = [str(warning.message) for warning in record]
    assert {warning.filename for warning in record} == {__file__}  # attributed to the loader's caller
    assert any("1 sequences miss some views" in m and "S9 'Walking 1' (no 2D for cameras ['54138969'])" in m for m in messages)
    assert any("skipped 1 sequences" in m and "S9 'Eating_2' (2D without 3D)" in m for m in messages)
    assert dataset.skeleton == H36M_16 and dataset.num_views == 4
    assert dataset.samples.keypoints2d.dtype == np.float32 and dataset.samples.target3d.dtype == np.float32
    assert set(dataset.samples.labels) == {"subject", "action", "sequence", "frame"}
    assert set(dataset.samples.labels["action"]) == {"Directions", "Photo", "WalkDog", "Walking"}
    s9_sequences = {"Directions 1", "TakingPhoto", "WalkingDog 1", "Walking 1"}
    assert set(dataset.where(subject="S9").samples.labels["sequence"]) == s9_sequences
    assert "TakingPhoto" in set(dataset.samples.labels["sequence"])
    # The sequence without camera 54138969's file keeps its three other views; the missing one has
    # confidence 0 (and coordinates 0), every other view confidence 1.
    partial = (dataset.samples.labels["subject"] == "S9") & (dataset.samples.labels["sequence"] == "Walking 1")
    np.testing.assert_array_equal(dataset.samples.confidence[partial, 0], 0.0)
    np.testing.assert_array_equal(dataset.samples.keypoints2d[partial, 0], 0.0)
    np.testing.assert_array_equal(dataset.samples.confidence[partial, 1:], 1.0)
    np.testing.assert_array_equal(dataset.samples.confidence[~partial], 1.0)
    _check_against_fixture(dataset, tree, MOCAP_16, {"S1": 5, "S9": 2})
    assert dataset.rigs.K.shape == (2, 4, 3, 3) and dataset.rigs.distortion_model == "h36m"


def test_ground_truth_2d_projects_with_distortion(tree):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # "gt" reads no 2D files, so nothing is skipped
        dataset = _load(tree.root, detections="gt", train_stride=3, test_stride=1)
    assert dataset.skeleton == H36M_17
    assert "Walking 1" in set(dataset.where(subject="S9").samples.labels["sequence"])
    _check_against_fixture(dataset, tree, list(H36M_MOCAP_17), {"S1": 3, "S9": 1})


def test_videopose3d_layout_with_json_cameras(tree, tmp_path):
    write_h36m_videopose3d_files(tmp_path, tree, extra_2d_frames=3, drop_views={("S1", "Walking 1"): 1})
    convert_h36m_cameras(tree.root / "cameras.h5", tmp_path / "cameras.json")
    with pytest.warns(UserWarning, match=r"miss some views.*S1 'Walking 1' \(no 2D for cameras \['60457274'\]\)"):
        dataset = _load(tmp_path, detections="cpn", cameras_path=tmp_path / "cameras.json", test_stride=4)
    assert dataset.skeleton == H36M_17
    walking = dataset.samples.labels["sequence"] == "Walking 1"
    assert walking.any() and (dataset.samples.confidence[walking & (dataset.samples.labels["subject"] == "S1"), 3] == 0).all()
    # Sequence labels are the 3D file's names, here VideoPose3D's ("Photo", "WalkDog 1").
    assert set(dataset.samples.labels["sequence"]) == {"Directions 1", "Photo", "WalkDog 1", "Walking 1"}
    renamed_mocap = {(subject, h36m_canonical_name(name)): m for (subject, name), m in tree.mocap.items()}
    renamed = type(tree)(tree.root, tree.cameras, renamed_mocap)
    _check_against_fixture(dataset, renamed, list(H36M_MOCAP_17), {"S1": 5, "S9": 4})


def test_martinez_3d_with_npz_2d_matches_renamed_sequences(tree, tmp_path):
    write_h36m_videopose3d_files(tmp_path, tree, detector_file="my_detector.npz")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every sequence finds its 2D despite the renaming
        dataset = _load(tree.root, detections=tmp_path / "my_detector.npz", subjects=("S1",))
    assert set(dataset.samples.labels["sequence"]) == {"Directions 1", "TakingPhoto", "WalkingDog 1", "Walking 1"}
    _check_against_fixture(dataset, tree, list(H36M_MOCAP_17), {"S1": 5})


@pytest.mark.parametrize(
    "name, action",
    [
        ("Walking 1", "Walking"),
        ("Walking", "Walking"),
        ("TakingPhoto_1", "Photo"),
        ("Photo 2", "Photo"),
        ("WalkingDog", "WalkDog"),
        ("WalkDog 1", "WalkDog"),
        ("SittingDown 2", "SittingDown"),
        ("WalkTogether", "WalkTogether"),
    ],
)
def test_sequence_action(name, action):
    assert sequence_action(name) == action


def test_subject_constants():
    assert TRAIN_SUBJECTS == ("S1", "S5", "S6", "S7", "S8") and TEST_SUBJECTS == ("S9", "S11")
    assert CAMERA_NAMES == ("54138969", "55011271", "58860488", "60457274")


def _copy(tree, tmp_path):
    root = tmp_path / "copy"
    shutil.copytree(tree.root, root)
    return root


def _expect_error(root, match, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(DataFormatError, match=match) as error:
            _load(root, **kwargs)
    assert "Getting the data" in str(error.value)
    return str(error.value)


def test_missing_folders_and_files(tree, tmp_path):
    _expect_error(tmp_path / "nowhere", "no such folder")
    (tmp_path / "empty").mkdir()
    _expect_error(tmp_path / "empty", "MyPoses/3D_positions")
    root = _copy(tree, tmp_path)
    _expect_error(root, "cameras of subject 'S11'", subjects=("S1", "S11"))
    shutil.rmtree(root / "S9" / "StackedHourglass")
    _expect_error(root, r"S9/StackedHourglass: expected Stacked Hourglass files .*; found no such folder")
    shutil.rmtree(root / "S9" / "MyPoses")
    _expect_error(root, r"S9/MyPoses/3D_positions: expected 3D pose files <Sequence>.h5; found no such folder")
    (root / "cameras.h5").unlink()
    _expect_error(root, r"cameras.h5: expected .*; found no such file")


def test_empty_and_truncated_h5_files(tree, tmp_path):
    root = _copy(tree, tmp_path)
    (root / "S1" / "MyPoses" / "3D_positions" / "Walking 1.h5").write_bytes(b"")
    _expect_error(root, r"Walking 1.h5: expected Human3.6M 3D poses \(an HDF5 file\); found a file h5py cannot read")
    root = _copy(tree, tmp_path / "2")
    sh_file = root / "S1" / "StackedHourglass" / "TakingPhoto.55011271.h5"
    sh_file.write_bytes(sh_file.read_bytes()[:1000])
    _expect_error(root, "TakingPhoto.55011271.h5: expected Stacked Hourglass detections")


def test_wrong_shapes_and_lengths(tree, tmp_path):
    root = _copy(tree, tmp_path)
    with h5py.File(root / "S1" / "StackedHourglass" / "Directions_1.54138969.h5", "a") as file:
        del file["poses"]
        file["poses"] = np.zeros((5, 16, 2), np.float32)  # fewer frames than the 3D
    _expect_error(root, r"'Directions 1', camera 54138969: expected 2D for all \d+ frames of the 3D sequence; found 5 frames")
    with h5py.File(root / "S1" / "StackedHourglass" / "Directions_1.54138969.h5", "a") as file:
        del file["poses"]
        file["poses"] = np.zeros((30, 17, 2), np.float32)
    _expect_error(root, r"expected dataset poses of shape \(N, 16, 2\); found shape \(30, 17, 2\)")
    with h5py.File(root / "S1" / "MyPoses" / "3D_positions" / "Walking 1.h5", "a") as file:
        del file["3D_positions"]
        file["wrong_name"] = np.zeros((96, 4))
    match = r"expected Human3.6M 3D poses: a dataset '3D_positions'; found only \['wrong_name'\]"
    _expect_error(root, match, detections="gt")


def test_malformed_npz_files(tree, tmp_path):
    write_h36m_videopose3d_files(tmp_path, tree)
    shutil.copy(tree.root / "cameras.h5", tmp_path)
    (tmp_path / "empty.npz").write_bytes(b"")
    match = r"empty.npz: expected VideoPose3D 2D detections \(an .npz file\)"
    _expect_error(tmp_path, match, detections=tmp_path / "empty.npz")
    data = (tmp_path / "data_3d_h36m.npz").read_bytes()
    (tmp_path / "data_3d_h36m.npz").write_bytes(data[: len(data) // 2])
    _expect_error(tmp_path, r"data_3d_h36m.npz: expected VideoPose3D 3D poses \(an .npz file\)", detections="gt")
    np.savez(tmp_path / "data_3d_h36m.npz", something=np.zeros(3))
    match = r"expected VideoPose3D 3D poses: an array 'positions_3d'; found only \['something'\]"
    _expect_error(tmp_path, match, detections="gt")
    np.savez(tmp_path / "data_3d_h36m.npz", positions_3d={"S1": {"Walking 1": np.zeros((4, 17, 3))}})
    match = r"\['S1'\]\['Walking 1'\]: expected f\[N, 32, 3\] metres"
    _expect_error(tmp_path, match, detections="gt", subjects=("S1",))
    match = r"positions_3d: expected subject 'S9'; found subjects \['S1'\]"
    _expect_error(tmp_path, match, detections="gt", subjects=("S9",))


def test_npz_with_16_joint_2d_is_rejected(tree, tmp_path):
    write_h36m_videopose3d_files(tmp_path, tree)
    np.savez(tmp_path / "sh16.npz", positions_2d={"S1": {"Walking 1": [np.zeros((30, 16, 2))] * 4}})
    match = r"camera 54138969: expected f\[N, 17, 2\] pixels; found shape \(30, 16, 2\)"
    _expect_error(tree.root, match, detections=tmp_path / "sh16.npz", subjects=("S1",))
