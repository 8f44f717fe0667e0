"""The calibration files users bring (jaxpose.formats.calibration_files and the readers and writer it
dispatches to: anipose_toml, easymocap_yaml, camera_file, h36m_cameras), and the fisheye lens model.

The real files are those of `../shared/data/formats` (their README lists each one's quirks); tests
that need them skip where that folder is absent.  The fixtures (tests/calibration_writers.py) mirror the
real files' layouts.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from calibration_writers import aniposelib_style_toml, synthetic_rig, write_easymocap
from scipy.spatial.transform import Rotation

from jaxpose.camera import Cameras, camera_centres, project, undistort_points
from jaxpose.formats.anipose_toml import write_anipose_toml
from jaxpose.formats.camera_file import save_cameras
from jaxpose.formats.easymocap_yaml import read_easymocap_intrinsics
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.h36m_cameras import opencv_from_h36m_distortion, opencv_rig_from_h36m
from jaxpose.formats.calibration_files import RigCalibration, find_calibration, read_rig_calibration
from jaxpose.rotations import rotation_from_rodrigues
import paths

SHARED = paths.SHARED_DATA.parent
FORMATS = SHARED / "data" / "formats"
ANIPOSE = FORMATS / "anipose-calibration-toml"
POSE2SIM = FORMATS / "pose2sim-calib-toml"
EASYMOCAP = FORMATS / "easymocap-yml"
H36M_CAMERAS = SHARED / "data" / "h36m_s1" / "cameras.h5"

MOUSE = "aniposelib_tests_7cam-allen-mouse_calibration.toml"
MOUSE_CONFIG = "aniposelib_tests_7cam-allen-mouse_config.toml"
FREEMOCAP = "freemocap_test_data_camera_calibration.toml"
FISHEYE = "freemocap_2022_previous_calibration_fisheye.toml"
QUALISYS = "pose2sim_demo_Calib_qualisys.toml"
SCENE = "pose2sim_demo_Calib_scene.toml"
SARKADAVA = "sarkadava_demo_Calib_checkerboard.toml"
REAL_TOMLS = [ANIPOSE / MOUSE, ANIPOSE / FREEMOCAP, ANIPOSE / FISHEYE]
REAL_TOMLS += [POSE2SIM / QUALISYS, POSE2SIM / SCENE, POSE2SIM / SARKADAVA]


def real(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"{path} is absent (the real example files live in ../shared)")
    return path


def read_quietly(path, **kwargs) -> RigCalibration:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_rig_calibration(path, **kwargs)


def check_geometry(rig: RigCalibration) -> None:
    """What every rig read from a file must satisfy."""
    count = len(rig.camera_names)
    assert rig.cameras.K.shape == (count, 3, 3) and rig.cameras.K.dtype == np.float64
    assert rig.cameras.R.shape == (count, 3, 3) and rig.cameras.t.shape == (count, 3)
    assert rig.cameras.t.dtype == np.float64
    identity = np.broadcast_to(np.eye(3), (count, 3, 3))
    np.testing.assert_allclose(rig.cameras.R @ np.swapaxes(rig.cameras.R, 1, 2), identity, atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(rig.cameras.R), 1.0, atol=1e-9)
    if rig.cameras.dist is not None:
        assert rig.cameras.dist.shape == (count, 5)
    if rig.image_size is not None:
        assert rig.image_size.shape == (count, 2) and rig.image_size.dtype == np.int64
    centres = camera_centres(rig.cameras.R, rig.cameras.t)
    distances = np.linalg.norm(centres[:, None] - centres[None], axis=-1)[np.triu_indices(count, 1)]
    assert np.all(distances > 50.0) and np.all(distances < 20_000.0), distances  # distinct cameras, a room-sized rig
    assert rig.rig_size_mm() == pytest.approx(distances.max())


def raw_tables(path: Path) -> list[dict]:
    import tomllib

    return [table for key, table in tomllib.loads(path.read_text()).items() if key != "metadata" and isinstance(table, dict)]


def assert_same_rig(read: RigCalibration, expected: RigCalibration, rtol=1e-9) -> None:
    assert read.camera_names == expected.camera_names
    assert read.cameras.distortion_model == expected.cameras.distortion_model
    for field in ("K", "t"):
        np.testing.assert_allclose(getattr(read.cameras, field), getattr(expected.cameras, field), rtol=rtol, atol=1e-12)
    np.testing.assert_allclose(read.cameras.R, expected.cameras.R, rtol=0, atol=1e-12)
    if expected.cameras.dist is None or read.cameras.dist is None:
        assert read.cameras.dist is None or not np.any(read.cameras.dist)
        assert expected.cameras.dist is None or not np.any(expected.cameras.dist)
    else:
        np.testing.assert_allclose(read.cameras.dist, expected.cameras.dist, rtol=rtol, atol=1e-15)
    if expected.image_size is None:
        assert read.image_size is None
    else:
        np.testing.assert_array_equal(read.image_size, expected.image_size)


# ----------------------------------------------------------------------------------------------
# Real Anipose-family TOML files


def test_aniposelib_mouse_rig_reads_as_millimetres():
    path = real(ANIPOSE / MOUSE)
    rig = read_rig_calibration(path)
    check_geometry(rig)
    assert rig.camera_names == ("cam088", "cam091", "cam581", "cam592", "cam593", "cam712", "cam746")
    assert rig.unit == "mm" and rig.source == str(path)
    assert rig.rig_size_mm() == pytest.approx(1578.857, abs=1e-2)
    np.testing.assert_array_equal(rig.image_size, np.tile([1440, 1080], (7, 1)))
    tables = raw_tables(path)
    np.testing.assert_array_equal(rig.cameras.t, [table["translation"] for table in tables])  # mm: unchanged
    rotations = Rotation.from_rotvec([table["rotation"] for table in tables]).as_matrix()
    np.testing.assert_allclose(rig.cameras.R, rotations, atol=1e-14)
    assert rig.cameras.distortion_model == "opencv"
    np.testing.assert_array_equal(rig.cameras.dist[:, 0], [table["distortions"][0] for table in tables])
    assert not np.any(rig.cameras.dist[:, 1:])


def test_freemocap_files_one_with_fisheye_lenses():
    rig = read_rig_calibration(real(ANIPOSE / FREEMOCAP))
    check_geometry(rig)
    assert len(rig.camera_names) == 3 and rig.camera_names[0].endswith("_Cam1") and rig.unit == "mm"
    np.testing.assert_array_equal(rig.cameras.t[0], 0.0)
    np.testing.assert_array_equal(rig.image_size, np.tile([720, 1280], (3, 1)))  # portrait, (W, H)
    assert rig.rig_size_mm() == pytest.approx(2697.572, abs=1e-2)

    path = real(ANIPOSE / FISHEYE)  # fisheye = true, 4 coefficients, an empty [metadata]
    rig = read_rig_calibration(path)
    check_geometry(rig)
    assert rig.camera_names == ("1", "2", "3", "4", "5") and rig.unit == "mm"
    assert rig.cameras.distortion_model == "fisheye"
    np.testing.assert_array_equal(rig.cameras.dist[:, :4], [table["distortions"] for table in raw_tables(path)])
    np.testing.assert_array_equal(rig.cameras.dist[:, 4], 0.0)


def test_pose2sim_files_read_as_metres_converted_to_millimetres():
    rigs = {}
    for name, cameras, size in [(QUALISYS, 4, [1088, 1920]), (SCENE, 4, [1088, 1920]), (SARKADAVA, 3, [540, 960])]:
        path = real(POSE2SIM / name)
        rig = read_rig_calibration(path)
        check_geometry(rig)
        assert rig.unit == "m" and len(rig.camera_names) == cameras
        np.testing.assert_array_equal(rig.image_size, np.tile(size, (cameras, 1)))  # [1088.0, 1920.0] floats in the file
        tables = raw_tables(path)
        np.testing.assert_array_equal(rig.cameras.t, np.array([table["translation"] for table in tables]) * 1000.0)
        np.testing.assert_array_equal(rig.cameras.dist[:, :4], [table["distortions"] for table in tables])
        np.testing.assert_array_equal(rig.cameras.dist[:, 4], 0.0)  # 4 coefficients: k3 = 0
        rigs[name] = rig
    assert rigs[QUALISYS].camera_names == ("cam_01", "cam_02", "cam_03", "cam_04")
    assert rigs[SCENE].camera_names == ("int_cam01_img", "int_cam02_img", "int_cam03_img", "int_cam04_img")
    assert rigs[SARKADAVA].camera_names == ("cam1", "cam2", "cam3")
    # Calib_qualisys and Calib_scene calibrate the same four cameras two ways: same places.
    centres = [camera_centres(rigs[name].cameras.R, rigs[name].cameras.t) for name in (QUALISYS, SCENE)]
    assert np.linalg.norm(centres[0] - centres[1], axis=1).max() < 250.0
    assert rigs[QUALISYS].rig_size_mm() == pytest.approx(6689.184, abs=1e-2)


def test_pose2sim_demo_triangulation_projects_onto_its_detections():
    """The demo's own 3D result (TRC, metres, OpenSim's y-up axes) through the calibration as read
    lands on the demo's OpenPose detections: checks R's direction, t's metres -> mm, K and the order."""
    trc = real(FORMATS / "trc" / "pose2sim_demo_BalancingTrial_0-100.trc").read_text().splitlines()
    markers = [name for name in trc[3].split("\t")[2:] if name]
    rows = np.array([[float(value) for value in line.split("\t")] for line in trc[5:] if line.strip()])
    body_25b = {"RHip": 12, "RKnee": 14, "RAnkle": 16, "LHip": 11, "LKnee": 13, "LAnkle": 15, "RShoulder": 6, "RElbow": 8,
                "RWrist": 10, "LShoulder": 5, "LElbow": 7, "LWrist": 9, "Nose": 0, "Neck": 17, "Head": 18, "RBigToe": 22,
                "LBigToe": 19, "RHeel": 24, "LHeel": 21, "RSmallToe": 23, "LSmallToe": 20}  # fmt: skip
    joints = [body_25b[name] for name in markers]
    rig = read_rig_calibration(real(POSE2SIM / QUALISYS))
    errors = []
    for frame in (0, 19):
        yup = rows[frame, 2:].reshape(-1, 3)
        world = np.stack([yup[:, 2], yup[:, 0], yup[:, 1]], axis=-1) * 1000.0  # y-up (Y, Z, X) back to z-up mm
        pixels = np.asarray(project(rig.cameras, np.broadcast_to(world, (4, *world.shape))))
        for c in range(4):
            folder = FORMATS / "openpose-json" / "pose2sim_demo_balancing_body25b" / f"cam0{c + 1}_json"
            people = json.loads((folder / f"cam0{c + 1}.{frame:04d}.json").read_text())["people"]
            poses = [np.reshape(person["pose_keypoints_2d"], (-1, 3))[joints] for person in people]
            pose = min(poses, key=lambda p: np.median(np.linalg.norm(p[:, :2] - pixels[c], axis=1)))
            errors += list(np.linalg.norm(pose[:, :2] - pixels[c], axis=1)[pose[:, 2] > 0.3])
    assert np.median(errors) < 20.0, np.median(errors)


