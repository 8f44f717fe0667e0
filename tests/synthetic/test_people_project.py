"""The example project with several people (`ExampleProjectConfig.people` and friends): every person in
every camera's frame files in a shuffled order, detections on the ground truth's projections (numpy
pinhole oracle), people apart by `min_distance` except a pair passing each other as configured, a person
leaving and coming back, false detections, occlusion, and the single-person project unchanged."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from jaxpose.camera import camera_centres, project
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.formats.rig_folder import read_ground_truth
from jaxpose.synthetic import ExampleProjectConfig, write_rig_project
from jaxpose.synthetic.capture import Person, detect, field_radius2, occlude, pelvis_distance, people_bones, people_poses, rig_calibration
from jaxpose.synthetic.keypoints import keypoints3d
from jaxpose.synthetic.project import FALSE_PERSON

# Pinhole cameras, so that numpy's K [R | t] is the oracle; one camera 3 frames late; no left/right swaps
# (a swapped view is off its own projection by a body's width).
THREE = ExampleProjectConfig(
    recordings=1, frames_per_recording=60, cameras=3, people=3, second_person_rate=0.0, distortion=False,
    motions=("walking",), false_people_rate=0.1, swap_rate=0.0,
)  # fmt: skip


@pytest.fixture(scope="module")
def three(tmp_path_factory) -> Path:
    return write_rig_project(tmp_path_factory.mktemp("three") / "project", THREE)


def read_frames(root: Path, recording: str, camera: str) -> list[np.ndarray]:
    """Each frame file's people f64[entries, K, 3] (x, y, score), in file order."""
    frames = []
    for path in sorted((root / recording / f"{camera}_json").iterdir()):
        people = [person["pose_keypoints_2d"] for person in json.loads(path.read_text())["people"]]
        frames.append(np.array(people, np.float64).reshape(len(people), -1, 3))
    return frames


def test_every_person_listed_in_shuffled_order(three):
    truth = json.loads((three / "example_truth.json").read_text())
    record = truth["recordings"][THREE.recording_names[0]]
    unsorted = listed_all = false = 0
    for camera in THREE.camera_names:
        order = record["people_order"][camera]
        frames = read_frames(three, THREE.recording_names[0], camera)
        assert len(order) == len(frames) == THREE.frames_per_recording
        for codes, people in zip(order, frames):
            assert len(codes) == len(people)
            real = [code for code in codes if code >= 0]
            assert len(real) == len(set(real)) and set(codes) <= {FALSE_PERSON, 0, 1, 2}
            listed_all += sorted(real) == [0, 1, 2]
            unsorted += real != sorted(real)
            false += codes.count(FALSE_PERSON)
    views = THREE.cameras * THREE.frames_per_recording
    assert listed_all >= 0.9 * views  # every person in (nearly) every view and frame
    assert 0.6 * views <= unsorted  # the index is not the identity (5/6 of orders of 3 are unsorted)
    assert 0.03 * views <= false <= 0.2 * views  # false detections at about false_people_rate


def test_detections_are_the_ground_truths_projections(three):
    """Each listed person's detections lie on the projection of its own ground truth (through the
    calibration file) and far from every other person's; jaxpose.camera agrees with a numpy pinhole."""
    name = THREE.recording_names[0]
    truth = read_ground_truth(three / name / "ground_truth.npz")
    assert truth.points.shape == (60, 3, 18, 3) and truth.joint_names[-1] == "pelvis"
    rig = read_rig_calibration(three / "calibration.toml")
    order = json.loads((three / "example_truth.json").read_text())["recordings"][name]["people_order"]
    offsets = THREE.frame_offsets()
    points = truth.points[:, :, :17]  # the written COCO keypoints
    checked = 0
    for c, camera in enumerate(THREE.camera_names):
        K, R, t = (np.asarray(array[c], np.float64) for array in (rig.cameras.K, rig.cameras.R, rig.cameras.t))
        homogeneous = (points @ R.T + t) @ K.T
        pinhole = homogeneous[..., :2] / homogeneous[..., 2:]  # [N, P, 17, 2]
        camera_rig = type(rig.cameras)(K=K, R=R, t=t)
        np.testing.assert_allclose(np.asarray(project(camera_rig, points.reshape(-1, 17, 3))).reshape(pinhole.shape), pinhole, atol=1e-2)
        for f, (codes, people) in enumerate(zip(order[camera], read_frames(three, name, camera))):
            instant = f + offsets[c]
            if not 0 <= instant < len(points):
                continue
            for code, person in zip(codes, people):
                if code < 0:
                    continue
                seen = person[:, 2] > 0
                errors = np.linalg.norm(person[None, seen, :2] - pinhole[instant][:, seen], axis=-1)  # [P, seen]
                median = np.median(errors, axis=1)
                assert median[code] < 15.0 and np.argmin(median) == code, (camera, f, code, median)
                checked += 1
    assert checked > 0.9 * 3 * 3 * 57


