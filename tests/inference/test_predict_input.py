"""jaxpose.predict's input: the joint layout it is read in (`predict.input_layout`, `--format`), and the
readers of the detection file and the camera (`jaxpose.formats.detection_file`, `jaxpose.formats.intrinsics`).

75 values per person are OpenPose BODY_25 or BODY_25B (Pose2Sim's default), which the count cannot tell
apart: a lifter of either reads them in its own layout, any other is refused unless --format says which.
"""

from __future__ import annotations

import json
from pathlib import Path

import jax
import numpy as np
import optax
import pytest

from jaxpose import predict

from jaxpose.training import checkpoint
from jaxpose.model import ModelConfig
from jaxpose.formats import detection_file, intrinsics
from jaxpose.layouts import layout_joint_names, lifting_skeleton
from jaxpose.training.step import init_train_state
from keypoint_writers import write_frame
import paths

POSE2SIM_BODY25B = paths.FORMATS / "openpose-json/pose2sim_demo_balancing_body25b"
needs_pose2sim = pytest.mark.skipif(not POSE2SIM_BODY25B.is_dir(), reason=f"{POSE2SIM_BODY25B} (a real sample) is absent")
IMAGE = ("1088", "1920")  # the Pose2Sim demo's portrait video


@pytest.fixture(scope="module")
def body25b_run(tmp_path_factory) -> Path:
    """A BODY_25B lifter as a run directory: initialised, not trained (only its layout matters here)."""
    run = tmp_path_factory.mktemp("body25b") / "run"
    skeleton = lifting_skeleton("body25b")
    config = ModelConfig(width=32, stages=1, blocks_per_stage=1)
    state = init_train_state(config.build(skeleton.num_joints), optax.sgd(0.1), jax.random.key(0))
    manager = checkpoint.checkpoint_manager(run / "checkpoints", asynchronous=False)
    checkpoint.save(manager, state.replace(step=state.step + 1), checkpoint.LifterRecord(skeleton, config))
    manager.close()
    return run


def pose2sim_folder(folder: Path, frames: int = 3) -> Path:
    """BODY_25B frames as Pose2Sim's demo writes them (`keypoint_writers.write_frame`: cam01_json/cam01.0000.json,
    compact JSON, version 1.3, person_id [-1] and the empty face, hand and 3D arrays); two people in the first frame."""
    folder.mkdir(parents=True)
    rng = np.random.default_rng(0)
    names = layout_joint_names("body25b")
    for frame in range(frames):
        people = []
        for _ in range(2 if frame == 0 else 1):
            person = np.concatenate([rng.uniform([300, 300], [800, 1600], (25, 2)), rng.uniform(0.5, 0.9, (25, 1))], 1)
            person[names.index("RSmallToe")] = 0.0  # undetected: 0, 0, 0
            people.append(np.round(person, 3))
        write_frame(folder / f"cam01.{frame:04d}.json", people)
    return folder


def _predict(checkpoint_dir: Path, folder: Path, output: Path, *flags: str) -> np.ndarray:
    args = ["--checkpoint", checkpoint_dir, "--input", folder, "--output", output, "--image-size", *IMAGE, *flags]
    return predict.main([str(a) for a in args])


def _refused(checkpoint_dir: Path, folder: Path, output: Path, *flags: str) -> str:
    with pytest.raises(SystemExit) as refusal:
        _predict(checkpoint_dir, folder, output, *flags)
    message = str(refusal.value)
    assert message.startswith("jaxpose.predict: error: ") and "\n" not in message
    return message


def _check_layouts(folder: Path, people: int, h36m_run: Path, body25b_run: Path, tmp_path: Path) -> np.ndarray:
    """Refused by an H36M_17 lifter, and with --format body25 (its joint 8 is no mid-hip); --format body25b converts
    where a conversion exists (the BODY_25B lifter) and says so where none does (the H36M_17 lifter)."""
    message = _refused(h36m_run, folder, tmp_path / "refused.npz")
    assert f"{folder}: 75 values per person are OpenPose BODY_25 or BODY_25B" in message
    assert message.endswith("pass --format body25 or --format body25b")
    assert not (tmp_path / "refused.npz").exists()
    message = _refused(h36m_run, folder, tmp_path / "refused.npz", "--format", "body25b")
    assert "a lifter of skeleton 'h36m17' cannot take keypoints in layout 'body25b'" in message
    # BODY_25B named BODY_25: joint 8 is no mid-hip, so the data refuse it (issue 42 case 7: it was lifted as BODY_25).
    message = _refused(h36m_run, folder, tmp_path / "as_body25.npz", "--format", "body25")
    assert "read as body25, but joint 8 is not the midpoint of joints 9 and 12" in message and message.endswith("pass --format body25b")
    own = _predict(body25b_run, folder, tmp_path / "own.npz")
    assert own.shape == (people, 26, 3) and np.isfinite(own).all((1, 2)).any()
    np.testing.assert_array_equal(_predict(body25b_run, folder, tmp_path / "named.npz", "--format", "body25b"), own)
    with np.load(tmp_path / "own.npz") as out:
        assert out["joint_names"].tolist() == list(lifting_skeleton("body25b").joint_names)
    return own