# ----------------------------------------------------------------------------------------------
# Real EasyMocap files


def test_easymocap_trackmesh_rig_is_the_cameras_of_both_files():
    folder = real(EASYMOCAP / "trackmesh_gui")
    with pytest.warns(UserWarning, match=r"'1', '10'.*left out"):
        rig = read_rig_calibration(folder)
    check_geometry(rig)
    assert rig.camera_names == ("11", "12", "13", "15", "17", "19", "25", "27", "31", "7", "9")  # intri's order
    assert rig.unit == "m" and rig.image_size is None
    assert str(folder / "intri.yml") in rig.source and str(folder / "extri.yml") in rig.source
    np.testing.assert_allclose(rig.cameras.t[0], np.array([0.327633, 1.096058, 3.260243]) * 1000.0, rtol=1e-12)
    np.testing.assert_allclose(rig.cameras.R[0, 0], [0.287431, -0.957452, -0.025882], atol=2e-6)
    np.testing.assert_allclose(rig.cameras.R[0], rotation_from_rodrigues(np.array([1.631797, -1.236095, 0.801056])), atol=1e-5)
    np.testing.assert_allclose(rig.cameras.K[0], [[1605.067049, 0, 1002.329321], [0, 1611.179942, 533.332415], [0, 0, 1]])
    assert 2000.0 < rig.rig_size_mm() < 10_000.0
    # The same rig from either file's path.
    assert read_quietly(folder / "extri.yml").camera_names == rig.camera_names


