"""A recovered rig written as an Anipose/Pose2Sim calibration TOML (`jaxpose.calibration.rig_file`), and a
Pose2Sim calibration read back as intrinsics only (`jaxpose.formats.intrinsics.read_rig_intrinsics`).

The file is checked twice: by jaxpose's own reader, and by `tomllib` with scipy's Rodrigues vectors as an
independent oracle of what Pose2Sim sees (metres, world-to-camera rotation vectors, [W, H] sizes).
"""

from __future__ import annotations

import tomllib

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from jaxpose.calibration import CalibrationConfig, calibrate, from_dataset
from jaxpose.calibration.rig_file import SOURCE, write_recovered_rig
from jaxpose.calibration.world import WORLD_FRAME, points_to_world, to_world, world_frame
from jaxpose.camera import Cameras, project
from jaxpose.formats.anipose_toml import write_anipose_toml
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.formats.intrinsics import read_rig_intrinsics
from jaxpose.formats.outputs import OutputError
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.rotations import nearest_rotation
from jaxpose.synthetic import SyntheticConfig, generate, make_rig
import paths

QUALISYS = paths.FORMATS / "pose2sim-calib-toml" / "pose2sim_demo_Calib_qualisys.toml"
NAMES = ("c0", "c1", "c2", "c3")


@pytest.fixture(scope="module")
def recovered():
    """(the data set, the rig `calibrate` recovers from its one synthetic subject with K withheld)."""
    dataset = generate(SyntheticConfig(num_train_subjects=1, num_test_subjects=0, samples_per_subject=600))
    detections = from_dataset(dataset, "S1", NAMES, np.full((4, 2), 1000)).without_intrinsics()
    return dataset, calibrate(detections, CalibrationConfig(max_frames=150))


def two_cameras() -> RigCalibration:
    R = Rotation.random(2, random_state=0).as_matrix()
    cameras = Cameras(K=np.tile(np.diag([900.0, 900.0, 1.0]), (2, 1, 1)), R=R, t=np.array([[0.0, 0, 4000], [900, 0, 4000]]))
    return RigCalibration(("a", "b"), cameras, np.array([[640, 480], [640, 480]]), "test", "mm")


def assert_file_holds(path, cameras, names, image_size, unit_mm: float) -> dict:
    """`tomllib`'s reading of the file against the cameras (t in mm); returns the document."""
    document = tomllib.loads(path.read_text(encoding="utf-8"))
    tables = [key for key in document if key != "metadata"]
    assert tables == [f"cam_{c}" for c in range(len(names))]
    for c, key in enumerate(tables):
        table = document[key]
        assert table["name"] == names[c] and table["size"] == list(image_size[c]) and table["fisheye"] is False
        np.testing.assert_allclose(table["matrix"], cameras.K[c], rtol=1e-15)
        np.testing.assert_allclose(Rotation.from_rotvec(table["rotation"]).as_matrix(), cameras.R[c], atol=1e-12)
        np.testing.assert_allclose(np.array(table["translation"]) * unit_mm, cameras.t[c], rtol=1e-12, atol=1e-9)
        assert table["distortions"] == [0.0] * 5  # the recovered pinhole (no lens estimated)
    return document


def test_a_rig_in_metres_reads_back_the_same_through_jaxpose_and_tomllib(tmp_path):
    """The file layer alone (fast): a synthetic room's cameras, float64, with metadata."""
    room = make_rig(np.random.default_rng(7), SyntheticConfig())
    cameras = Cameras(**{name: np.asarray(getattr(room, name), np.float64) for name in ("K", "R", "t")})
    cameras = cameras.replace(R=nearest_rotation(cameras.R))
    rig = RigCalibration(NAMES, cameras, np.full((4, 2), 1000), "synthetic room", "mm")
    path = tmp_path / "calibration.toml"
    write_anipose_toml(path, rig, metadata={"world": "the room's", "reprojection_median_px": [1.0, 2.0, 3.0, 4.0]})
    document = assert_file_holds(path, cameras, NAMES, rig.image_size, 1000.0)
    assert document["metadata"] == {"unit": "m", "world": "the room's", "reprojection_median_px": [1.0, 2.0, 3.0, 4.0]}
    again = read_rig_calibration(path)
    assert again.camera_names == NAMES and again.unit == "m" and again.cameras.dist is None
    for name in ("K", "R", "t"):
        np.testing.assert_allclose(getattr(again.cameras, name), getattr(cameras, name), rtol=1e-12, atol=1e-9)


@pytest.mark.slow  # a rig recovered by calibrate: ~40 s, nearly all of it compilation
def test_a_recovered_rig_reads_back_the_same_through_jaxpose_and_tomllib(recovered, tmp_path):
    _, calibration = recovered
    cameras = calibration.cameras
    path = write_recovered_rig(tmp_path / "calibration.toml", calibration)
    document = assert_file_holds(path, cameras, NAMES, calibration.image_size, 1000.0)
    metadata = document["metadata"]
    assert metadata["unit"] == "m" and metadata["source"] == SOURCE and "view 0's camera frame" in metadata["world"]
    np.testing.assert_allclose(metadata["reprojection_median_px"], calibration.reprojection_median_px, atol=1e-3)
    assert metadata["focal_estimated"] is True and metadata["scale"].startswith("limb prior (upper arm 290 mm")

    again = read_rig_calibration(path)
    assert again.camera_names == NAMES and again.unit == "m" and again.cameras.dist is None
    np.testing.assert_array_equal(again.image_size, calibration.image_size)
    for name in ("K", "R", "t"):
        np.testing.assert_allclose(getattr(again.cameras, name), getattr(cameras, name), rtol=1e-12, atol=1e-9)


