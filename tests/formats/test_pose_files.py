"""Lifted poses out to a file (`jaxpose.formats.pose_files`): .json, .npz and .csv a row per pose with its frame,
time and person; .trc a file per person and continuous segment, gaps interpolated.  jaxpose.predict writing
them from an OpenPose folder: tests/inference/test_predict_outputs.py."""

from __future__ import annotations

import csv
import itertools
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxpose.formats import pose_files
from jaxpose.formats.trc import marker_name, read_trc
from jaxpose.skeleton import H36M_17


def _lifted(frames, persons, first_frame=0, fps=60.0, not_lifted=(), seed=1) -> pose_files.LiftedPoses:
    rng = np.random.default_rng(seed)
    poses = rng.normal(0, 300, (len(frames), 17, 3)).astype(np.float32)
    poses[:, 0] = 0.0  # root-relative
    poses[list(not_lifted)] = np.nan
    image_ids = [f"frame_{f:04d}" for f in frames]
    return pose_files.LiftedPoses(poses, H36M_17.joint_names, image_ids, np.asarray(frames, np.int64),
                                  np.asarray(persons, np.int64), first_frame, fps)  # fmt: skip


def test_one_person_trc_a_row_per_frame_on_the_input_time_axis(tmp_path):
    """Frames 7-11 of an input starting at frame 5, frame 10 not lifted: one file, the path given, Frame# the
    input's frames, Time = (frame - 5) / fps, frame 10 halfway between 9 and 11, no empty cell."""
    lifted = _lifted([7, 8, 9, 10, 11], [0] * 5, first_frame=5, not_lifted=[3])
    path = tmp_path / "poses.trc"
    written = pose_files.write_trc_files(path, lifted, max_gap=1)
    assert [p for p, _ in written] == [path] and written[0][1].filled == 1
    first = path.read_text().split("\n")[0].split("\t")
    assert first[:3] == ["PathFileType", "4", "(X/Y/Z)"] and len(first) == 4
    assert first[3].startswith("poses.trc ") and "X=-z Y=-y Z=-x" in first[3]
    data = read_trc(path)
    assert data.units == "m" and data.rate == 60.0 and data.frame_numbers.tolist() == [7, 8, 9, 10, 11]
    assert data.header["OrigDataStartFrame"] == "7" and data.header["NumFrames"] == "5"
    assert data.marker_names == tuple(marker_name(n) for n in H36M_17.joint_names) and "Neck_Nose" in data.marker_names
    np.testing.assert_allclose(data.times, (np.arange(7, 12) - 5) / 60.0, atol=1e-6)
    # Camera (x right, y down, z forward, mm) -> X = -z, Y = -y, Z = -x in metres: a rotation.
    axes = pose_files.TRC_AXES
    assert np.linalg.det(axes) == pytest.approx(1.0) and np.allclose(axes @ axes.T, np.eye(3))
    poses = lifted.poses.astype(np.float64)
    poses[3] = (poses[2] + poses[4]) / 2
    expected = np.stack([-poses[..., 2], -poses[..., 1], -poses[..., 0]], -1) / 1000.0
    np.testing.assert_allclose(data.markers, expected, atol=1e-6)
    assert np.isfinite(data.markers).all()
    head = H36M_17.index("Head")  # above the pelvis in the camera (smaller y) -> above in OpenSim (larger Y)
    assert ((poses[:, head, 1] < 0) == (data.markers[:, head, 1] > 0)).all()


def test_people_and_segments_get_their_own_files(tmp_path):
    # Person 0 in frames 0-3; person 1 in 0, 1 and, after a gap of 3 frames, 5; a pose followed by none.
    lifted = _lifted([0, 0, 1, 1, 2, 3, 5, 4], [0, 1, 1, 0, 0, 0, 1, -1], first_frame=0)
    written = pose_files.write_trc_files(tmp_path / "poses.trc", lifted, max_gap=2)
    assert [(p.name, s.person, s.index, s.frames.tolist()) for p, s in written] == [
        ("poses.person0.trc", 0, 0, [0, 1, 2, 3]), ("poses.person1.trc", 1, 0, [0, 1]), ("poses.person1.seg1.trc", 1, 1, [5]),
    ]  # fmt: skip
    assert read_trc(tmp_path / "poses.person1.seg1.trc").times.tolist() == [pytest.approx(5 / 60, abs=1e-6)]
    summary = pose_files.trc_summary(written, lifted, 2, earlier=[tmp_path / "poses.person7.trc"])
    assert summary.startswith("wrote 3 .trc files for 2 of 2 people followed, Time = (frame - 0) / 60 fps: 0 frames")
    assert "3 segments, 1 person split at longer gaps" in summary and "poses.person7.trc" in summary.splitlines()[-1]
    assert pose_files.trc_family(tmp_path / "poses.trc") == sorted(p for p, _ in written)
    with pytest.raises(ValueError, match="person 0 has two poses in frame 3"):
        pose_files.segments(_lifted([3, 3], [0, 0]))