def test_easymocap_rodrigues_as_a_row_vector_and_wrapped_lists():
    path = real(EASYMOCAP / "a-nerf" / "intri.yml")
    rig = read_rig_calibration(path)
    check_geometry(rig)
    assert rig.camera_names == ("2", "3", "4", "5", "6", "7") and rig.cameras.dist is None  # all-zero dist
    np.testing.assert_array_equal(rig.cameras.K[:, :2, 2], np.tile([960.0, 540.0], (6, 1)))
    np.testing.assert_allclose(rig.cameras.t[0], [138.11055048575024, 139.41702782968118, 5865.3820170920312], rtol=1e-14)
    rodrigues = np.array([1.7333808154182149, 0.27177228964133848, -0.21631450334637528])  # R_2, 1x3
    np.testing.assert_allclose(rig.cameras.R[0], rotation_from_rodrigues(rodrigues), atol=1e-9)


def test_easymocap_intrinsics_without_extrinsics_is_refused_clearly():
    folder = real(EASYMOCAP / "easymocap_examples_calibration")
    names, intrinsics = read_easymocap_intrinsics(folder / "intri.yml")  # the parser alone reads it
    assert names == [str(index) for index in range(1, 9)]
    K = np.array([[909.27224982003611, 0.0, 960.62674039097942], [0.0, 924.44288845626772, 542.93008226872905], [0, 0, 1]])
    np.testing.assert_allclose(intrinsics["1"][0], K, rtol=1e-15)  # wrapped over two lines in the file
    # Six different K: the formats README's "the same K for every cam" holds for cams 1-3 only.
    assert len({intrinsics[name][0].tobytes() for name in names}) == 6
    assert all(not np.any(intrinsics[name][1]) for name in names)
    with pytest.raises(DataFormatError, match=r"extri\.yml.*poses.*no such file"):
        read_rig_calibration(folder / "intri.yml")
    with pytest.raises(DataFormatError, match=r"extri\.yml"):
        read_rig_calibration(folder)


