"""The embedded example rig project (`jaxpose.synthetic.project`): OpenPose JSON frames as OpenPose
writes them, a calibration that reads back to the generator's rig, ground truth that projects onto the
detections, a desynchronized camera, a second person, determinism, both layouts, the command line."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from pathlib import Path

import numpy as np
import pytest
from help_text import assert_every_flag_documented

from jaxpose.camera import project
from jaxpose.formats.calibration_files import read_rig_calibration
from jaxpose.synthetic import ExampleProjectConfig, keypoints3d, rig_calibration, write_rig_project
from jaxpose.synthetic.project import main
from jaxpose.layouts import OPENPOSE_25_JOINT_NAMES
from jaxpose.skeleton import COCO_17
import paths

# Small projects: a fast walk (so that a 3-frame shift shows) and a slower motion, a second person
# in a quarter of the frames.
COCO = ExampleProjectConfig(recordings=2, frames_per_recording=80, motions=("walking", "reaching"), second_person_rate=0.25)
BODY25 = dataclasses.replace(COCO, layout="body25", recordings=1, frames_per_recording=60, seed=3)
REAL_OPENPOSE = paths.FORMATS / "openpose-json"
PERSON_KEYS = [
    "person_id", "pose_keypoints_2d", "face_keypoints_2d", "hand_left_keypoints_2d", "hand_right_keypoints_2d",
    "pose_keypoints_3d", "face_keypoints_3d", "hand_left_keypoints_3d", "hand_right_keypoints_3d",
]  # fmt: skip


@pytest.fixture(scope="module")
def coco_project(tmp_path_factory) -> Path:
    return write_rig_project(tmp_path_factory.mktemp("coco") / "project", COCO)


@pytest.fixture(scope="module")
def body25_project(tmp_path_factory) -> Path:
    return write_rig_project(tmp_path_factory.mktemp("body25") / "project", BODY25)


def read_camera(folder: Path, values: int) -> list[np.ndarray]:
    """Each frame file's people as f64[P, values // 3, 3], in frame order."""
    frames = []
    for path in sorted(folder.iterdir()):
        people = json.loads(path.read_text())["people"]
        keypoints = np.array([person["pose_keypoints_2d"] for person in people], np.float64)
        frames.append(keypoints.reshape(len(people), values // 3, 3))
    return frames


def subject_errors(frames: list[np.ndarray], projected: np.ndarray, shift: int) -> np.ndarray:
    """Pixel errors of the detections (the person nearest the projection, each frame) against the
    projection f[N, K, 2] of instant f + shift, for the file f."""
    errors = []
    for f, people in enumerate(frames):
        if not 0 <= f + shift < len(projected) or len(people) == 0:
            continue
        distance = np.linalg.norm(people[..., :2] - projected[f + shift], axis=-1)
        detected = people[..., 2] > 0
        median = [np.median(d[m]) for d, m in zip(distance, detected)]
        best = int(np.argmin(median))
        errors.append(distance[best][detected[best]])
    return np.concatenate(errors)


@pytest.mark.parametrize("layout", ["coco17", "body25"])
def test_files_are_openpose_frames(layout, coco_project, body25_project):
    root, config = (coco_project, COCO) if layout == "coco17" else (body25_project, BODY25)
    values = {"coco17": 51, "body25": 75}[layout]
    width, height = config.image_size
    assert sorted(p.name for p in root.iterdir()) == sorted(
        [*config.recording_names, "calibration.toml", "example_truth.json"]
    )
    for recording in config.recording_names:
        assert sorted(p.name for p in (root / recording).iterdir()) == sorted(
            [f"{camera}_json" for camera in config.camera_names] + ["ground_truth.npz"]
        )
        for camera in config.camera_names:
            paths = sorted((root / recording / f"{camera}_json").iterdir())
            pattern = re.compile(rf"{recording}_{camera}_(\d{{12}})_keypoints\.json")
            assert [int(pattern.fullmatch(p.name).group(1)) for p in paths] == list(range(config.frames_per_recording))
            for path in paths:
                text = path.read_text()
                assert " " not in text and "\n" not in text  # compact, no trailing newline
                document = json.loads(text)
                assert list(document) == ["version", "people"] and document["version"] == 1.3
                for person in document["people"]:
                    assert list(person) == PERSON_KEYS and person["person_id"] == [-1]
                    assert all(person[key] == [] for key in PERSON_KEYS[2:])
                    keypoints = np.array(person["pose_keypoints_2d"], np.float64).reshape(-1, 3)
                    assert keypoints.size == values
                    detected = keypoints[:, 2] > 0
                    assert np.all(keypoints[~detected] == 0.0)  # undetected: 0, 0, 0
                    assert np.all(keypoints[detected, 2] <= 1.0)
                    assert np.all((keypoints[detected, 0] >= 0) & (keypoints[detected, 0] < width))
                    assert np.all((keypoints[detected, 1] >= 0) & (keypoints[detected, 1] < height))
                    assert detected.sum() >= 5
    # Scores: lower for the noisy distal joints than for the torso.
    frames = read_camera(root / config.recording_names[0] / "cam01_json", values)
    scores = np.concatenate([people[:1, :, 2] for people in frames if len(people)])
    names = [name.lower() for name in (COCO_17.joint_names if layout == "coco17" else OPENPOSE_25_JOINT_NAMES)]
    wrists = [i for i, name in enumerate(names) if "wrist" in name]
    shoulders = [i for i, name in enumerate(names) if "shoulder" in name]
    wrist_scores, shoulder_scores = scores[:, wrists].ravel(), scores[:, shoulders].ravel()
    assert np.median(wrist_scores[wrist_scores > 0]) < np.median(shoulder_scores[shoulder_scores > 0])


@pytest.mark.skipif(not REAL_OPENPOSE.is_dir(), reason="the real OpenPose samples are not on this machine")
def test_frames_are_laid_out_as_real_openpose_output(coco_project):
    real_text = (REAL_OPENPOSE / "pose2sim_demo_balancing_body25b" / "cam01_json" / "cam01.0000.json").read_text()
    ours_text = (coco_project / COCO.recording_names[0] / "cam01_json").iterdir().__next__().read_text()
    real, ours = json.loads(real_text), json.loads(ours_text)
    assert list(ours) == list(real) and ours["version"] == real["version"]
    assert list(ours["people"][0]) == list(real["people"][0]) == PERSON_KEYS
    assert all(ours["people"][0][key] == real["people"][0][key] for key in PERSON_KEYS[2:])
    assert ours_text == json.dumps(ours, separators=(",", ":"))  # compact, numbers as they read back

    def digits(text: str) -> set[int]:  # significant digits of the numbers written
        numbers = re.findall(r"(?<=[\[,])-?[\d.]+(?=[,\]])", text.split('"pose_keypoints_2d":')[1])
        return {len(number.lstrip("-").replace(".", "").lstrip("0")) for number in numbers}

    assert max(digits(ours_text)) == max(digits(real_text)) == 6


def test_calibration_reads_back_to_the_generators_rig(coco_project):
    read = read_rig_calibration(coco_project / "calibration.toml")
    rig = rig_calibration(COCO)
    assert read.camera_names == rig.camera_names == COCO.camera_names
    assert read.unit == "m" and read.cameras.distortion_model == "opencv"
    np.testing.assert_array_equal(read.image_size, [COCO.image_size] * COCO.cameras)
    for field in ("K", "R", "dist"):
        np.testing.assert_allclose(getattr(read.cameras, field), getattr(rig.cameras, field), rtol=0, atol=1e-9)
    np.testing.assert_allclose(read.cameras.t, rig.cameras.t, rtol=0, atol=1e-6)  # mm, through metres
    assert np.all(np.asarray(rig.cameras.dist)[:, 0] < 0)  # the lenses are distorted (barrel)
    pinhole = rig_calibration(dataclasses.replace(COCO, distortion=False))
    assert pinhole.cameras.dist is None
    np.testing.assert_allclose(pinhole.cameras.R, rig.cameras.R)


@pytest.mark.parametrize("layout", ["coco17", "body25"])
def test_ground_truth_projects_onto_the_detections(layout, coco_project, body25_project):
    root, config = (coco_project, COCO) if layout == "coco17" else (body25_project, BODY25)
    values = {"coco17": 51, "body25": 75}[layout]
    truth = json.loads((root / "example_truth.json").read_text())
    rig = read_rig_calibration(root / "calibration.toml")
    recording = config.recording_names[0]  # the walk
    with np.load(root / recording / "ground_truth.npz") as data:
        points, frames, names = data["points3d"], data["frames"], data["joint_names"]
    K = values // 3
    assert points.dtype == np.float32 and points.shape == (config.frames_per_recording, K + (layout == "coco17"), 3)
    assert frames.dtype == np.int64 and np.array_equal(frames, np.arange(config.frames_per_recording))
    assert list(names) == truth["ground_truth_joint_names"]
    if layout == "coco17":
        assert list(names) == [*COCO_17.joint_names, "pelvis"]
        hips = [COCO_17.joint_names.index("left_hip"), COCO_17.joint_names.index("right_hip")]
        np.testing.assert_allclose(points[:, -1], points[:, hips].mean(1), atol=1e-3)
    else:
        assert tuple(names) == OPENPOSE_25_JOINT_NAMES
    assert truth["desynchronized_camera"] == config.camera_names[config.desync_camera]
    assert truth["desync_offset_frames"] == config.desync_frames == 3
    for c, camera in enumerate(config.camera_names):
        projected = np.asarray(project(rig.cameras[c], points[:, :K].astype(np.float64)))
        detections = read_camera(root / recording / f"{camera}_json", values)
        medians = {shift: float(np.median(subject_errors(detections, projected, shift))) for shift in range(-5, 6)}
        offset = truth["frame_offsets"][camera]
        assert offset == (config.desync_frames if c == config.desync_camera else 0)
        assert min(medians, key=medians.get) == offset, (camera, medians)
        assert medians[offset] < 10.0, (camera, medians)  # the detector's noise: 3-8 px per axis
        if offset:
            assert medians[0] > medians[offset] + 2.0  # read unshifted, the desynchronized camera is off


def test_second_person(coco_project):
    truth = json.loads((coco_project / "example_truth.json").read_text())
    rig = read_rig_calibration(coco_project / "calibration.toml")
    N = COCO.frames_per_recording
    first_somewhere = 0
    for recording in COCO.recording_names:
        record = truth["recordings"][recording]
        with np.load(coco_project / recording / "ground_truth.npz") as data:
            points = data["points3d"][:, :17].astype(np.float64)
        seen_by = {camera: set(record["second_person_frames"][camera]) for camera in COCO.camera_names}
        with_second = set().union(*seen_by.values())
        assert 0 < len(with_second) <= 0.3 * N  # a quarter of the frames at most, where any camera sees it
        # Only some cameras see the passer-by: at every frame with it, some camera does not list it.
        for frame in with_second:
            assert any(frame not in frames for frames in seen_by.values())
        for c, camera in enumerate(COCO.camera_names):
            offset = truth["frame_offsets"][camera]
            projected = np.asarray(project(rig.cameras[c], points))
            detections = read_camera(coco_project / recording / f"{camera}_json", 51)
            first = set(record["second_person_first_frames"][camera])
            absent = set(record["subject_undetected_frames"][camera])
            assert first <= seen_by[camera]
            first_somewhere += len(first)
            for f, people in enumerate(detections):
                assert len(people) == (f not in absent) + (f in seen_by[camera])
                if len(people) == 2 and 0 <= f + offset < N:
                    distance = np.linalg.norm(people[..., :2] - projected[f + offset], axis=-1)
                    median = [np.median(d[p[:, 2] > 0]) for d, p in zip(distance, people)]
                    subject = 1 if f in first else 0
                    assert median[subject] < 20.0 and median[1 - subject] > 100.0, (recording, camera, f, median)
    # "Take the first person" is wrong in about half of the frames with two people.
    two_people = sum(
        len(truth["recordings"][r]["second_person_frames"][c]) for r in COCO.recording_names for c in COCO.camera_names
    )
    assert 0.25 * two_people <= first_somewhere <= 0.75 * two_people


def test_deterministic_for_a_seed(tmp_path):
    config = ExampleProjectConfig(recordings=1, frames_per_recording=20, cameras=3, second_person_rate=0.5)

    def digest(root: Path) -> dict[str, str]:
        out = {}
        for path in sorted(root.rglob("*")):
            if path.suffix == ".npz":
                with np.load(path) as data:
                    content = b"".join(data[key].tobytes() for key in data.files)
                out[str(path.relative_to(root))] = hashlib.sha256(content).hexdigest()
            elif path.is_file():
                out[str(path.relative_to(root))] = hashlib.sha256(path.read_bytes()).hexdigest()
        return out

    first = digest(write_rig_project(tmp_path / "a", config))
    assert first == digest(write_rig_project(tmp_path / "b", config))
    other = digest(write_rig_project(tmp_path / "c", dataclasses.replace(config, seed=1)))
    assert first.keys() == other.keys() and first != other
    # Writing again over an example project replaces it; any other non-empty folder is refused.
    write_rig_project(tmp_path / "a", dataclasses.replace(config, motions=("sitting",)))
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["calibration.toml", "example_truth.json", "sitting01"]
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "mine.txt").write_text("keep")
    with pytest.raises(FileExistsError):
        write_rig_project(tmp_path / "d", config)


def test_keypoints3d_are_anatomical():
    config = ExampleProjectConfig()
    from jaxpose.synthetic import sample_bone_lengths, sample_motion
    from jaxpose.synthetic.config import Stream, stream_rng

    synthetic = config.synthetic_config()
    bones = sample_bone_lengths(stream_rng(synthetic, Stream.BODY, 0))
    poses = sample_motion(np.random.default_rng(0), "walking", bones, 200, synthetic).poses
    body25 = keypoints3d(poses, bones, "body25")
    coco = keypoints3d(poses, bones, "coco17")
    index = {name: k for k, name in enumerate(OPENPOSE_25_JOINT_NAMES)}

    def distance(a: str, b: str) -> np.ndarray:
        return np.linalg.norm(body25[:, index[a]] - body25[:, index[b]], axis=-1)

    assert np.all((distance("LEye", "REye") > 50) & (distance("LEye", "REye") < 75))
    assert np.all((distance("LEar", "REar") > 110) & (distance("LEar", "REar") < 170))
    assert np.all((distance("LBigToe", "LHeel") > 170) & (distance("LBigToe", "LHeel") < 280))
    feet = [index[f"{side}{point}"] for side in "LR" for point in ("BigToe", "SmallToe", "Heel")]
    assert body25[:, feet, 2].min() > -10.0  # on or above the floor (a few mm into it at worst, pushing off)
    np.testing.assert_allclose(body25[:, index["MidHip"]], body25[:, [index["LHip"], index["RHip"]]].mean(1))
    np.testing.assert_allclose(body25[:, index["Neck"]], body25[:, [index["LShoulder"], index["RShoulder"]]].mean(1))
    # COCO's keypoints are BODY_25's of the same name.
    for k, name in enumerate(COCO_17.joint_names):
        side = {"left": "L", "right": "R"}.get(name.split("_")[0], "")
        part = name.split("_")[-1].capitalize()
        np.testing.assert_allclose(coco[:, k], body25[:, index[side + part]])


def test_config_is_validated():
    with pytest.raises(ValueError, match="desync_camera"):
        ExampleProjectConfig(cameras=2, desync_camera=2)
    with pytest.raises(ValueError, match="motion"):
        ExampleProjectConfig(motions=("juggling",))
    with pytest.raises(ValueError, match="second_person_rate"):
        ExampleProjectConfig(second_person_rate=1.5)


def test_command_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--help"])
    assert stop.value.code == 0
    flags = ["--" + field.name.replace("_", "-") for field in dataclasses.fields(ExampleProjectConfig)] + ["--output"]
    assert_every_flag_documented(capsys.readouterr().out, flags)
    root = main([
        "--output", str(tmp_path / "p"), "--layout", "body25", "--recordings", "1", "--frames-per-recording", "12",
        "--cameras", "2", "--desync-camera", "1", "--desync-frames", "-2",
    ])  # fmt: skip
    out = capsys.readouterr().out
    assert "cam02 is -2 frames out of sync" in out and "python -m experiments.rig --data.root" in out
    truth = json.loads((root / "example_truth.json").read_text())
    assert truth["layout"] == "body25" and truth["frame_offsets"] == {"cam01": 0, "cam02": -2}
    assert len(list((root / "walking01" / "cam02_json").iterdir())) == 12
