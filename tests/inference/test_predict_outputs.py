"""What `python -m jaxpose.predict` writes: files replaced only with --overwrite, through temporary files; the
input's time axis (frame numbers, Time, one .trc per person and segment, no empty cell)."""

from __future__ import annotations

import contextlib
import io
import json
import logging
import os
import subprocess
import sys

import numpy as np
import pytest

from detection_helpers import body25_from_coco, coco_from_h36m, views
from jaxpose import predict
from jaxpose.formats import pose_files
from jaxpose.formats.trc import read_trc
from jaxpose.layouts import OPENPOSE_25_JOINT_NAMES
from jaxpose.skeleton import COCO_17
from keypoint_writers import write_frame
import paths

POSE2SIM_TRC = paths.FORMATS / "trc" / "pose2sim_demo_BalancingTrial_0-100.trc"
needs_pose2sim_trc = pytest.mark.skipif(not POSE2SIM_TRC.is_file(), reason=f"{POSE2SIM_TRC} (a real sample) is absent")


def _coco_results(trained_run, path, image_ids) -> None:
    keypoints = coco_from_h36m(views(trained_run[1])[0][: len(image_ids)])
    triplets = np.concatenate([keypoints, np.full((*keypoints.shape[:2], 1), 0.9)], -1).reshape(len(keypoints), -1)
    path.write_text(json.dumps([{"image_id": i, "keypoints": t.tolist()} for i, t in zip(image_ids, triplets)]))


def _cli(*args) -> np.ndarray:
    return predict.main([str(a) for a in args])


def test_a_second_run_replaces_every_output_only_with_overwrite(trained_run, tmp_path, capsys):
    _coco_results(trained_run, tmp_path / "results.json", [1, 2, 3])
    outputs = ["--output", tmp_path / "out" / "poses.npz", "--plot", tmp_path / "plots", "--animation", tmp_path / "clip.gif"]
    common = ["--checkpoint", trained_run[0], "--input", tmp_path / "results.json", "--image-size", 1000, 1000, *outputs]
    first = _cli(*common, "--plot-count", 2)
    logging.getLogger("jaxpose.serving.inference").info("a jaxpose log line")  # predict shows them (jaxpose.logs)
    assert capsys.readouterr().err.count("a jaxpose log line") == 1
    written = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file())
    assert [str(p) for p in written] == [
        "clip.gif", "out/poses.npz", "plots/lifting_00000.png", "plots/lifting_00001.png", "results.json",
    ]  # fmt: skip  (no temporary file left behind)
    contents = {p: (tmp_path / p).read_bytes() for p in written}
    with pytest.raises(SystemExit, match=r"poses\.npz: exists; pass --overwrite to replace it"):
        _cli(*common)
    assert {p: (tmp_path / p).read_bytes() for p in written} == contents
    second = _cli(*common, "--plot-count", 2, "--overwrite")
    np.testing.assert_array_equal(first, second)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*") if p.is_file()) == written
    with np.load(tmp_path / "out" / "poses.npz") as data:
        np.testing.assert_array_equal(data["pose3d_mm"], second)


@pytest.mark.processes
def test_the_command_line_caches_its_compiled_programs(trained_run, tmp_path):
    """`python -m jaxpose.predict` turns on the persistent compilation cache (`jaxpose.compilation_cache`)."""
    _coco_results(trained_run, tmp_path / "results.json", [1, 2])
    cache = tmp_path / "xla"
    command = [sys.executable, "-m", "jaxpose.predict", "--checkpoint", str(trained_run[0]), "--input",
               str(tmp_path / "results.json"), "--output", str(tmp_path / "poses.json"), "--image-size", "1000", "1000"]  # fmt: skip
    environment = os.environ | {"JAXPOSE_COMPILATION_CACHE": str(cache), "JAX_PLATFORMS": "cpu"}
    result = subprocess.run(command, capture_output=True, text=True, env=environment, timeout=300)
    assert result.returncode == 0, result.stderr
    assert any(cache.iterdir()) and (tmp_path / "poses.json").is_file()


# ---------------------------------------------------------------------------------------------
# The time axis: an OpenPose folder with empty frames and two people, out as .trc and .npz

FRAMES, FPS = 40, 25
EMPTY = {0, 10, 11, 12}  # nobody in these files
B_AWAY = set(range(20, 32))  # 12 frames: more than --max-gap 10, fewer than --track-gap 30
A_ROOTLESS = 15  # A's hips undetected: not liftable


def _two_people_folder(trained_run, folder):
    """A walks right from x = 300, B left from x = 700, listed in a random order (A first in frame 1, so A
    is person 0); BODY_25 from two test poses, each centred on its pelvis."""
    keypoints = coco_from_h36m(np.nan_to_num(views(trained_run[1])[0][:2]))
    hips = [COCO_17.index("left_hip"), COCO_17.index("right_hip")]
    shapes = body25_from_coco(keypoints - keypoints[:, hips].mean(1, keepdims=True), 0.9)
    rng = np.random.default_rng(0)
    folder.mkdir()
    for frame in range(FRAMES):
        people = []
        if frame not in EMPTY:
            a = shapes[0].copy()
            a[:, :2] += (300 + 4 * frame, 500)
            if frame == A_ROOTLESS:
                a[[OPENPOSE_25_JOINT_NAMES.index(n) for n in ("LHip", "RHip")]] = 0.0
            people.append(a)
            if frame not in B_AWAY:
                b = shapes[1].copy()
                b[:, :2] += (700 - 4 * frame, 520)
                people.append(b)
            if frame > 1 and rng.random() < 0.5:
                people.reverse()
        for person in people:
            person[person[:, 2] == 0] = 0.0  # undetected: 0, 0, 0 as OpenPose writes it
        write_frame(folder / f"clip_{frame:012d}_keypoints.json", people)
    return folder