def test_body25b_folder_in_pose2sim_layout(trained_run, body25b_run, tmp_path):
    folder = pose2sim_folder(tmp_path / "cam01_json")
    assert np.isfinite(_check_layouts(folder, 4, trained_run[0], body25b_run, tmp_path)).all()


@needs_pose2sim
def test_the_real_pose2sim_body25b_folder(trained_run, body25b_run, tmp_path):
    lifted = np.isfinite(_check_layouts(POSE2SIM_BODY25B / "cam01_json", 40, trained_run[0], body25b_run, tmp_path))
    assert lifted.all((1, 2)).sum() == 22  # the second person's hips are not detected in 18 frames


def test_the_layout_of_each_input_kind(body25b_run, tmp_path):
    """An .npz is in the lifter's own joints; a detector's JSON is told by its count, or is the lifter's own
    layout where the count fits it."""
    h36m17, body25b = lifting_skeleton("h36m17"), lifting_skeleton("body25b")
    np.savez(tmp_path / "poses.npz", keypoints=np.zeros((2, 17, 2), np.float32))
    assert predict.input_layout(h36m17, detection_file.read_detections(tmp_path / "poses.npz")) is None
    entries = [{"image_id": 1, "keypoints": [500.0, 500.0, 0.9] * joints} for joints in (17, 17)]
    (tmp_path / "coco.json").write_text(json.dumps(entries))
    assert predict.input_layout(h36m17, detection_file.read_detections(tmp_path / "coco.json")) == "coco17"
    folder = pose2sim_folder(tmp_path / "cam01_json")
    assert predict.input_layout(body25b, detection_file.read_detections(folder)) == "body25b"
    with pytest.raises(ValueError, match="BODY_25 or BODY_25B.*--format body25b"):
        predict.input_layout(h36m17, detection_file.read_detections(folder))


# ---------------------------------------------------------------------------------------------
# The readers of predict's input: the detection file's refusals, --intrinsics in each of its forms

QUALISYS = POSE2SIM_BODY25B.parents[1] / "pose2sim-calib-toml" / "pose2sim_demo_Calib_qualisys.toml"


def test_a_negative_score_is_refused_by_every_kind(tmp_path):
    np.savez(tmp_path / "poses.npz", keypoints=np.zeros((2, 17, 2), np.float32), confidence=np.full((2, 17), -0.5, np.float32))
    entries = [{"image_id": 1, "keypoints": [500.0, 500.0, 0.9] * 16 + [500.0, 500.0, -0.1]}]
    (tmp_path / "coco.json").write_text(json.dumps(entries))
    for name, where in (("poses.npz", "-0.5 at pose 0 joint 0"), ("coco.json", "-0.1 at pose 0 joint 16")):
        with pytest.raises(ValueError, match=rf"{name}: expected detector scores >= 0.*; found {where}"):
            detection_file.read_detections(tmp_path / name)


def test_scores_above_one_are_clipped_and_counted_by_every_kind(tmp_path):
    confidence = np.full((2, 17), 0.5, np.float32)
    confidence[1, 3] = 1.4
    np.savez(tmp_path / "poses.npz", keypoints=np.zeros((2, 17, 2), np.float32), confidence=confidence)
    (tmp_path / "coco.json").write_text(json.dumps([{"image_id": 1, "keypoints": [500.0, 500.0, 2.0] * 2 + [500.0, 500.0, 0.7] * 15}]))
    npz, coco = (detection_file.read_detections(tmp_path / name) for name in ("poses.npz", "coco.json"))
    assert npz.clipped_scores == 1 and npz.scores[1, 3] == 1.0 and npz.scores[0, 0] == 0.5
    assert coco.clipped_scores == 2 and coco.scores.max() == 1.0 and np.isclose(coco.scores[0, 2], 0.7)


