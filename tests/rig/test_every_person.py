"""The rig loader keeps every person (`jaxpose.rig.tracked`): a prepared row per (instant, person), person k
numbered from 1 in order of first appearance, each with its own ground truth; what is no person (a track the
detector scores low, a person in one view, an empty entry, a crowd beyond `MAX_PEOPLE`) is left out and said;
Pose2Sim's multi-person demo gives its real person and its ghost, one identity each from the first frame to the
last, and not its false detections."""

from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path

import numpy as np
import pytest

from jaxpose.rig import tracked
from jaxpose.rig.config import RigProjectConfig
from jaxpose.rig.project import load_rig_project, prepared_project
from jaxpose.rig.recordings import MAX_PEOPLE, find_project, truth_of_people
from jaxpose.rig.split import every_instant, person_names
from jaxpose.synthetic import ExampleProjectConfig, write_rig_project
from tests.paths import FORMATS

# Pinhole cameras, so that numpy's K [R | t] is the oracle of where a ground-truth person is seen.
TWO = ExampleProjectConfig(
    recordings=1, frames_per_recording=60, people=2, second_person_rate=0.0, distortion=False, motions=("walking",),
    swap_rate=0.0, desync_camera=-1,
)  # fmt: skip
DEMO = FORMATS / "openpose-json" / "pose2sim_demo_multiperson_body25b"
DEMO_CALIBRATION = FORMATS / "pose2sim-calib-toml" / "pose2sim_demo_Calib_qualisys.toml"


@pytest.fixture(scope="module")
def two(tmp_path_factory) -> Path:
    return write_rig_project(tmp_path_factory.mktemp("two") / "project", TWO)


def every_row(root: Path, **settings):
    config = RigProjectConfig(root=root, **settings)
    prepared = prepared_project(config, find_project(root, (), config.calibration), progress=False)
    return prepared, every_instant(prepared).instants


def reprojection_px(dataset, target: np.ndarray) -> np.ndarray:
    """f64[R]: each row's median pixel distance of its detections from its ground truth's projection (numpy pinhole)."""
    rig = dataset.rigs
    K, R, t = (np.asarray(getattr(rig, name), np.float64)[0] for name in ("K", "R", "t"))
    camera = np.einsum("cij,rkj->rcki", R, target.astype(np.float64)) + t[None, :, None]
    pixels = np.einsum("cij,rckj->rcki", K, camera / camera[..., 2:])[..., :2]
    distance = np.linalg.norm(pixels - np.asarray(dataset.samples.keypoints2d, np.float64), axis=-1)
    seen = np.asarray(dataset.samples.confidence) > 0
    return np.array([np.median(d[s]) if s.any() else np.nan for d, s in zip(distance, seen)])


def test_two_people_are_two_persons_rows_each_with_its_own_ground_truth(two):
    prepared, rows = every_row(two)
    labels = rows.samples.labels
    (summary,) = prepared.meta.recordings
    assert summary.people == (60, 60) and summary.implausible_tracks == 0  # both people at every instant
    assert len(labels["frame"]) == sum(summary.people)  # the sum of both people's instants
    assert list(np.unique(labels["person"])) == [1, 2]
    name = TWO.recording_names[0]
    assert sorted(set(labels["sequence"])) == [f"{name}.person1", f"{name}.person2"]
    for k in (1, 2):
        mine = labels["person"] == k
        np.testing.assert_array_equal(labels["frame"][mine], np.arange(60))  # each person's instants in order
    # Each person's ground truth is theirs: it projects onto their own detections, not the other's.
    target = np.asarray(rows.samples.target3d)
    assert np.isfinite(target).all()
    own = reprojection_px(rows, target)
    swapped = np.concatenate([target[labels["person"] == 2], target[labels["person"] == 1]])
    other = reprojection_px(rows, swapped)
    assert np.median(own) < 15.0 and np.median(other) > 100.0  # the detector's noise: a few pixels, (np.median(own), np.median(other))


def test_training_parts_split_each_person(two):
    project = load_rig_project(RigProjectConfig(root=two), progress=False)
    counts = [np.bincount(part.samples.labels["person"], minlength=3)[1:] for part in (project.train, project.validation)]
    # --data.validation-fraction 0.2 of each person's 60 instants.
    assert [list(count) for count in counts] == [[48, 48], [12, 12]]