# ----------------------------------------------------------------------------------------------
# EasyMocap fixtures in both writers' layouts


@pytest.mark.parametrize("wrap, rodrigues", [(True, "1x3"), (False, "3x1")])
def test_easymocap_fixture_both_layouts(tmp_path, wrap, rodrigues):
    rig = synthetic_rig(5, seed=1, with_size=False)
    write_easymocap(tmp_path, rig, wrap=wrap, rodrigues=rodrigues)
    read = read_rig_calibration(tmp_path / "intri.yml")
    tolerance = 1e-12 if wrap else 1e-5  # %.16e or %.6f
    np.testing.assert_allclose(read.cameras.t, rig.cameras.t, atol=tolerance * 1000)
    np.testing.assert_allclose(read.cameras.R, rig.cameras.R, atol=tolerance)
    np.testing.assert_allclose(read.cameras.dist, rig.cameras.dist, atol=tolerance)
    assert read.camera_names == rig.camera_names and read.unit == "m"
    assert read_rig_calibration(tmp_path, unit="m").camera_names == rig.camera_names  # the folder


def test_easymocap_refusals(tmp_path):
    rig = synthetic_rig(3, seed=2)
    write_easymocap(tmp_path / "apart", rig, intri_names=["cam0"], extri_names=["cam1", "cam2"])
    with pytest.raises(DataFormatError, match=r"cameras present in both files.*\['cam0'\].*\['cam1', 'cam2'\]"):
        read_rig_calibration(tmp_path / "apart")
    write_easymocap(tmp_path / "disagree", rig, rotation_noise=0.05)
    with pytest.raises(DataFormatError, match=r"Rot_cam0.*R_cam0.*degrees apart"):
        read_rig_calibration(tmp_path / "disagree")
    write_easymocap(tmp_path / "metres", rig)  # metres, read as millimetres: a rig a few mm across
    with pytest.raises(DataFormatError, match=r"read in 'mm'.*--data\.calibration-unit"):
        read_rig_calibration(tmp_path / "metres", unit="mm")
    text = (tmp_path / "apart" / "intri.yml").read_text().replace("rows: 3", "rows: 2", 1)
    (tmp_path / "apart" / "intri.yml").write_text(text)
    with pytest.raises(DataFormatError, match=r"K_cam0.*line 5.*rows x cols"):
        read_rig_calibration(tmp_path / "apart")


# ----------------------------------------------------------------------------------------------
# Refusals and select


def test_implausible_unit_is_refused_with_the_numbers():
    path = real(POSE2SIM / QUALISYS)
    with pytest.raises(DataFormatError) as error:
        read_rig_calibration(path, unit="mm")
    message = str(error.value)
    assert str(path) in message and "'mm'" in message and "6.68918 mm" in message and "--data.calibration-unit" in message
    with pytest.raises(DataFormatError, match=r"1\.57886e\+06 mm.*'m'"):
        read_rig_calibration(real(ANIPOSE / MOUSE), unit="m")
    assert read_rig_calibration(path, unit="m").unit == "m"


