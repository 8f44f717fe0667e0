"""Several people per view in every detection format: each read as detected, an absent person left out."""

import json

import numpy as np
import pytest

from jaxpose.formats import detections_npz
from jaxpose.formats import keypoint_files as kf
from jaxpose.formats.errors import DataFormatError
from jaxpose.rig import recordings
from tests.paths import FORMATS

DEMO = FORMATS / "openpose-json" / "pose2sim_demo_multiperson_body25b"


@pytest.mark.skipif(not DEMO.exists(), reason="Pose2Sim's multi-person demo is not in ../shared/data")
def test_pose2sim_demo_every_person_read():
    """The demo's cam01.0001.json lists a person with an empty pose_keypoints_2d (real Pose2Sim output):
    that person is absent, the frame's two others are read."""
    counts = {}
    for camera in ("cam01_json", "cam02_json", "cam03_json", "cam04_json"):
        detections = kf.read_openpose_folder(DEMO / camera, progress=False, workers=1)
        assert detections.frames.tolist() == list(range(100))
        assert detections.keypoints.shape[2:] == (25, 2)
        counts[camera] = detections.people
    assert counts["cam01_json"][1] == 2 and counts["cam01_json"][0] == 2 and counts["cam01_json"].max() == 4
    assert (counts["cam02_json"] == 3).all() and (counts["cam03_json"] == 2).all() and (counts["cam04_json"] == 2).all()
    frame = json.loads((DEMO / "cam01_json" / "cam01.0001.json").read_text())
    kept = [p["pose_keypoints_2d"] for p in frame["people"] if p["pose_keypoints_2d"]]
    detections = kf.read_openpose_folder(DEMO / "cam01_json", progress=False, workers=1)
    for slot, values in enumerate(kept):
        rows = np.array(values, np.float32).reshape(25, 3)
        np.testing.assert_array_equal(detections.keypoints[1, slot][rows[:, 2] > 0], rows[rows[:, 2] > 0, :2])


def test_empty_person_entry_is_absent(tmp_path):
    folder = tmp_path / "cam"
    folder.mkdir()
    person = [10.0, 20.0, 0.9] * 17
    (folder / "f_0001.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": []}, {"pose_keypoints_2d": person}]}))
    (folder / "f_0002.json").write_text(json.dumps({"people": [{"pose_keypoints_2d": []}]}))
    detections = kf.read_openpose_folder(folder, progress=False, workers=1)
    assert detections.people.tolist() == [1, 0]
    assert detections.keypoints.shape == (2, 1, 17, 2) and detections.scores[0, 0, 0] == pytest.approx(0.9)


def test_coco_several_detections_per_image(tmp_path):
    entries = [{"image_id": frame, "keypoints": [float(frame), 1.0, 0.5] * 17} for frame in (3, 1, 3, 3, 2)]
    entries[3]["keypoints"] = [7.0, 7.0, 0.25] * 17
    (tmp_path / "r.json").write_text(json.dumps(entries))
    detections = kf.read_coco_results(tmp_path / "r.json")
    assert detections.frames.tolist() == [1, 2, 3] and detections.people.tolist() == [1, 1, 3]
    np.testing.assert_array_equal(detections.keypoints[2, :, 0, 0], [3.0, 3.0, 7.0])  # file order within a frame


def _write_npz(path, keypoints, confidence):
    np.savez(path, keypoints=keypoints, confidence=confidence, camera_names=np.array(["a", "b"]))


def test_detections_npz_person_axis(tmp_path):
    rng = np.random.default_rng(0)
    keypoints = rng.uniform(0, 500, (4, 2, 3, 17, 2)).astype(np.float32)
    confidence = np.ones((4, 2, 3, 17), np.float32)
    confidence[:, 1, 2] = 0  # view b sees two people
    _write_npz(tmp_path / "detections.npz", keypoints, confidence)
    read = detections_npz.read(tmp_path / "detections.npz", people=True)
    assert read.keypoints.shape == (4, 2, 3, 17, 2)
    cameras = recordings._npz_cameras(read)
    assert cameras["a"].people.tolist() == [3] * 4 and cameras["b"].people.tolist() == [2] * 4
    np.testing.assert_array_equal(cameras["b"].keypoints, keypoints[:, 1])
    # Calibration takes one person per view: one line naming the file and the field.
    with pytest.raises(DataFormatError, match=r"detections\.npz, field 'keypoints'.*one person per view.*\(4, 2, 3, 17, 2\)"):
        detections_npz.read(tmp_path / "detections.npz")
    _write_npz(tmp_path / "bad.npz", keypoints, confidence[:, :, :2])
    with pytest.raises(DataFormatError, match=r"bad\.npz, field 'confidence'.*\(4, 2, 3, 17\)"):
        detections_npz.read(tmp_path / "bad.npz", people=True)
