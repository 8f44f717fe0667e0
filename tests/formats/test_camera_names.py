"""Camera names across the tools (jaxpose.formats.camera_names): the names each tool gives one camera
find it in the calibrations of the others, a number is never a longer number, a guess by order is said,
and a partial match is refused naming the names at fault.  The real calibrations of `../shared/data/formats`
(skipped where absent) are matched against the folder names their tools write, through the readers."""

from __future__ import annotations

import logging

import numpy as np
import paths
import pytest
from hypothesis import given
from hypothesis import strategies as st

from jaxpose.formats import intrinsics
from jaxpose.formats.camera_names import CameraMismatch, camera_key, match_cameras
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.calibration_files import read_rig_calibration

POSE2SIM = paths.FORMATS / "pose2sim-calib-toml"
ANIPOSE = paths.FORMATS / "anipose-calibration-toml"


needs_real_files = pytest.mark.skipif(not paths.FORMATS.is_dir(), reason="needs ../shared/data/formats (real sample files)")


@pytest.mark.parametrize(
    "names",
    [
        ("cam_1", "cam1", "Cam1", "cam01", "cam_01", "CAM-001", "int_cam01_img", "ext_cam01_img", "cam01_json", "camera1"),
        ("1", "01", "001"),
    ],
)
def test_the_tools_spellings_of_one_camera_share_a_key(names):
    assert len({camera_key(name) for name in names}) == 1


def test_each_tools_names_find_the_others_cameras():
    pose2sim_scene = ["int_cam01_img", "int_cam02_img", "int_cam03_img", "int_cam04_img"]
    assert match_cameras(pose2sim_scene, ["cam02_json", "cam01_json"], "f") == {
        "cam02_json": "int_cam02_img", "cam01_json": "int_cam01_img"}  # fmt: skip
    assert match_cameras(["cam_01", "cam_02"], ["cam02", "cam01"], "f") == {"cam02": "cam_02", "cam01": "cam_01"}
    assert match_cameras(["cam_0", "cam_1"], ["cam1", "cam0"], "f") == {"cam1": "cam_1", "cam0": "cam_0"}  # Anipose
    freemocap = [f"sesh_2022-09-19_16_16_50_in_class_jsm_synced_Cam{i}" for i in (1, 2, 3)]
    assert match_cameras(freemocap, ["cam3", "Cam1"], "f") == {"cam3": freemocap[2], "Cam1": freemocap[0]}
    easymocap = [str(i) for i in range(1, 33)]
    assert match_cameras(easymocap, ["cam01", "cam11", "02"], "f") == {"cam01": "1", "cam11": "11", "02": "2"}
    assert match_cameras(["cam01", "cam11"], ["1", "11"], "f") == {"1": "cam01", "11": "cam11"}
    # The exact name wins over a looser match.
    assert match_cameras(["cam1", "cam_01x"], ["cam1"], "f") == {"cam1": "cam1"}


def test_a_number_is_never_a_longer_number():
    with pytest.raises(CameraMismatch, match=r"cameras \['cam11', 'cam12'\], which lack \['1', '2'\]"):
        match_cameras(["cam11", "cam12"], ["1", "2"], "f")


@pytest.mark.parametrize(
    "cameras, names, message",
    [
        (["cam1", "cam2"], ["cam1", "cam9"], r"which lack \['cam9'\]"),
        (["cam1", "cam_01", "cam2"], ["cam01"], r"where 'cam01' could be any of \['cam1', 'cam_01'\]"),
        (["cam1", "cam2"], ["cam1", "cam_01"], r"where \['cam1', 'cam_01'\] would all be 'cam1'"),
    ],
)
def test_a_partial_match_is_refused_naming_the_names(cameras, names, message):
    with pytest.raises(CameraMismatch, match=message):
        match_cameras(cameras, names, "f", by_order=True)


