"""The real Human3.6M development set (subject S1 of the h36m.zip tree, with every subject's
cameras.h5), loaded unmodified, and its geometry checked against the detections.

These tests read `../shared/data/h36m_s1` beside the repository and skip, with the reason, where
it is absent (a user's fresh clone).  Thresholds come from the measured facts of the real files:
the ground truth projected through cameras.h5 lands a median of ~9 px from the Stacked Hourglass
detections (most joints 6-13 px; SH's "Spine" and "Head" are MPII joints: ~43 and ~24 px).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from experiments import h36m as h36m_experiment
from jaxpose.training import pseudo_labelling
from jaxpose.camera import camera_centres, project
from jaxpose.training.config import PseudoLabelConfig
from jaxpose.formats.h36m_cameras import read_h36m_cameras
from jaxpose.datasets.h36m import CAMERA_NAMES, load_h36m
import paths

S1_DIR = paths.H36M_S1
pytestmark = pytest.mark.skipif(
    not (S1_DIR / "cameras.h5").is_file(), reason=f"the real Human3.6M S1 development set is not at {S1_DIR}"
)


@pytest.fixture(scope="module")
def s1_sh():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # every S1 sequence has all four SH files and its 3D
        return load_h36m(S1_DIR, detections="sh", subjects=("S1",), train_stride=25, progress=False)


def test_real_cameras_h5_loads_with_float64_names():
    rigs = read_h36m_cameras(S1_DIR / "cameras.h5")
    assert sorted(rigs) == ["S1", "S11", "S5", "S6", "S7", "S8", "S9"]
    for names, cameras in rigs.values():
        assert sorted(names) == sorted(CAMERA_NAMES)
        rotations = np.asarray(cameras.R, np.float64)
        np.testing.assert_allclose(rotations @ rotations.transpose(0, 2, 1), np.broadcast_to(np.eye(3), (4, 3, 3)), atol=1e-5)
        np.testing.assert_allclose(np.linalg.det(rotations), 1.0, atol=1e-5)
        # Camera centres -R^T t stand 4-6 m from the capture volume's centre, ~1.5 m high.
        centres = camera_centres(cameras.R, cameras.t)
        distance = np.linalg.norm(centres[:, :2], axis=-1)
        assert np.all((distance > 3000) & (distance < 7000)), centres
        focal = np.asarray(cameras.K)[:, [0, 1], [0, 1]]
        assert np.all((focal > 1100) & (focal < 1200)), focal


def test_real_s1_loads_and_its_geometry_matches_the_detections(s1_sh):
    dataset = s1_sh
    assert dataset.num_views == 4 and dataset.skeleton.num_joints == 16
    assert len(set(dataset.samples.labels["sequence"])) == 30 and len(set(dataset.samples.labels["action"])) == 15
    np.testing.assert_array_equal(dataset.samples.confidence, 1.0)
    cameras = dataset.cameras_for(np.arange(len(dataset)))
    projected = np.asarray(project(cameras, dataset.samples.target3d[:, None]))
    error = np.linalg.norm(projected - dataset.samples.keypoints2d, axis=-1)  # [N, C, J] px
    median = dict(zip(dataset.skeleton.joint_names, np.median(error, axis=(0, 1))))
    agreeing = [median[name] for name in dataset.skeleton.joint_names if name not in ("Spine", "Head")]
    assert max(agreeing) < 18.0 and np.median(agreeing) < 12.0, median
    assert 25.0 < median["Spine"] < 70.0 and 12.0 < median["Head"] < 40.0, median  # MPII's thorax and head top
    # Every view agrees: a wrong camera order or a transposed rotation would put one view hundreds of pixels off.
    assert np.all(np.median(error, axis=(0, 2)) < 15.0)
    # The detections triangulate to within a few centimetres of the mocap for the agreeing joints.
    labelled = pseudo_labelling.label(dataset, PseudoLabelConfig(method="ransac"))
    label_error = np.median(np.linalg.norm(labelled.samples.pseudo3d - dataset.samples.target3d, axis=-1), axis=0)
    joint = dict(zip(dataset.skeleton.joint_names, label_error))
    assert joint["Thorax"] < 50 and joint["LShoulder"] < 50 and joint["RElbow"] < 60, joint


def test_missing_camera_file_keeps_the_other_views(tmp_path):
    # S11 "Directions" has only 3 of its 4 SH files in the real data; the same situation made from S1.
    root = tmp_path / "h36m"
    (root / "S1" / "StackedHourglass").mkdir(parents=True)
    (root / "S1" / "MyPoses").mkdir(parents=True)
    (root / "cameras.h5").symlink_to(S1_DIR / "cameras.h5")
    (root / "S1" / "MyPoses" / "3D_positions").mkdir()
    for name in ("Walking.h5", "Walking 1.h5"):
        (root / "S1" / "MyPoses" / "3D_positions" / name).symlink_to(S1_DIR / "S1" / "MyPoses" / "3D_positions" / name)
    for path in (S1_DIR / "S1" / "StackedHourglass").glob("Walking*.h5"):
        if path.name != "Walking_1.54138969.h5":
            (root / "S1" / "StackedHourglass" / path.name).symlink_to(path)
    with pytest.warns(UserWarning, match=r"S1 'Walking 1' \(no 2D for cameras \['54138969'\]\)"):
        dataset = load_h36m(root, detections="sh", subjects=("S1",), progress=False)
    partial = dataset.samples.labels["sequence"] == "Walking 1"
    assert partial.any() and (~partial).any()
    np.testing.assert_array_equal(dataset.samples.confidence[partial, 0], 0.0)
    np.testing.assert_array_equal(dataset.samples.confidence[partial, 1:], 1.0)
    assert (dataset.usable_view_count()[partial] == 3).all()


def test_development_split_trains_on_one_trial_and_tests_on_the_other():
    data = h36m_experiment.H36MData(
        data_dir=S1_DIR, detections="sh", train_subjects=("S1",), test_subjects=(), split="trials", train_stride=25, test_stride=25
    )
    splits = h36m_experiment.load_splits(data)
    train, test = set(splits.train.samples.labels["sequence"]), set(splits.test.samples.labels["sequence"])
    assert len(train) == len(test) == 15 and not train & test
    assert {"Walking", "Eating", "Sitting 1"} <= train and {"Walking 1", "Eating 2", "Sitting 2"} <= test
    assert set(splits.train.samples.labels["action"]) == set(splits.test.samples.labels["action"])