def test_centimetres_must_be_given(tmp_path):
    rig = synthetic_rig(4, seed=3)
    path = tmp_path / "calibration.toml"
    path.write_text(aniposelib_style_toml(rig, scale=10.0))
    read = read_rig_calibration(path, unit="cm")
    np.testing.assert_allclose(read.cameras.t, rig.cameras.t, rtol=1e-12)
    assert read_rig_calibration(path).unit == "mm"  # "auto" cannot tell cm from mm (documented)


def test_malformed_camera_tables_are_named(tmp_path):
    text = real(ANIPOSE / MOUSE).read_text()
    lines = text.splitlines()
    start = lines.index("[cam_2]")
    broken = lines[: start + 3] + lines[start + 4 :]  # drop cam_2's matrix
    (tmp_path / "no_matrix.toml").write_text("\n".join(broken))
    with pytest.raises(DataFormatError, match=r"no_matrix\.toml: table \[cam_2\].*no 'matrix'"):
        read_rig_calibration(tmp_path / "no_matrix.toml")
    short = text.replace("distortions = [ -0.16089133125720043, 0.0, 0.0, 0.0, 0.0,]", "distortions = [ 0.1, 0.0, 0.0,]")
    (tmp_path / "short.toml").write_text(short)
    with pytest.raises(DataFormatError, match=r"table \[cam_2\], key 'distortions'.*4 or 5.*shape \[3\]"):
        read_rig_calibration(tmp_path / "short.toml")
    (tmp_path / "twice.toml").write_text(text.replace('name = "cam091"', 'name = "cam088"'))
    with pytest.raises(DataFormatError, match=r"distinct camera names.*cam088"):
        read_rig_calibration(tmp_path / "twice.toml")
    fisheye = real(ANIPOSE / FISHEYE).read_text()
    (tmp_path / "mixed.toml").write_text(fisheye.replace("fisheye = true", "fisheye = false", 1))
    with pytest.raises(DataFormatError, match=r"fisheye = true in \['cam_1', 'cam_2', 'cam_3', 'cam_4'\] only"):
        read_rig_calibration(tmp_path / "mixed.toml")
    (tmp_path / "bad.toml").write_text("[cam_0\nname = 1")
    with pytest.raises(DataFormatError, match=r"bad\.toml.*invalid TOML"):
        read_rig_calibration(tmp_path / "bad.toml")
    with pytest.raises(DataFormatError, match=r"no camera table.*'pipeline'"):
        read_rig_calibration(real(ANIPOSE / MOUSE_CONFIG))
    with pytest.raises(DataFormatError, match="no such file"):
        read_rig_calibration(tmp_path / "absent.toml")


def test_select_reorders_and_names_what_is_missing():
    rig = synthetic_rig(4)
    picked = rig.select(["cam2", "cam0"], "detection folders of recording walk1")
    assert picked.camera_names == ("cam2", "cam0")
    np.testing.assert_array_equal(picked.cameras.K, rig.cameras.K[[2, 0]])
    np.testing.assert_array_equal(picked.cameras.dist, rig.cameras.dist[[2, 0]])
    np.testing.assert_array_equal(picked.image_size, rig.image_size[[2, 0]])
    with pytest.raises(DataFormatError) as error:
        rig.select(["cam0", "camX"], "detection folders of recording walk1")
    message = str(error.value)
    assert message.startswith("synthetic:") and "detection folders of recording walk1" in message
    assert "['cam0', 'camX']" in message and "['cam0', 'cam1', 'cam2', 'cam3']" in message and "['camX']" in message


# ----------------------------------------------------------------------------------------------
# Round trips


def test_every_real_toml_round_trips(tmp_path):
    for path in REAL_TOMLS:
        rig = read_rig_calibration(real(path))
        for unit in ("m", "mm"):
            out = tmp_path / f"{unit}_{path.name}"
            write_anipose_toml(out, rig, unit=unit)
            again = read_rig_calibration(out)
            assert again.unit == unit  # from [metadata]
            assert_same_rig(again, rig)
            assert (raw_tables(out)[0]["fisheye"]) == (rig.cameras.distortion_model == "fisheye")


def test_round_trip_of_odd_names_and_a_rig_without_sizes(tmp_path):
    rig = synthetic_rig(3, seed=4, with_size=False)
    rig = RigCalibration(('cam "A"', "back\\slash\ttab", "caméra-ß"), rig.cameras, None, "synthetic", "mm")
    with pytest.warns(UserWarning, match="without `size`"):
        write_anipose_toml(tmp_path / "calibration.toml", rig, unit="mm")
    assert_same_rig(read_rig_calibration(tmp_path / "calibration.toml"), rig)
    fisheye = synthetic_rig(3, seed=5, fisheye=True)
    write_anipose_toml(tmp_path / "fisheye.toml", fisheye)
    assert_same_rig(read_rig_calibration(tmp_path / "fisheye.toml"), fisheye)


