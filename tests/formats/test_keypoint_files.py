"""Per-camera 2D detection files (`jaxpose.formats.keypoint_files`, COCO files parsed by `coco_results`):
the real samples as they are, the refusals, frame numbers and the process pool (the cache: test_file_cache)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxpose.formats import coco_results, file_pool
from jaxpose.formats import keypoint_files as kf
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.frame_numbers import frame_number
from keypoint_writers import check_matches, coco_entry, openpose_document, random_people, write_folder, write_frame
import paths

FORMATS = paths.FORMATS
needs_formats = pytest.mark.skipif(not FORMATS.is_dir(), reason=f"{FORMATS} (the real format samples) is absent")
BODY25B = FORMATS / "openpose-json" / "pose2sim_demo_balancing_body25b"
HALPE26 = FORMATS / "openpose-json" / "pose2sim_rtmpose_halpe26_2cam"
SPIN = FORMATS / "openpose-json" / "spin_im1010_single_image"
ALPHAPOSE = FORMATS / "coco-keypoint-results" / "alphapose_hockey_alphapose-results.json"
COCOAPI = FORMATS / "coco-keypoint-results" / "cocoapi_person_keypoints_val2014_fakekeypoints100_results.json"


def check_types(detections: kf.CameraDetections) -> None:
    F, P, J, two = detections.keypoints.shape
    assert two == 2 and detections.scores.shape == (F, P, J) and detections.people.shape == (F,)
    assert detections.frames.dtype == np.int64 and detections.people.dtype == np.int32
    assert detections.keypoints.dtype == np.float32 and detections.scores.dtype == np.float32
    assert (np.diff(detections.frames) > 0).all() and detections.values_per_person == 3 * J


# ---------------------------------------------------------------------------------------------
# The real samples, read as they are


@needs_formats
@pytest.mark.parametrize("camera, people", [("cam01_json", 2), ("cam02_json", 2), ("cam03_json", 1), ("cam04_json", 1)])
def test_pose2sim_body25b_demo(camera, people):
    folder = BODY25B / camera
    detections = kf.read_openpose_folder(folder, progress=False)
    check_types(detections)
    assert detections.frames.tolist() == list(range(20)) and detections.source == str(folder)
    assert detections.people.tolist() == [people] * 20 and detections.keypoints.shape == (20, people, 25, 2)
    assert detections.values_per_person == 75
    first = json.loads((folder / f"{camera[:5]}.0000.json").read_text())["people"][0]["pose_keypoints_2d"]
    np.testing.assert_allclose(detections.keypoints[0, 0], np.reshape(first, (25, 3))[:, :2], rtol=1e-6)
    np.testing.assert_allclose(detections.scores[0, 0], np.reshape(first, (25, 3))[:, 2], rtol=1e-6)
    assert 0 < detections.scores.max() <= 1
    # Pixels inside the demo's 1088 x 1920 portrait frames.
    assert detections.keypoints[..., 0].max() < 1088 and detections.keypoints[..., 1].max() < 1920
    dispatched = kf.read_camera_detections(folder, progress=False)
    np.testing.assert_array_equal(dispatched.keypoints, detections.keypoints)


@needs_formats
@pytest.mark.parametrize("camera", ["cam03", "cam04"])
def test_pose2sim_rtmpose_halpe26(camera):
    detections = kf.read_camera_detections(HALPE26 / camera, progress=False)
    check_types(detections)
    assert detections.frames.tolist() == list(range(1, 21))  # 1-based frame_00001.json ... frame_00020.json
    assert detections.values_per_person == 78 and detections.people.tolist() == [1] * 20
    document = json.loads((HALPE26 / camera / "frame_00007.json").read_text())
    values = np.reshape(document["people"][0]["pose_keypoints_2d"], (26, 3))
    np.testing.assert_allclose(detections.keypoints[6, 0], values[:, :2], rtol=1e-6)
    written = [json.loads(path.read_text())["people"][0]["pose_keypoints_2d"][2::3] for path in (HALPE26 / camera).iterdir()]
    assert detections.clipped_scores == (np.array(written) > 1).sum()  # RTMPose's SimCC maxima: cam04 up to 1.015
    assert detections.scores.max() <= 1 and (camera == "cam03" or detections.clipped_scores > 0)
    # HALPE_26: joint 19 (hip) is about the midpoint of the two hips (11, 12).
    hips = detections.keypoints[:, 0, [11, 12]].mean(1)
    assert np.abs(detections.keypoints[:, 0, 19] - hips).max() < 25.0  # px, in 1088 x 1920 frames


@needs_formats
def test_spin_single_openpose_file():
    for path in (SPIN, SPIN / "im1010_openpose.json"):
        detections = kf.read_camera_detections(path, progress=False)
        check_types(detections)
        assert detections.frames.tolist() == [1010] and detections.people.tolist() == [1]
        assert detections.values_per_person == 75  # version 1.2, no person_id
        assert detections.scores[0, 0, 3] == 0 and not detections.keypoints[0, 0, 3].any()  # written 0, 0, 0
        mid_hip = detections.keypoints[0, 0, [9, 12]].mean(0)  # BODY_25: MidHip (8) between the hips
        assert np.abs(detections.keypoints[0, 0, 8] - mid_hip).max() < 3.0
    np.testing.assert_array_equal(kf.read_openpose_folder(SPIN, progress=False).keypoints, detections.keypoints)


@needs_formats
def test_alphapose_results():
    detections = kf.read_camera_detections(ALPHAPOSE)
    check_types(detections)
    entries = json.loads(ALPHAPOSE.read_text())
    assert {e["image_id"] for e in entries} == {"out-002.jpg"} and max(e["score"] for e in entries) > 1
    assert detections.frames.tolist() == [2] and detections.people.tolist() == [13]
    assert detections.keypoints.shape == (1, 13, 17, 2) and detections.values_per_person == 51
    for person, entry in enumerate(entries):  # file order within the frame
        values = np.reshape(entry["keypoints"], (17, 3))
        np.testing.assert_allclose(detections.keypoints[0, person], values[:, :2], rtol=1e-6)
        np.testing.assert_allclose(detections.scores[0, person], values[:, 2], rtol=1e-6)
    image_ids, keypoints = coco_results.load_coco_entries(ALPHAPOSE)
    assert image_ids == ["out-002.jpg"] * 13 and keypoints.shape == (13, 17, 3)


@needs_formats
def test_cocoapi_results():
    detections = kf.read_coco_results(COCOAPI)
    check_types(detections)
    entries = json.loads(COCOAPI.read_text())
    ids = [e["image_id"] for e in entries]
    assert len(entries) == 125 and detections.frames.tolist() == sorted(set(ids)) and len(detections.frames) == 47
    assert detections.people.tolist() == [ids.count(i) for i in sorted(set(ids))] and detections.people.sum() == 125
    frame = int(np.argmax(detections.people))
    mine = [e for e in entries if e["image_id"] == detections.frames[frame]]
    for person, entry in enumerate(mine):  # its third values are 0/1/2 visibility flags: 2 is clipped to 1
        np.testing.assert_allclose(detections.scores[frame, person], np.minimum(entry["keypoints"][2::3], 1))
    flags = np.array([e["keypoints"][2::3] for e in entries])
    assert detections.clipped_scores == (flags > 1).sum() == 1314


# ---------------------------------------------------------------------------------------------
# Frame numbers


@pytest.mark.parametrize(
    "name, number",
    [
        ("clip_000000000123_keypoints.json", 123),
        ("video2_000000000000_keypoints.json", 0),
        ("cam01.0010.json", 10),
        ("frame_00001.json", 1),
        ("im1010_openpose.json", 1010),
        ("S00_P00_T01_cam03_000042.json", 42),
    ],
)
def test_frame_number_of_real_names(name, number):
    assert frame_number(name) == number


@settings(max_examples=200, deadline=None)
@given(
    prefix=st.text(st.sampled_from("abcXYZ_-. 0123456789"), max_size=12).filter(lambda s: not s[-1:].isdigit()),
    number=st.integers(0, 10**12),
    width=st.integers(0, 12),
    tail=st.sampled_from(["_keypoints.json", ".json", "_rgb.json", "_keypoints_keypoints.json"]),
)
def test_frame_number_is_the_last_digit_run(prefix, number, width, tail):
    assert frame_number(f"{prefix}{number:0{width}d}{tail}") == number


def test_names_without_digits_and_duplicate_frames_are_refused(tmp_path):
    folder = tmp_path / "cam01_json"
    write_folder(folder, [1, 1], name="cam01.{:04d}.json")
    write_frame(folder / "camA_keypoints.json", random_people(np.random.default_rng(1), 1))
    with pytest.raises(DataFormatError, match=r"camA_keypoints\.json: expected a frame number .*no digits"):
        kf.read_openpose_folder(folder, progress=False)
    (folder / "camA_keypoints.json").unlink()
    write_frame(folder / "cam01.1.json", random_people(np.random.default_rng(1), 1))
    with pytest.raises(DataFormatError, match=r"one file per frame number.*cam01\.0001\.json and cam01\.1\.json"):
        kf.read_openpose_folder(folder, progress=False)


def test_other_files_are_ignored_and_folders_may_lack_the_json_suffix(tmp_path):
    folder = tmp_path / "cam02"  # no _json suffix, 1-based numbering
    written = write_folder(folder, [2, 0, 1, 3], name="frame_{:05d}.json", first=1)
    (folder / "notes.txt").write_text("not a frame")
    (folder / "video.mp4").write_bytes(b"\x00\x01")
    (folder / ".DS_Store.json").write_text("junk")  # hidden files too
    (folder / "sub.json").mkdir()  # and folders
    detections = kf.read_openpose_folder(folder, progress=False)
    check_types(detections)
    check_matches(detections, written)
    assert detections.people.tolist() == [2, 0, 1, 3] and detections.keypoints.shape == (4, 3, 25, 2)


@pytest.mark.parametrize("joints", [17, 18, 25, 26])
def test_skeletons_by_value_count(tmp_path, joints):
    written = write_folder(tmp_path / "cam", [1, 2], joints=joints, seed=joints)
    detections = kf.read_openpose_folder(tmp_path / "cam", progress=False)
    assert detections.values_per_person == 3 * joints
    check_matches(detections, written)


def test_non_finite_values_are_undetected(tmp_path):
    folder = tmp_path / "cam"
    folder.mkdir()
    values = np.arange(75, dtype=float) + 1
    values[3:6] = [np.nan, 5.0, 0.9]
    (folder / "f_1.json").write_text(json.dumps(openpose_document([values])))  # Python's json writes NaN
    detections = kf.read_openpose_folder(folder, progress=False)
    assert not detections.keypoints[0, 0, 1].any() and detections.scores[0, 0, 1] == 0
    assert detections.keypoints[0, 0, 2].tolist() == [7.0, 8.0]


# ---------------------------------------------------------------------------------------------
# The one rule for scores (jaxpose.formats.confidences)


@given(scores=st.lists(st.one_of(st.floats(0, 1), st.floats(1, 1e6)), min_size=1, max_size=40))
def test_scores_above_one_are_clipped_and_counted(tmp_path_factory, scores):
    folder = tmp_path_factory.mktemp("cam")
    values = np.zeros((len(scores), 3))
    values[:, :2], values[:, 2] = 100.0, scores
    (folder / "f_1.json").write_text(json.dumps(openpose_document([values])))
    detections = kf.read_openpose_folder(folder, progress=False)
    written = np.float32(scores)
    np.testing.assert_array_equal(detections.scores[0, 0], np.minimum(written, 1))
    assert detections.clipped_scores == (written > 1).sum()


def test_the_clipped_count_is_cached(tmp_path, monkeypatch):
    folder = tmp_path / "cam"
    written = write_folder(folder, [2, 1])
    written[1][0][:3, 2] = [1.5, 2.0, 1.0]
    write_frame(folder / "clip_000000000001_keypoints.json", written[1])
    first = kf.read_camera_detections(folder, progress=False, cache=tmp_path / "cam.npz")
    monkeypatch.setattr(kf, "_parse_chunk", None)  # served from the cache below
    cached = kf.read_camera_detections(folder, progress=False, cache=tmp_path / "cam.npz")
    assert first.clipped_scores == cached.clipped_scores == 2
    np.testing.assert_array_equal(first.scores, cached.scores)


@pytest.mark.parametrize("kind", ["openpose", "coco"])
def test_a_negative_score_is_refused_naming_where(tmp_path, kind):
    people = random_people(np.random.default_rng(3), 2, joints=17)
    people[1][5] = [300.0, 400.0, -0.25]
    if kind == "openpose":
        source = tmp_path / "cam01_json"
        source.mkdir()
        write_frame(source / "cam01.0041.json", people)
        place = r"cam01\.0041\.json \(frame 41\), person 1, joint 5"
    else:
        source = tmp_path / "cam01.json"
        source.write_text(json.dumps([coco_entry("img_0041.png", person) for person in people]))
        place = r"image_id 'img_0041.png' \(frame 41\), person 1, joint 5"
    with pytest.raises(DataFormatError, match=rf"^{source}: expected detector scores >= 0 .*found -0\.25 at {place}"):
        kf.read_camera_detections(source, progress=False)


# ---------------------------------------------------------------------------------------------
# Refusals: each names the file and the field


@pytest.mark.parametrize(
    "content, message",
    [
        ("[1, 2, 3]", r"f_0002\.json: expected an OpenPose JSON frame .*found a JSON list"),
        ('{"version": 1.3}', r"f_0002\.json: expected an OpenPose JSON frame .*found no 'people' list .*'version'"),
        ('{"people": [{"face_keypoints_2d": []}]}', r"f_0002\.json: .*people\[0\]\.pose_keypoints_2d.*no 'pose_key"),
        ('{"people": [{"pose_keypoints_2d": [1, 2, 3, 4]}]}', r"f_0002\.json: .*pose_keypoints_2d.*4 values, not a"),
        ('{"people": [7]}', r"f_0002\.json: .*people\[0\]\.pose_keypoints_2d.* is a int"),
        ('{"people": [{"pose_keypoints_2d": ["a", 2, 3]}]}', r"f_0002\.json: expected numbers in people\[0\]\.pose_key"),
        ('{"people": [', r"f_0002\.json: .*found invalid JSON: Expecting value: line 1 column 13"),
        (b"\xff\xfe{", r"f_0002\.json: .*found invalid JSON"),
    ],
)
def test_openpose_refusals(tmp_path, content, message):
    folder = tmp_path / "cam"
    write_folder(folder, [1, 1], name="f_{:04d}.json")
    bad = folder / "f_0002.json"
    bad.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(DataFormatError, match=message):
        kf.read_openpose_folder(folder, progress=False)


def test_different_value_counts_name_the_files(tmp_path):
    folder = tmp_path / "cam"
    write_folder(folder, [1, 2, 1], name="f_{:04d}.json")
    write_frame(folder / "f_0003.json", random_people(np.random.default_rng(3), 1, joints=26))
    message = (r"f_0003\.json: expected pose_keypoints_2d with the same number of values .*\(75 as in f_0000\.json\);"
               r" found 78 values; .*75 values \(25 joints\) in 3 file\(s\): f_0000\.json, f_0001\.json, f_0002\.json;"
               r" 78 values \(26 joints\) in 1 file\(s\): f_0003\.json")  # fmt: skip
    with pytest.raises(DataFormatError, match=message):
        kf.read_openpose_folder(folder, progress=False)


def test_missing_and_empty_inputs(tmp_path):
    with pytest.raises(DataFormatError, match="nothing there"):
        kf.read_openpose_folder(tmp_path / "absent", progress=False)
    with pytest.raises(DataFormatError, match="nothing there"):
        kf.read_camera_detections(tmp_path / "absent.json")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("x")
    with pytest.raises(DataFormatError, match=r"empty: expected OpenPose JSON frames .*no \.json file"):
        kf.read_openpose_folder(tmp_path / "empty", progress=False)
    (tmp_path / "poses.csv").write_text("x")
    with pytest.raises(DataFormatError, match=r"found a \.csv file"):
        kf.read_camera_detections(tmp_path / "poses.csv")


@pytest.mark.parametrize(
    "document, message",
    [
        ({"annotations": []}, r"results\.json: expected a COCO keypoint-results list .*found a JSON dict .*annotations"),
        ([[1, 2, 3]], r"results\.json: expected a COCO .*found entry 0 is a list"),
        ([{"keypoints": [1, 2, 3]}], r"results\.json: expected a COCO .*entry 0 is an object without 'image_id' or"),
        ([{"image_id": 3}], r"results\.json: expected a COCO .*entry 0 is an object without 'image_id' or 'keypoi"),
        ([{"image_id": 3, "keypoints": [1, 2]}], r"results\.json: expected keypoints a list of \[x, y, score\].*entry 0"),
        ([{"image_id": 3.5, "keypoints": [1, 2, 3]}], r"results\.json: expected image_id an integer or a file-name"),
        ([coco_entry(1, np.ones(51)), coco_entry(2, np.ones(54))], r"same length .*54 values in entry 1 \(image_id 2\)"),
        ([coco_entry(1, ["a"] * 51)], r"results\.json: expected numbers in keypoints; found entry 0"),
        ([coco_entry("img-1.jpg", np.ones(51)), coco_entry("other-01.jpg", np.ones(51))],
         r"one image_id per frame number.*'img-1\.jpg' and 'other-01\.jpg' are both frame 1"),
        ([coco_entry("cover.jpg", np.ones(51))], r"results\.json: expected image_id an integer or a string with a fr"),
    ],
)  # fmt: skip
def test_coco_refusals(tmp_path, document, message):
    path = tmp_path / "results.json"
    path.write_text(json.dumps(document))
    with pytest.raises(DataFormatError, match=message):
        kf.read_coco_results(path)


def test_coco_invalid_json(tmp_path):
    path = tmp_path / "results.json"
    path.write_text('[{"image_id": 1,')
    with pytest.raises(DataFormatError, match=r"results\.json: .*found invalid JSON: Expecting"):
        kf.read_camera_detections(path)


def test_coco_frames_group_people_in_file_order(tmp_path):
    rng = np.random.default_rng(5)
    people = random_people(rng, 5, joints=17)
    ids = [12, 7, 12, 3, 12]
    path = tmp_path / "results.json"
    path.write_text(json.dumps([coco_entry(i, p, box=[0, 0, 1, 1], idx=[[0.0]]) for i, p in zip(ids, people)]))
    detections = kf.read_coco_results(path)
    check_types(detections)
    check_matches(detections, {3: [people[3]], 7: [people[1]], 12: [people[0], people[2], people[4]]})
    assert kf.read_coco_results(tmp_path / "results.json").source == str(path)
    path.write_text("[]")  # a detector that found nobody
    empty = kf.read_coco_results(path)
    assert empty.frames.shape == (0,) and empty.keypoints.shape == (0, 0, 0, 2)


# ---------------------------------------------------------------------------------------------
# The process pool


def test_pool_equals_sequential(tmp_path, monkeypatch):
    people = list(np.random.default_rng(7).integers(0, 4, 57))
    written = write_folder(tmp_path / "cam01_json", people, name="cam01.{:04d}.json")
    sequential = kf.read_openpose_folder(tmp_path / "cam01_json", progress=False, workers=1)
    monkeypatch.setattr(file_pool, "POOL_MIN_FILES", 10)
    monkeypatch.setattr(file_pool, "POOL_MIN_FILES_SPAWN", 10)
    monkeypatch.setattr(file_pool, "CHUNK_FILES", 5)
    pooled = kf.read_openpose_folder(tmp_path / "cam01_json", progress=False, workers=2)
    check_matches(pooled, written)
    for field in ("frames", "keypoints", "scores", "people"):
        np.testing.assert_array_equal(getattr(pooled, field), getattr(sequential, field))
    # The cache key from the digests the pool's parse computed is the one its digest pass computes.
    kf.read_camera_detections(tmp_path / "cam01_json", progress=False, cache=tmp_path / "cam01.npz")
    with monkeypatch.context() as patch:
        patch.setattr(kf, "_parse_chunk", None)
        check_matches(kf.read_camera_detections(tmp_path / "cam01_json", progress=False, cache=tmp_path / "cam01.npz"), written)
    # A bad file in a later chunk: the pool reports it as the sequential path does.
    (tmp_path / "cam01_json" / "cam01.0031.json").write_text('{"people": [{"pose_keypoints_2d": [1, 2]}]}')
    for workers in (1, 2):
        with pytest.raises(DataFormatError, match=r"cam01\.0031\.json: .*2 values, not a multiple of 3"):
            kf.read_openpose_folder(tmp_path / "cam01_json", progress=False, workers=workers)


def test_progress_bar(tmp_path, capsys):
    write_folder(tmp_path / "cam", [1, 1, 1])
    kf.read_openpose_folder(tmp_path / "cam", progress=True)  # tqdm shows nothing for a read under 0.5 s
    assert "Traceback" not in capsys.readouterr().err


def test_frames_without_people(tmp_path):
    folder = tmp_path / "cam"
    write_folder(folder, [0, 0, 0])
    detections = kf.read_openpose_folder(folder, progress=False)
    assert detections.frames.tolist() == [0, 1, 2] and detections.people.tolist() == [0, 0, 0]
    assert detections.keypoints.shape == (3, 0, 0, 2) and detections.values_per_person == 0


# ---------------------------------------------------------------------------------------------
# jaxpose.predict's input, a pose per row (`jaxpose.formats.detection_file`), reads through these readers


@needs_formats
def test_detection_file_reads_the_real_samples():
    from jaxpose.formats import detection_file
    from jaxpose.layouts import coco17_to_h36m17, to_skeleton
    from jaxpose.skeleton import H36M_17

    body25b = detection_file.read_detections(BODY25B / "cam01_json")
    assert body25b.kind == "openpose" and body25b.keypoints.shape == (40, 25, 2)
    assert body25b.image_ids[:3] == ["cam01.0000", "cam01.0000", "cam01.0001"]
    assert body25b.frame_ids == [f"cam01.{i:04d}" for i in range(20)]
    halpe = detection_file.read_detections(HALPE26 / "cam03")
    assert halpe.keypoints.shape == (20, 26, 2) and halpe.image_ids[0] == "frame_00001"
    full = kf.read_openpose_folder(HALPE26 / "cam03", progress=False)
    np.testing.assert_array_equal(halpe.keypoints, full.keypoints[:, 0])
    # An H36M_17 lifter takes HALPE_26 through its first 17 keypoints, which are COCO-17's.
    for converted, expected in zip(
        to_skeleton("halpe26", H36M_17, halpe.keypoints, halpe.scores),
        coco17_to_h36m17(halpe.keypoints[:, :17], halpe.scores[:, :17]),
    ):
        np.testing.assert_array_equal(converted, expected)
    spin = detection_file.read_detections(SPIN / "im1010_openpose.json")
    assert spin.image_ids == ["im1010_openpose"] and spin.keypoints.shape == (1, 25, 2) and spin.frame_ids == ["im1010_openpose"]
    alphapose = detection_file.read_detections(ALPHAPOSE)
    assert alphapose.kind == "coco" and alphapose.image_ids == ["out-002.jpg"] * 13 and alphapose.frame_ids is None
    np.testing.assert_array_equal(alphapose.scores, kf.read_coco_results(ALPHAPOSE).scores[0])