@pytest.fixture(scope="module")
def two_people_trc(trained_run, tmp_path_factory):
    root = tmp_path_factory.mktemp("two_people")
    folder = _two_people_folder(trained_run, root / "openpose")
    common = ["--checkpoint", trained_run[0], "--input", folder, "--format", "body25", "--intrinsics", 1000, 1000, 500, 500,
              "--fps", FPS]  # fmt: skip
    _cli(*common, "--output", root / "poses.npz")
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr):
        _cli(*common, "--output", root / "poses.trc")
    return root, stderr.getvalue()


def test_openpose_folder_gives_a_trc_per_person_on_the_frame_numbers_without_empty_cells(two_people_trc):
    root, stderr = two_people_trc
    assert sorted(p.name for p in root.glob("poses*")) == [
        "poses.npz", "poses.person0.trc", "poses.person1.seg1.trc", "poses.person1.trc",
    ]  # fmt: skip
    with np.load(root / "poses.npz") as data:
        poses, frames, persons, times = data["pose3d_mm"], data["frame"], data["person"], data["time_s"]
    np.testing.assert_allclose(times, frames / FPS)  # the folder's first file, frame 0, is Time 0
    expected = {
        "poses.person0.trc": (range(1, FRAMES), 0),
        "poses.person1.trc": (range(1, min(B_AWAY)), 1),
        "poses.person1.seg1.trc": (range(max(B_AWAY) + 1, FRAMES), 1),
    }
    for name, (span, person) in expected.items():
        data = read_trc(root / name)
        assert data.frame_numbers.tolist() == list(span)
        np.testing.assert_allclose(data.times, np.array(span) / FPS, atol=1e-6)
        assert np.isfinite(data.markers).all() and data.rate == FPS
        rows = (root / name).read_text().splitlines()[5:]
        assert len(rows) == len(span) and all(field != "" for row in rows for field in row.split("\t"))
        lifted = (persons == person) & np.isfinite(poses).all((1, 2)) & np.isin(frames, span)
        rows_of = np.searchsorted(data.frame_numbers, frames[lifted])
        np.testing.assert_allclose(data.markers[rows_of], poses[lifted] @ pose_files.TRC_AXES.T / 1000.0, atol=1e-6)
    # Every pose followed: A's 36 (one of them not lifted) and B's 24, each person in one track.
    not_lifted = ~np.isfinite(poses).all((1, 2))
    assert frames[not_lifted].tolist() == [A_ROOTLESS] and persons[not_lifted].tolist() == [0]
    assert np.bincount(persons).tolist() == [FRAMES - len(EMPTY), FRAMES - len(EMPTY | B_AWAY)]
    filled = len(EMPTY - {0}) * 2 + 1  # frames 10-12 for both, and A's rootless frame
    assert f"wrote 3 .trc files for 2 of 2 people followed, Time = (frame - 0) / {FPS} fps: {filled} frames filled" in stderr
    assert "3 segments, 1 person split at longer gaps" in stderr


@needs_pose2sim_trc
def test_the_trc_has_the_header_and_layout_of_pose2sims(two_people_trc):
    """Line for line as Pose2Sim's own TRC (its demo's triangulation): header keys, rates and units, the marker
    row with two empty fields after each name, the X/Y/Z row, no blank line, a number in every field, Frame#
    up by 1 and Time by 1 / DataRate per row.  (Pose2Sim numbers Frame# from 1 with Time = Frame# / rate;
    jaxpose keeps the input's frame numbers, Time = (frame - first frame) / rate.)"""
    ours_path = two_people_trc[0] / "poses.person0.trc"
    for path in (POSE2SIM_TRC, ours_path):
        lines = path.read_text().splitlines()
        theirs = POSE2SIM_TRC.read_text().splitlines()
        assert lines[0].split("\t")[:3] == ["PathFileType", "4", "(X/Y/Z)"] and len(lines[0].split("\t")) == 4
        assert lines[1] == theirs[1]
        rate, camera_rate, frames, markers, units, original_rate, _, _ = lines[2].split("\t")
        assert rate == camera_rate == original_rate and units == "m" and int(frames) == len(lines) - 5
        names = lines[3].split("\t")
        assert names[:2] == ["Frame#", "Time"] and len(names) == 2 + 3 * int(markers)
        assert all(names[i + 1] == names[i + 2] == "" and names[i] for i in range(2, len(names), 3))
        assert lines[4].split("\t") == ["", ""] + [f"{axis}{m}" for m in range(1, int(markers) + 1) for axis in "XYZ"]
        table = np.array([[float(field) for field in line.split("\t")] for line in lines[5:]])
        assert table.shape[1] == 2 + 3 * int(markers)
        np.testing.assert_array_equal(np.diff(table[:, 0]), 1)
        np.testing.assert_allclose(np.diff(table[:, 1]), 1 / float(rate), atol=2e-6)