def test_people_keep_min_distance_except_the_passing_pair():
    config = ExampleProjectConfig(people=4, min_distance=600.0, pass_each_other=500.0, motions=("reaching",), frames_per_recording=300)
    bones = people_bones(config)
    poses = people_poses(config, 0, bones, 300)
    distance = {(a, b): pelvis_distance(poses[a], poses[b]) for a in range(4) for b in range(a + 1, 4)}
    passing = distance.pop((0, 1))
    # Level at the middle instant, exactly the stated distance apart; never closer.
    np.testing.assert_allclose(passing[150], 500.0, rtol=1e-9)
    assert np.nanmin(passing) == pytest.approx(500.0, rel=1e-9)
    # Both walk out of the room (NaN) and are in it at the pass.
    assert np.isnan(passing).any() and np.isfinite(passing[140:161]).all()
    for pair, gap in distance.items():
        assert np.nanmin(gap) >= 600.0, pair
    # Without a passing pair every pair keeps min_distance, the subject is the single-person one.
    alone = dataclasses.replace(config, pass_each_other=0.0, people=1)
    apart = people_poses(dataclasses.replace(config, pass_each_other=0.0), 0, bones, 300)
    np.testing.assert_array_equal(apart[0], people_poses(alone, 0, bones[:1], 300)[0])
    assert min(np.nanmin(pelvis_distance(apart[a], apart[b])) for a in range(4) for b in range(a + 1, 4)) >= 600.0


def test_a_person_leaves_and_comes_back(tmp_path):
    config = dataclasses.replace(THREE, people=2, absent_frames=20, false_people_rate=0.0, desync_camera=-1)
    root = write_rig_project(tmp_path / "p", config)
    name = config.recording_names[0]
    points = read_ground_truth(root / name / "ground_truth.npz").points  # [60, 2, 18, 3]
    out = np.isnan(points[:, 1]).all(axis=(1, 2))
    np.testing.assert_array_equal(np.flatnonzero(out), np.arange(20, 40))
    assert np.isfinite(points[:, 0]).all() and np.isfinite(points[~out, 1]).all()
    order = json.loads((root / "example_truth.json").read_text())["recordings"][name]["people_order"]
    for camera in config.camera_names:
        with_second = [1 in codes for codes in order[camera]]
        assert not any(with_second[20:40]) and sum(with_second[:20]) >= 15 and sum(with_second[40:]) >= 15


def test_occlusion_hides_who_is_behind():
    """One person 1.5 m straight behind another as camera 1 sees them: most of its keypoints hidden
    there (its head may show above the other's), fewer by the camera most to the side; the one in front
    loses nothing."""
    config = dataclasses.replace(THREE, people=2, missing_rate=0.0, outlier_rate=0.0, swap_rate=0.0, false_people_rate=0.0)
    rig = rig_calibration(config)
    bones = people_bones(config)
    front = people_poses(dataclasses.replace(config, people=1), 0, bones[:1], 1)[0].astype(np.float64)
    centres = np.asarray(camera_centres(rig.cameras.R, rig.cameras.t))  # [C, 3]
    away = front[0, 0, :2] - centres[0, :2]
    away /= np.linalg.norm(away)
    behind = front.copy()
    behind[..., :2] += 1500.0 * away
    radius2 = field_radius2(rig.cameras, config.image_size)
    people = [detect(config, rig, radius2, keypoints3d(poses, bones[0], config.layout), (0, k)) for k, poses in enumerate((front, behind))]
    assert all(person.listed.all() and (person.scores > 0).all() for person in people)
    hidden = occlude(rig, people)
    assert isinstance(hidden[1], Person)
    np.testing.assert_array_equal(hidden[0].scores, people[0].scores)
    lost = (hidden[1].scores[0] == 0).sum(-1)  # [C] keypoints hidden in each view
    side = int(np.argmin(np.abs((centres[:, :2] - front[0, 0, :2]) @ away) / np.linalg.norm(centres[:, :2] - front[0, 0, :2], axis=1)))
    assert lost[0] >= 10 and side != 0 and lost[side] < lost[0], (lost, side)
    np.testing.assert_array_equal(hidden[1].keypoints[hidden[1].scores == 0], 0.0)


def test_bad_people_settings_are_one_line():
    with pytest.raises(ValueError, match="pass_each_other needs people >= 2"):
        ExampleProjectConfig(pass_each_other=500.0)
    with pytest.raises(ValueError, match="people must lie in 1..8"):
        ExampleProjectConfig(people=0)
    crowded = ExampleProjectConfig(people=8, min_distance=2500.0, recordings=1, frames_per_recording=20)
    with pytest.raises(ValueError, match="could not place person [0-9] of 8 2500 mm from the others"):
        people_poses(crowded, 0, people_bones(crowded), 20)


