"""Keypoint files written as detectors write them (OpenPose / Pose2Sim frames, COCO results entries), and
the check that `CameraDetections` hold what was written, for the tests of the keypoint file readers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from jaxpose.formats.keypoint_files import CameraDetections

EMPTY_PARTS = ("face_keypoints_2d", "hand_left_keypoints_2d", "hand_right_keypoints_2d", "pose_keypoints_3d",
               "face_keypoints_3d", "hand_left_keypoints_3d", "hand_right_keypoints_3d")  # fmt: skip


def openpose_document(people: list[np.ndarray], version: float = 1.3) -> dict:
    """An OpenPose frame as OpenPose / Pose2Sim write it: person_id [-1], then the empty other parts."""
    persons = [{"person_id": [-1], "pose_keypoints_2d": np.asarray(p, float).ravel().tolist()} for p in people]
    return {"version": version, "people": [person | {part: [] for part in EMPTY_PARTS} for person in persons]}


def write_frame(path: Path, people: list[np.ndarray], pretty: bool = False) -> Path:
    """Compact (OpenPose's C++ writer, Pose2Sim's demo) or indent=4 (Pose2Sim's RTMPose writer)."""
    document = openpose_document(people)
    path.write_text(json.dumps(document, indent=4) if pretty else json.dumps(document, separators=(",", ":")))
    return path


def random_people(rng: np.random.Generator, count: int, joints: int = 25) -> list[np.ndarray]:
    people = []
    for _ in range(count):
        person = np.concatenate([rng.uniform(0, 1900, (joints, 2)), rng.uniform(0.05, 1.0, (joints, 1))], 1)
        person[rng.random(joints) < 0.2] = 0.0  # undetected joints are written as 0, 0, 0
        people.append(np.round(person, 3))
    return people


def write_folder(folder: Path, people_per_frame: list[int], seed: int = 0, name: str = "clip_{:012d}_keypoints.json",
                 first: int = 0, joints: int = 25) -> dict[int, list[np.ndarray]]:  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    written = {}
    for index, count in enumerate(people_per_frame):
        written[first + index] = random_people(rng, count, joints)
        write_frame(folder / name.format(first + index), written[first + index], pretty=index % 2 == 1)
    return written


def check_matches(detections: CameraDetections, written: dict[int, list[np.ndarray]]) -> None:
    assert detections.frames.tolist() == sorted(written)
    assert detections.people.tolist() == [len(written[f]) for f in sorted(written)]
    for k, frame in enumerate(sorted(written)):
        for p, person in enumerate(written[frame]):
            np.testing.assert_allclose(detections.keypoints[k, p], person[:, :2], rtol=1e-6)
            np.testing.assert_allclose(detections.scores[k, p], person[:, 2], rtol=1e-6)
        assert not detections.keypoints[k, len(written[frame]):].any()
        assert not detections.scores[k, len(written[frame]):].any()


def coco_entry(image_id, values, **extra) -> dict:
    keypoints = values if isinstance(values, list) else np.asarray(values, float).ravel().tolist()
    return {"image_id": image_id, "category_id": 1, "keypoints": keypoints, "score": 0.9} | extra