def test_aniposelib_layout_fixture_with_pose2sim_table_names(tmp_path):
    rig = synthetic_rig(4, seed=6)
    path = tmp_path / "Calib_scene.toml"
    path.write_text(aniposelib_style_toml(rig, scale=1000.0, tables=[f"int_cam{c + 1:02d}_img" for c in range(4)]))
    read = read_rig_calibration(path)
    assert read.unit == "m"
    assert_same_rig(read, rig, rtol=1e-12)


# ----------------------------------------------------------------------------------------------
# jaxpose camera files and Human3.6M


def test_jaxpose_camera_file_subjects(tmp_path):
    one, two = synthetic_rig(3, seed=7), synthetic_rig(2, seed=8)
    path = tmp_path / "cameras.json"
    save_cameras(path, {"S1": (list(one.camera_names), one.cameras), "S2": (list(two.camera_names), two.cameras)},
                 {"S1": [tuple(size) for size in one.image_size]})  # fmt: skip
    with pytest.raises(DataFormatError, match=r"a subject to pick.*\['S1', 'S2'\]"):
        read_rig_calibration(path)
    with pytest.raises(DataFormatError, match=r"subject 'S3'.*\['S1', 'S2'\]"):
        read_rig_calibration(path, subject="S3")
    read = read_rig_calibration(path, subject="S1")
    assert read.unit == "mm" and read.source == str(path)
    assert_same_rig(read, dataclasses.replace(one, source=str(path)), rtol=0)  # float64, exact
    assert read_rig_calibration(path, subject="S2").image_size is None
    save_cameras(tmp_path / "single.json", {"walk": (list(two.camera_names), two.cameras)})
    with pytest.warns(UserWarning, match="unit 'm' ignored"):
        assert read_rig_calibration(tmp_path / "single.json", unit="m").camera_names == two.camera_names


def test_h36m_cameras_convert_to_opencv_and_write_as_toml(tmp_path, capsys):
    path = real(H36M_CAMERAS)
    with pytest.raises(DataFormatError, match=r"a subject to pick.*'S1'"):
        read_rig_calibration(path)
    rig = read_rig_calibration(path, subject="S1")
    check_geometry(rig)
    assert rig.camera_names == ("54138969", "55011271", "58860488", "60457274") and rig.unit == "mm"
    np.testing.assert_array_equal(rig.image_size, [[1000, 1002], [1000, 1000], [1000, 1000], [1000, 1002]])
    with pytest.raises(ValueError, match="no OpenCV/Anipose equivalent|tangential terms"):
        write_anipose_toml(tmp_path / "h36m.toml", rig)

    converted, max_error = opencv_rig_from_h36m(rig)
    fits = zip(rig.cameras.dist, rig.cameras.K, rig.image_size, strict=True)
    per_camera = [opencv_from_h36m_distortion(dist, K, size)[1] for dist, K, size in fits]
    with capsys.disabled():
        print(f"\nS1 h36m -> opencv distortion, max pixel error per camera: {np.round(per_camera, 3).tolist()}")
    assert max_error == pytest.approx(max(per_camera))
    # Five OpenCV coefficients cannot hold Human3.6M's tangential terms exactly: ~0.2-0.4 px at the
    # image corners (the tangential terms themselves move corners by 1.5-2.8 px).
    assert max_error < 0.5
    # Independently: both models through jaxpose.camera.project over points spread across the images.
    rng = np.random.default_rng(0)
    pixels = rng.uniform(0, 1000, (4, 500, 2))
    normalized = (pixels - rig.cameras.K[:, None, :2, 2]) / rig.cameras.K[:, None, [0, 1], [0, 1]]
    rays = np.concatenate([normalized, np.ones((4, 500, 1))], -1)
    world = np.einsum("cji,cnj->cni", rig.cameras.R, rays * 4000.0 - rig.cameras.t[:, None])
    difference = np.asarray(project(converted.cameras, world)) - np.asarray(project(rig.cameras, world))
    assert np.linalg.norm(difference, axis=-1).max() < max_error + 1e-3
    assert np.median(np.linalg.norm(difference, axis=-1)) < 0.15

    write_anipose_toml(tmp_path / "h36m_S1.toml", converted)
    assert_same_rig(read_rig_calibration(tmp_path / "h36m_S1.toml"), converted)