def test_intrinsics_in_each_form(tmp_path):
    camera = intrinsics.read_intrinsics(["1000", "1100", "500", "400"])
    np.testing.assert_array_equal(camera.K, [[1000, 0, 500], [0, 1100, 400], [0, 0, 1]])
    assert camera.dist is None and camera.image_size is None
    entry = {"K": camera.K.tolist(), "dist": [-0.2, 0.05, 0.0, 0.0, 0.0], "image_size": [1000, 800], "name": "cam01"}
    (tmp_path / "camera.json").write_text(json.dumps(entry))
    from_file = intrinsics.read_intrinsics([str(tmp_path / "camera.json")])
    np.testing.assert_array_equal(from_file.K, camera.K)
    assert from_file.dist.tolist() == pytest.approx(entry["dist"]) and from_file.image_size == (1000, 800)
    (tmp_path / "bad.json").write_text(json.dumps({"dist": None}))
    with pytest.raises(ValueError, match=r"bad.json: expected a camera \{'K'"):
        intrinsics.read_intrinsics([str(tmp_path / "bad.json")])
    with pytest.raises(FileNotFoundError, match="--intrinsics file .*absent.json does not exist"):
        intrinsics.read_intrinsics([str(tmp_path / "absent.json")])
    with pytest.raises(ValueError, match="--intrinsics takes 4 numbers .* got 3 values"):
        intrinsics.read_intrinsics(["1", "2", "3"])


def test_a_camera_per_pose_and_intrinsics_are_refused_together(trained_run, tmp_path):
    K = np.broadcast_to(intrinsics.read_intrinsics(["1000", "1000", "500", "500"]).K, (2, 3, 3))
    np.savez(tmp_path / "poses.npz", keypoints=np.full((2, 17, 2), 500.0, np.float32), K=K)
    message = _refused(trained_run[0], tmp_path / "poses.npz", tmp_path / "out.npz", "--intrinsics", "1000", "1000", "500", "500")
    assert message.endswith("poses.npz holds a camera per pose ('K'); do not pass --intrinsics as well")


def test_a_camera_per_pose_or_one_for_all():
    K = np.stack([np.eye(3, dtype=np.float32) * (i + 1) for i in range(4)])
    assert intrinsics.CameraIntrinsics().of_poses(slice(0, 2)) is None
    np.testing.assert_array_equal(intrinsics.CameraIntrinsics(K[0]).of_poses(slice(1, 3)), K[0])
    np.testing.assert_array_equal(intrinsics.CameraIntrinsics(K).of_poses(np.array([3, 1])), K[[3, 1]])


@pytest.mark.skipif(not QUALISYS.is_file(), reason=f"{QUALISYS} (a real sample) is absent")
def test_intrinsics_of_one_camera_of_a_pose2sim_calibration():
    camera = intrinsics.read_intrinsics([str(QUALISYS), "cam_01"])
    np.testing.assert_allclose(camera.K, [[1681.244873046875, 0, 532.97369384375], [0, 1681.075439453125, 948.137390140625], [0, 0, 1]])
    np.testing.assert_allclose(camera.dist, [-0.000721609375, 0.002187234375, 9.5e-06, 1.078125e-05, 0.0], rtol=1e-6)
    assert camera.image_size == (1088.0, 1920.0)


@pytest.mark.parametrize(
    "image_ids, frames, note",
    [
        ([10, 9, 9, 2], [10, 9, 9, 2], None),  # COCO's own numbers; images with nobody are simply absent
        (["out-012.jpg", "out-003.jpg"], [12, 3], None),  # AlphaPose's file names: their last digits
        (["b.jpg", 4, "a.jpg"], [2, 0, 1], "image id 'b.jpg' has no digits"),  # numbers first, then names
        (["cam1_007.png", "cam2_007.png"], [0, 1], "two image ids share a frame number"),
    ],
)
def test_frame_numbers_of_coco_results(tmp_path, image_ids, frames, note):
    entries = [{"image_id": i, "keypoints": [500.0, 500.0, 0.9] * 17} for i in image_ids]
    (tmp_path / "results.json").write_text(json.dumps(entries))
    detections = detection_file.read_detections(tmp_path / "results.json")
    assert detections.frames.tolist() == frames and detections.first_frame == min(frames)
    assert (detections.frames_note is None) if note is None else (note in detections.frames_note)


def test_frame_numbers_of_an_openpose_folder_start_at_its_first_file(tmp_path):
    folder = tmp_path / "openpose"
    folder.mkdir()
    person = np.full((25, 3), 0.5)
    for frame, people in ((4, []), (5, [person, person]), (7, [person])):
        write_frame(folder / f"clip_{frame:012d}_keypoints.json", people)
    detections = detection_file.read_detections(folder)
    assert detections.frames.tolist() == [5, 5, 7] and detections.first_frame == 4