# Digests of the single-person projects written before several people existed (commit 0a8999c): the
# files' bytes (npz: their arrays), example_truth.json without the config fields added since.
_SINGLE_PERSON_DIGESTS = {
    "coco17": "4bfb664c1b62c260c9db3e9bf02996dff5f5558dc4a930359dc997a0d03d42a1",
    "body25": "de3a0e018eef230b3a00e062415a1d232629d70734e43b5a42b6abeb1133fa52",
}
_NEW_FIELDS = ("people", "min_distance", "pass_each_other", "false_people_rate", "occlusion", "absent_frames")


@pytest.mark.parametrize("layout", ["coco17", "body25"])
def test_single_person_project_unchanged(tmp_path, layout):
    config = ExampleProjectConfig(
        layout=layout, recordings=2, frames_per_recording=40, cameras=3, second_person_rate=0.5, motions=("walking", "reaching")
    )  # fmt: skip
    root = write_rig_project(tmp_path / "p", config)
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*")):
        if not path.is_file():
            continue
        digest.update(str(path.relative_to(root)).encode())
        if path.suffix == ".npz":
            with np.load(path) as data:
                for key in sorted(data.files):
                    digest.update(key.encode() + data[key].tobytes())
        elif path.name == "example_truth.json":
            truth = json.loads(path.read_text())
            assert set(_NEW_FIELDS) <= set(truth["config"]) and "people_order" not in truth["recordings"]["walking01"]
            for key in _NEW_FIELDS:
                truth["config"].pop(key)
            digest.update(json.dumps(truth, sort_keys=True).encode())
        else:
            digest.update(path.read_bytes())
    assert digest.hexdigest() == _SINGLE_PERSON_DIGESTS[layout]
    assert read_ground_truth(root / "walking01" / "ground_truth.npz").points.shape[1] == 1
    with np.load(root / "walking01" / "ground_truth.npz") as data:
        assert data["points3d"].ndim == 3  # the file keeps the single-person layout [N, J, 3]


def test_ground_truth_person_axis_read_and_checked(tmp_path):
    from jaxpose.formats.errors import DataFormatError
    from jaxpose.formats.rig_folder import write_ground_truth

    points = np.arange(5 * 2 * 3 * 3, dtype=np.float32).reshape(5, 2, 3, 3)
    write_ground_truth(tmp_path / "two.npz", points, np.arange(5), ["a", "b", "c"])
    truth = read_ground_truth(tmp_path / "two.npz")
    np.testing.assert_array_equal(truth.points, points)
    write_ground_truth(tmp_path / "one.npz", points[:, 0], np.arange(5), ["a", "b", "c"])
    np.testing.assert_array_equal(read_ground_truth(tmp_path / "one.npz").points, points[:, :1])
    write_ground_truth(tmp_path / "bad.npz", points[..., None], np.arange(5), ["a", "b", "c"])
    with pytest.raises(DataFormatError, match=r"bad.npz.*points3d \[N, J, 3\] or \[N, P, J, 3\]") as error:
        read_ground_truth(tmp_path / "bad.npz")
    assert "\n" not in str(error.value)


def test_rig_loader_reads_every_ground_truth_person(three):
    """The rig loader takes the ground truth of every person (matched to the people it tracks later:
    tests/rig/test_every_person.py), on the instants asked, NaN at an instant the file lacks."""
    from jaxpose.rig.recordings import ground_truth_on_instants
    from jaxpose.skeleton import COCO_17

    target, count = ground_truth_on_instants(three / THREE.recording_names[0], COCO_17, "coco17", np.arange(-1, 60))
    assert target.shape == (61, 3, COCO_17.num_joints, 3) and count == 60
    assert np.isnan(target[0]).all() and np.isfinite(target[1:]).any()


def test_person_0_is_the_single_person_projects_subject(three, tmp_path):
    """Person 0's detections are those of the single-person project of the same config (one body, one
    motion, one detector stream), so that a person reconstructed among others compares with it alone."""
    alone = write_rig_project(tmp_path / "alone", dataclasses.replace(THREE, people=1, false_people_rate=0.0))
    name = THREE.recording_names[0]
    order = json.loads((three / "example_truth.json").read_text())["recordings"][name]["people_order"]
    compared = 0
    for camera in THREE.camera_names:
        for codes, people, single in zip(order[camera], read_frames(three, name, camera), read_frames(alone, name, camera)):
            if 0 in codes:
                np.testing.assert_array_equal(people[codes.index(0)], single[0])
                compared += 1
    assert compared >= 0.9 * THREE.cameras * THREE.frames_per_recording
    np.testing.assert_array_equal(
        read_ground_truth(three / name / "ground_truth.npz").points[:, 0], read_ground_truth(alone / name / "ground_truth.npz").points[:, 0]
    )