def test_h36m_distortion_fit_is_exact_for_an_opencv_radial_lens():
    K = np.array([[1150.0, 0.0, 510.0], [0.0, 1148.0, 505.0], [0.0, 0.0, 1.0]])
    radial = np.array([-0.2, 0.25, 0.0, 0.0, -0.003])  # no tangential terms: the two models agree
    dist, error = opencv_from_h36m_distortion(radial, K)
    np.testing.assert_allclose(dist, radial, atol=1e-10)
    assert error < 1e-8


# ----------------------------------------------------------------------------------------------
# find_calibration


def test_find_calibration_picks_the_calibration_not_the_anipose_config(tmp_path):
    shutil.copy(real(ANIPOSE / MOUSE), tmp_path / "calibration.toml")
    shutil.copy(ANIPOSE / MOUSE_CONFIG, tmp_path / "config.toml")
    coco = FORMATS / "coco-keypoint-results" / "cocoapi_person_keypoints_val2014_fakekeypoints100_results.json"
    shutil.copy(real(coco), tmp_path / "detections.json")
    (tmp_path / "cam088").mkdir()
    shutil.copy(POSE2SIM / QUALISYS, tmp_path / "cam088" / "Calib.toml")  # in a sub-folder: not looked at
    assert find_calibration(tmp_path) == tmp_path / "calibration.toml"
    assert read_rig_calibration(tmp_path).source == str(tmp_path / "calibration.toml")


POSE2SIM_CONFIG = """\
###############################################################################
## PROJECT PARAMETERS                                                        ##
###############################################################################

[project]
multi_person = false # comment
frame_rate = 60 # fps
frame_range = []

[pose]
pose_model = 'BODY_25B' #With openpose: BODY_25B, BODY_25
\t\t\t\t      #With mediapipe: BLAZEPOSE.

[calibration]
calibration_type = 'convert' # 'convert' or 'calculate'

   [calibration.convert]
   convert_from = 'qualisys'
      [calibration.convert.qualisys]
      binning_factor = 1

   [calibration.calculate]
      [calibration.calculate.extrinsics]
      extrinsics_method = 'scene'
         [calibration.calculate.extrinsics.scene]
         object_coords_3d =   [[-2.0,  0.3,  0.0],
                              [0.0, 0.0,  0.05]]

[triangulation]
reproj_error_threshold_triangulation = 15 # px

[pose.CUSTOM]
name = "CHip"
id = "None"
  [[pose.CUSTOM.children]]
  name = "RHip"
  id = 12
"""


def test_find_calibration_in_a_pose2sim_session(tmp_path):
    (tmp_path / "Config.toml").write_text(POSE2SIM_CONFIG)
    (tmp_path / "calibration").mkdir()
    shutil.copy(real(POSE2SIM / SCENE), tmp_path / "calibration" / "Calib_scene.toml")
    assert find_calibration(tmp_path) is None  # Config.toml is a project config
    assert find_calibration(tmp_path / "calibration") == tmp_path / "calibration" / "Calib_scene.toml"
    shutil.copy(POSE2SIM / QUALISYS, tmp_path / "calibration" / "Calib_qualisys.toml")
    with pytest.raises(DataFormatError, match=r"one calibration file.*Calib_qualisys\.toml.*Calib_scene\.toml"):
        find_calibration(tmp_path / "calibration")


def test_find_calibration_other_formats(tmp_path):
    rig = synthetic_rig(3, seed=9)
    write_easymocap(tmp_path / "easymocap", rig)
    assert find_calibration(tmp_path / "easymocap") == tmp_path / "easymocap" / "intri.yml"
    (tmp_path / "json").mkdir()
    save_cameras(tmp_path / "json" / "cameras.json", {"S1": (list(rig.camera_names), rig.cameras)})
    (tmp_path / "json" / "results.json").write_text(json.dumps([{"image_id": 1, "format": "jaxpose-cameras"}]))
    (tmp_path / "json" / "other.json").write_text(json.dumps({"format": "something else"}))
    assert find_calibration(tmp_path / "json") == tmp_path / "json" / "cameras.json"
    assert read_rig_calibration(tmp_path / "json").camera_names == rig.camera_names
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "calibration.toml").write_text("[cam_0]\nmatrix = [")
    with pytest.raises(DataFormatError, match="invalid TOML"):
        find_calibration(tmp_path / "broken")
    (tmp_path / "empty").mkdir()
    assert find_calibration(tmp_path / "empty") is None
    with pytest.raises(DataFormatError, match="none among"):
        read_rig_calibration(tmp_path / "empty")