def test_truth_of_people_pairs_each_person_with_its_nearest_truth():
    rng = np.random.default_rng(0)
    truth = (rng.normal(0.0, 300.0, (10, 3, 5, 3)) + np.array([0.0, 2000.0, 4000.0])[None, :, None, None]).astype(np.float32)
    instant = np.tile(np.arange(10), 3)
    person = np.repeat([1, 2, 3], 10)
    # Person 1 is truth 2, person 2 truth 0; person 3 is nobody's (a metre off every truth).
    points = np.concatenate([truth[:, 2] + 5.0, truth[:, 0] - 5.0, truth[:, 1] + 1000.0])
    out = truth_of_people(truth, instant, person, points)
    np.testing.assert_array_equal(out[:10], truth[:, 2])
    np.testing.assert_array_equal(out[10:20], truth[:, 0])
    assert np.isnan(out[20:]).all()


def test_person_names_keep_a_lone_persons_recording_name():
    names = person_names(np.array(["a", "a", "b", "b", "b"]), np.array([1, 1, 1, 2, 2]))
    assert list(names) == ["a", "a", "b.person1", "b.person2", "b.person2"]


def test_a_track_the_detector_scores_low_is_no_person():
    assert tracked.plausible(np.full(50, 0.6)) and not tracked.plausible(np.full(50, 0.38)) and not tracked.plausible(np.zeros(0))


def _edit_frames(root: Path, recording: str, camera: str, edit) -> None:
    """Rewrite every frame file of a camera: edit(frame index, people list, codes) -> people list."""
    order = json.loads((root / "example_truth.json").read_text())["recordings"][recording]["people_order"][camera]
    for index, path in enumerate(sorted((root / recording / f"{camera}_json").iterdir())):
        content = json.loads(path.read_text())
        content["people"] = edit(index, content["people"], order[index])
        path.write_text(json.dumps(content))


def _rows_by_person(rows) -> dict[int, np.ndarray]:
    labels = rows.samples.labels
    return {int(k): np.asarray(labels["frame"][labels["person"] == k]) for k in np.unique(labels["person"])}


@pytest.fixture
def hostile(tmp_path) -> Path:
    return write_rig_project(tmp_path / "project", TWO)


def test_hostile_people_lose_nobody(hostile, two, caplog):
    """A frame with 50 detections, people with every joint missing in every frame, a person in one view only
    and a person count that changes every frame: the two people keep every instant they are in, the crowd
    is said in one line."""
    name, cameras = TWO.recording_names[0], TWO.camera_names
    empty = {"person_id": [-1], "pose_keypoints_2d": []}
    blank = {"person_id": [-1], "pose_keypoints_2d": [0.0] * (17 * 3)}
    rng = np.random.default_rng(1)

    def edit(camera):
        def rewrite(index, people, codes):
            kept = [person for person, code in zip(people, codes) if code != 1 or index % 2 == 0]  # person 1: even frames
            if camera == cameras[0]:  # a steady third person seen by this camera only: person 0 moved 300 px aside
                values = people[codes.index(0)]["pose_keypoints_2d"]
                kept.append({"person_id": [-1], "pose_keypoints_2d": [v + 300.0 if j % 3 == 0 and v else v for j, v in enumerate(values)]})
            if index == 30:  # 50 detections: the people and faint false ones
                kept += [{"person_id": [-1], "pose_keypoints_2d": [v for _ in range(17) for v in (*rng.uniform(0, 1000, 2), 0.15)]}
                         for _ in range(50 - len(kept))]  # fmt: skip
            return kept + [empty, blank]  # people with every joint missing, in every frame

        return rewrite

    for camera in cameras:
        _edit_frames(hostile, name, camera, edit(camera))
    with caplog.at_level(logging.WARNING, logger="jaxpose.rig.recordings"):
        prepared, rows = every_row(hostile)
    crowded = [record.getMessage() for record in caplog.records if "people detected" in record.getMessage()]
    assert len(crowded) == len(cameras) and all(f"1 frames with more than {MAX_PEOPLE} people" in line for line in crowded)
    frames = _rows_by_person(rows)
    assert sorted(frames) == [1, 2]
    always, even = sorted(frames.values(), key=len, reverse=True)
    np.testing.assert_array_equal(always, np.arange(60))  # one person at every instant, the crowd's frame too
    np.testing.assert_array_equal(even, np.arange(0, 60, 2))  # the other where it is listed: every second frame
    # The one-view person is nobody's: each person's rows hold their own detections (within pixels of the
    # unedited project's), and the one-view copy is counted as a view without match nowhere else.
    _, clean = every_row(two)
    clean_keypoints = np.asarray(clean.samples.keypoints2d)
    labels = clean.samples.labels
    for k, kept in frames.items():
        edited = np.asarray(rows.samples.keypoints2d)[rows.samples.labels["person"] == k]
        original = clean_keypoints[labels["person"] == k][np.isin(labels["frame"][labels["person"] == k], kept)]
        seen = np.asarray(rows.samples.confidence)[rows.samples.labels["person"] == k] > 0
        np.testing.assert_allclose(edited[seen], original[seen], atol=1e-3)