@settings(max_examples=100, deadline=None)
@given(st.data())
def test_segments_fill_short_gaps_and_split_at_long_ones(data):
    """Every segment runs over consecutive frames, holds each lifted pose of its person exactly and lies
    linearly between them elsewhere; each person's lifted frames are covered once; segments of one person
    are more than max_gap frames apart."""
    count = data.draw(st.integers(1, 40))
    frames = np.array(data.draw(st.lists(st.integers(0, 60), min_size=count, max_size=count, unique=True)))
    persons = np.array(data.draw(st.lists(st.integers(-1, 2), min_size=count, max_size=count)))
    not_lifted = data.draw(st.lists(st.integers(0, count - 1), max_size=count // 2))
    max_gap = data.draw(st.integers(0, 12))
    lifted = _lifted(frames, persons, not_lifted=not_lifted)
    found = pose_files.segments(lifted, max_gap)
    for person in set(persons[persons >= 0].tolist()):
        own = [s for s in found if s.person == person]
        assert [s.index for s in own] == list(range(len(own)))
        rows = np.flatnonzero((persons == person) & lifted.valid)
        covered = np.concatenate([s.frames for s in own]) if own else np.zeros(0, int)
        known = set(frames[rows].tolist())
        assert known <= set(covered.tolist()) and len(covered) == len(set(covered.tolist()))
        for earlier, later in itertools.pairwise(own):
            assert later.frames[0] - earlier.frames[-1] - 1 > max_gap
        for segment in own:
            assert (np.diff(segment.frames) == 1).all() and np.isfinite(segment.poses).all()
            assert segment.frames[0] in known and segment.frames[-1] in known
            assert segment.filled == len(segment.frames) - len(known & set(segment.frames.tolist()))
            for frame, pose in zip(segment.frames, segment.poses):
                if frame in known:
                    np.testing.assert_array_equal(pose, lifted.poses[rows[frames[rows] == frame][0]])
                else:  # linear between the lifted frames around it, no more than max_gap apart
                    before = max(f for f in known if f < frame)
                    after = min(f for f in known if f > frame)
                    assert after - before - 1 <= max_gap
                    pose_before, pose_after = (lifted.poses[rows[frames[rows] == f][0]] for f in (before, after))
                    weight = (frame - before) / (after - before)
                    np.testing.assert_allclose(pose, (1 - weight) * pose_before + weight * pose_after, atol=1e-3)


def test_csv_npz_and_json_a_row_per_pose_with_frame_time_and_person(tmp_path):
    lifted = _lifted([7, 9, 9, 10, 12], [0, 0, 1, -1, 0], first_frame=3, fps=2.0, not_lifted=[3])
    for suffix in (".csv", ".npz", ".json"):
        pose_files.write_poses(tmp_path / f"poses{suffix}", lifted)
    with open(tmp_path / "poses.csv", newline="") as file:
        rows = list(csv.reader(file))
    assert rows[0][:6] == ["image_id", "frame", "time_s", "person", "Hip_x_mm", "Hip_y_mm"] and len(rows[0]) == 4 + 17 * 3
    assert rows[0][-1] == f"{H36M_17.joint_names[-1]}_z_mm" and len(rows) == 6
    assert [row[:4] for row in rows[1:3]] == [["frame_0007", "7", "2.0", "0"], ["frame_0009", "9", "3.0", "0"]]
    assert rows[4][4:] == [""] * 51 and rows[4][3] == "-1"  # not lifted, followed by none
    for row, pose, ok in zip(rows[1:], lifted.poses, lifted.valid):
        if ok:
            np.testing.assert_allclose([float(v) for v in row[4:]], pose.ravel(), atol=0.006)
    with np.load(tmp_path / "poses.npz") as data:
        assert data["frame"].tolist() == [7, 9, 9, 10, 12] and data["person"].tolist() == [0, 0, 1, -1, 0]
        np.testing.assert_allclose(data["time_s"], [2.0, 3.0, 3.0, 3.5, 4.5])
        np.testing.assert_array_equal(data["pose3d_mm"], lifted.poses)
        assert data["valid"].tolist() == [True, True, True, False, True]
    records = json.loads((tmp_path / "poses.json").read_text())
    assert [(r["frame"], r["time_s"], r["person"]) for r in records][:2] == [(7, 2.0, 0), (9, 3.0, 0)]
    assert records[3]["pose3d_mm"] is None and records[0]["joint_names"] == list(H36M_17.joint_names)
    with pytest.raises(ValueError, match="write_trc_files"):
        pose_files.write_poses(tmp_path / "poses.trc", lifted)