@pytest.mark.slow  # the recovered rig of the fixture above
def test_the_rig_in_the_upright_world_projects_as_before(recovered, tmp_path):
    """Written in the upright world (mm in the file too): the same pixels for the same points."""
    dataset, calibration = recovered
    # The subject's true joints in view 0's camera frame: about where the recovered world (that frame) has them.
    rig = dataset.rigs[0]
    points = dataset.samples.target3d[:300].astype(np.float64) @ np.asarray(rig.R[0], np.float64).T + np.asarray(rig.t[0], np.float64)
    frame = world_frame(points, np.ones(points.shape[:2], bool), dataset.skeleton, height_mm=1750.0)
    path = write_recovered_rig(tmp_path / "upright.toml", to_world(frame, calibration), unit="mm")
    document = tomllib.loads(path.read_text(encoding="utf-8"))
    assert document["metadata"]["world"] == WORLD_FRAME and document["metadata"]["unit"] == "mm"
    assert document["metadata"]["scale"] == "the subject's height" and document["metadata"]["ankle_height_mm"] > 0
    world = read_rig_calibration(path).cameras
    before = np.asarray(project(calibration.cameras, np.broadcast_to(points[:5].reshape(1, -1, 3), (4, 85, 3))))
    after = np.asarray(project(world, np.broadcast_to(points_to_world(frame, points[:5]).reshape(1, -1, 3), (4, 85, 3))))
    np.testing.assert_allclose(after, before, atol=1e-2)


@pytest.mark.slow  # the recovered rig of the fixture above
def test_an_existing_recovered_rig_file_is_replaced_only_when_asked(recovered, tmp_path):
    _, calibration = recovered
    path = tmp_path / "calibration.toml"
    path.write_text("# the user's own file\n")
    with pytest.raises(OutputError, match=r"calibration.toml: exists; pass overwrite=True"):
        write_recovered_rig(path, calibration)
    assert path.read_text() == "# the user's own file\n"
    write_recovered_rig(path, calibration, overwrite=True)
    assert read_rig_calibration(path).camera_names == NAMES
    assert sorted(entry.name for entry in tmp_path.iterdir()) == ["calibration.toml"]  # no partial file left


@pytest.mark.skipif(not QUALISYS.is_file(), reason=f"{QUALISYS} (a real sample) is absent")
def test_pose2sims_demo_calibration_read_as_intrinsics_only():
    intrinsics = read_rig_intrinsics(QUALISYS, ["cam_04", "cam_01"], "the test's cameras")
    document = tomllib.loads(QUALISYS.read_text())
    assert intrinsics.camera_names == ("cam_04", "cam_01") and intrinsics.distortion_model == "opencv"
    for c, key in enumerate(("cam_04", "cam_01")):
        np.testing.assert_array_equal(intrinsics.K[c], document[key]["matrix"])
        np.testing.assert_array_equal(intrinsics.dist[c], [*document[key]["distortions"], 0.0])  # k3 = 0
        np.testing.assert_array_equal(intrinsics.image_size[c], document[key]["size"])
    assert not hasattr(intrinsics, "R") and "intrinsics only" in intrinsics.source


def test_metadata_values_are_checked(tmp_path):
    rig = two_cameras()
    with pytest.raises(ValueError, match="metadata 'unit' is the translations' unit"):
        write_anipose_toml(tmp_path / "a.toml", rig, metadata={"unit": "cm"})
    with pytest.raises(ValueError, match="not finite"):
        write_anipose_toml(tmp_path / "a.toml", rig, metadata={"error_px": [1.0, float("nan")]})
    assert not (tmp_path / "a.toml").exists()
    write_anipose_toml(tmp_path / "a.toml", rig, metadata={"a key with spaces": "x \"quoted\"", "flag": True, "n": 3})
    metadata = tomllib.loads((tmp_path / "a.toml").read_text())["metadata"]
    assert metadata == {"unit": "m", "a key with spaces": 'x "quoted"', "flag": True, "n": 3.0}


def test_an_existing_file_is_replaced_only_when_asked(tmp_path):
    rig = two_cameras()
    path = tmp_path / "calibration.toml"
    path.write_text("# the user's own file\n")
    with pytest.raises(OutputError, match=r"calibration.toml: exists; pass overwrite=True"):
        write_anipose_toml(path, rig)
    assert path.read_text() == "# the user's own file\n"
    write_anipose_toml(path, rig, overwrite=True)
    assert read_rig_calibration(path).camera_names == ("a", "b")
    assert sorted(entry.name for entry in tmp_path.iterdir()) == ["calibration.toml"]  # no partial file left