# ----------------------------------------------------------------------------------------------
# Lens models against OpenCV (jitted: one compilation each instead of one per eager operation)


def opencv_scene(seed=0):
    rng = np.random.default_rng(seed)
    K = np.array([[902.6, 0.0, 359.5], [0.0, 905.1, 639.5], [0.0, 0.0, 1.0]])
    rvec, tvec = np.array([0.1, -0.2, 0.05]), np.array([10.0, 20.0, 30.0])
    R = rotation_from_rodrigues(rvec)
    # Points that land inside the 720 x 1280 image (up to ~40 degrees off axis), 1-3 m away.
    depth = rng.uniform(1000.0, 3000.0, (300, 1))
    rays = np.concatenate([rng.uniform(-0.5, 0.5, (300, 1)), rng.uniform(-0.75, 0.75, (300, 1)), np.ones((300, 1))], 1)
    camera = rays * depth
    world = (camera - tvec) @ R
    return K, rvec, tvec, R, world


def test_fisheye_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    K, rvec, tvec, R, world = opencv_scene()
    D = np.array([-0.19, 0.03, -0.01, 0.002])
    cameras = Cameras(K=K, R=R, t=tvec, dist=np.r_[D, 0.0], distortion_model="fisheye")
    expected = cv2.fisheye.projectPoints(world[None], rvec, tvec, K, D)[0][0]
    projected = np.asarray(jax.jit(project)(cameras, world))
    np.testing.assert_allclose(projected, expected, atol=1e-3)
    expected = cv2.fisheye.undistortPoints(expected[None], K, D, P=K)[0]
    np.testing.assert_allclose(np.asarray(jax.jit(undistort_points)(cameras, jnp.asarray(projected))), expected, atol=1e-3)
    # The image corners too (~40 degrees off axis for this lens).
    corners = np.array([[0.0, 0.0], [720.0, 1280.0], [0.0, 1280.0], [720.0, 0.0], [359.5, 639.5]])
    expected = cv2.fisheye.undistortPoints(corners[None], K, D, P=K)[0]
    np.testing.assert_allclose(np.asarray(jax.jit(undistort_points)(cameras, jnp.asarray(corners))), expected, atol=1e-3)


def test_fisheye_is_finite_on_the_optical_axis():
    K, _, _, _, _ = opencv_scene()
    dist = np.array([-0.19, 0.03, -0.01, 0.002, 0.0])
    cameras = Cameras(K=K, R=np.eye(3), t=np.zeros(3), dist=dist, distortion_model="fisheye")
    on_axis = jnp.array([[0.0, 0.0, 2000.0]])
    np.testing.assert_allclose(np.asarray(jax.jit(project)(cameras, on_axis)), [[359.5, 639.5]], atol=1e-4)
    # jit: one compilation instead of one per operation of the eager derivative.
    jacobian = np.asarray(jax.jit(jax.jacobian(lambda points: project(cameras, points)))(on_axis))[0, :, 0, :]
    assert np.all(np.isfinite(jacobian))
    np.testing.assert_allclose(jacobian[:, :2], np.diag([902.6, 905.1]) / 2000.0, rtol=1e-5)  # pinhole at the axis
    undistorted = jax.jit(undistort_points)(cameras, jnp.array([[359.5, 639.5], [359.5 + 1e-3, 639.5]]))
    np.testing.assert_allclose(np.asarray(undistorted), [[359.5, 639.5], [359.5 + 1e-3, 639.5]], atol=1e-4)
    gradient = jax.jit(jax.grad(lambda pixels: undistort_points(cameras, pixels).sum()))(jnp.array([[359.5, 639.5]]))
    assert np.all(np.isfinite(np.asarray(gradient)))


def test_opencv_model_matches_opencv():
    cv2 = pytest.importorskip("cv2")
    K, rvec, tvec, R, world = opencv_scene(1)
    D = np.array([-0.21, 0.09, 0.0012, -0.0008, -0.01])
    cameras = Cameras(K=K, R=R, t=tvec, dist=D, distortion_model="opencv")
    expected = cv2.projectPoints(world, rvec, tvec, K, D)[0][:, 0]
    projected = np.asarray(jax.jit(project)(cameras, world))
    np.testing.assert_allclose(projected, expected, atol=1e-3)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    expected = cv2.undistortPoints(expected[:, None], K, D, None, None, K, criteria)[:, 0]
    np.testing.assert_allclose(np.asarray(jax.jit(undistort_points)(cameras, jnp.asarray(projected))), expected, atol=1e-3)