def test_by_order_only_when_allowed_and_nothing_matches(caplog):
    with pytest.raises(CameraMismatch, match="which lack"):
        match_cameras(["A", "B", "C"], ["cam1", "cam2", "cam10"], "calib.toml")
    with caplog.at_level(logging.WARNING, logger="jaxpose.formats.camera_names"):
        matched = match_cameras(["A", "B", "C"], ["cam10", "cam2", "cam1"], "calib.toml", by_order=True)
    assert matched == {"cam1": "A", "cam2": "B", "cam10": "C"}  # by the last number, as Pose2Sim sorts
    assert "calib.toml: no camera name matches" in caplog.text and "by order as Pose2Sim does" in caplog.text
    with pytest.raises(CameraMismatch):  # one name matching is no licence to pair the others by order
        match_cameras(["A", "cam2", "C"], ["cam1", "cam2", "cam3"], "f", by_order=True)
    with pytest.raises(CameraMismatch):  # nor are different counts
        match_cameras(["A", "B", "C"], ["cam1", "cam2"], "f", by_order=True)


SPELLINGS = [
    lambda i: f"cam{i}", lambda i: f"cam_{i:02d}", lambda i: f"Cam-{i:03d}", lambda i: f"int_cam{i:02d}_img",
    lambda i: f"cam{i:02d}_json", lambda i: f"CAMERA_{i}", lambda i: f"session_7_synced_Cam{i}",
]  # fmt: skip


@given(
    numbers=st.lists(st.integers(0, 120), min_size=1, max_size=8, unique=True),
    spelling=st.tuples(st.sampled_from(range(len(SPELLINGS))), st.sampled_from(range(len(SPELLINGS)))),
    order=st.randoms(use_true_random=False),
)
def test_any_two_spellings_of_a_rig_match_camera_for_camera(numbers, spelling, order):
    calibration = [SPELLINGS[spelling[0]](i) for i in numbers]
    folders = [SPELLINGS[spelling[1]](i) for i in numbers]
    order.shuffle(folders)
    matched = match_cameras(calibration, folders, "f")
    assert {name: calibration.index(camera) for name, camera in matched.items()} == {
        SPELLINGS[spelling[1]](i): k for k, i in enumerate(numbers)}  # fmt: skip


# ----------------------------------------------------------------------------------------------
# Through the readers: RigCalibration.select and predict --intrinsics


@needs_real_files
def test_pose2sim_scene_cameras_are_its_folders_cameras():
    rig = read_rig_calibration(POSE2SIM / "pose2sim_demo_Calib_scene.toml")
    picked = rig.select(["cam03", "cam01_json"], "detection folders")
    assert picked.camera_names == ("cam03", "cam01_json")
    np.testing.assert_array_equal(picked.cameras.K, rig.cameras.K[[2, 0]])


@needs_real_files
@pytest.mark.parametrize("camera", ["cam_01", "cam01", "int_cam01_img", "1"])
def test_intrinsics_of_a_pose2sim_camera_by_any_of_its_names(camera):
    path = POSE2SIM / "pose2sim_demo_Calib_scene.toml"
    read = intrinsics.read_intrinsics([str(path), camera])
    K = [[1671.5012042021037, 0, 564.6403499852015], [0, 1671.3866928599075, 933.0074897877159], [0, 0, 1]]
    np.testing.assert_allclose(read.K, K)
    assert read.image_size == (1088.0, 1920.0)


@needs_real_files
def test_intrinsics_of_a_camera_the_calibration_lacks_names_both():
    path = POSE2SIM / "pose2sim_demo_Calib_qualisys.toml"
    with pytest.raises(DataFormatError) as error:
        intrinsics.read_intrinsics([str(path), "cam_09"])
    message = str(error.value)
    assert message.startswith(str(path)) and "--intrinsics" in message and "cam_09" in message and "'cam_04'" in message


@needs_real_files
def test_intrinsics_never_pairs_by_order():
    with pytest.raises(DataFormatError, match=r"which lack \['left'\]"):
        intrinsics.read_intrinsics([str(ANIPOSE / "freemocap_2022_previous_calibration_fisheye.toml"), "left"])