@pytest.mark.skipif(not (DEMO.exists() and DEMO_CALIBRATION.exists()), reason="Pose2Sim's demo is not in ../shared/data")
def test_pose2sim_multiperson_demo_is_its_real_person_and_its_ghost(tmp_path):
    """Real detections of one person, a synthetic ghost consistent across the four views, and false detections
    in cameras 1 and 2 that agree with each other (a body 4.5 m off, scored low): two people, each one identity
    from the first frame to the last, the false detections' track left out and counted."""
    recording = tmp_path / "project" / "demo"
    recording.mkdir(parents=True)
    for camera in range(1, 5):  # the calibration names its cameras cam_01 .. cam_04
        (recording / f"cam_0{camera}_json").symlink_to(DEMO / f"cam0{camera}_json")
    prepared, rows = every_row(tmp_path / "project", calibration=DEMO_CALIBRATION, skeleton="body25b", cache_dir=tmp_path / "cache")
    (summary,) = prepared.meta.recordings
    assert summary.people == (100, 100) and summary.implausible_tracks >= 1
    frames = _rows_by_person(rows)
    assert all(np.array_equal(kept, np.arange(100)) for kept in frames.values())
    kinds = []
    for k in (1, 2):
        confidence = np.asarray(rows.samples.confidence)[rows.samples.labels["person"] == k]
        scores = confidence[confidence > 0]
        # The ghost's scores are exactly 1 (the lifting skeleton's derived joints aside: their parents' lowest).
        kinds.append("ghost" if np.median(scores) == 1.0 else "real")
        assert ((confidence > 0).any(-1).sum(-1) >= 3).mean() > 0.9  # seen by three cameras or four, not by 1 and 2 only
    assert sorted(kinds) == ["ghost", "real"]


def test_several_people_compile_nothing_more_for_more_and_longer_recordings(two, tmp_path):
    """The people of a project are found and tracked in the loader's fixed-size chunks: after one project of two
    people, another of more and shorter recordings of two people lowers no program anew."""
    from compilations import compilations

    every_row(two)
    more = write_rig_project(tmp_path / "more", dataclasses.replace(TWO, recordings=3, frames_per_recording=41))
    with compilations() as found:
        prepared, _ = every_row(more)
    assert [summary.people for summary in prepared.meta.recordings] == [(41, 41)] * 3
    assert found["lowered"] == 0, found


def test_the_run_report_counts_samples_per_person(two):
    from jaxpose.training.report import samples_per_person, samples_per_person_table

    project = load_rig_project(RigProjectConfig(root=two), progress=False)
    name = TWO.recording_names[0]
    counts = {part: samples_per_person(dataset) for part, dataset in (("train", project.train), ("test", project.validation))}
    assert counts == {"train": {f"{name}.person1": 48, f"{name}.person2": 48}, "test": {f"{name}.person1": 12, f"{name}.person2": 12}}
    table = samples_per_person_table(counts)
    assert f"| {name}.person2 | 48 | 12 |" in table and table.endswith("| all | 96 | 24 |")


def test_a_known_count_of_people_starts_no_more_tracks(two, tmp_path):
    """--data.people 1 on two people: one track, the other person's detections given to it where it is unseen
    (never, here: both are at every instant), so one person of 60 instants, as the choice prepared it."""
    prepared, rows = every_row(two, people=1, cache_dir=tmp_path / "cache")
    assert [summary.people for summary in prepared.meta.recordings] == [(60,)]
    assert list(np.unique(rows.samples.labels["person"])) == [1]
    with pytest.raises(ValueError, match=r"--data.people is how many people .* got 0"):
        RigProjectConfig(root=two, people=0)
