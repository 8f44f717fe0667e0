"""OpenSim marker files (`jaxpose.formats.trc`) and predict's .trc / .csv outputs."""

from __future__ import annotations

import csv
import json
from contextlib import nullcontext
from pathlib import Path

import numpy as np
import pytest

from detection_helpers import body25_from_coco, coco_from_h36m, views
from jaxpose import predict
from jaxpose.formats.errors import DataFormatError
from jaxpose.formats.trc import HEADER_KEYS, marker_name, read_trc, write_trc
from jaxpose.skeleton import H36M_17

TRC = Path(__file__).resolve().parents[2] / "shared" / "data" / "formats" / "trc"
needs_formats = pytest.mark.skipif(not TRC.is_dir(), reason=f"{TRC} (the real TRC samples) is absent")


def _data_rows(path: Path) -> list[list[str]]:
    """The data rows as tab-split text, the header and blank lines left out."""
    return [line.split("\t") for line in path.read_text().splitlines()[5:] if line.strip()]


# ---------------------------------------------------------------------------------------------
# The real samples, read as they are


@needs_formats
@pytest.mark.parametrize(
    "name, markers, rows, header_frames, rate, first_frame, first_time, names",
    [
        ("pose2sim_demo_BalancingTrial_0-100.trc", 21, 100, "100", 60.0, 1, 1 / 60, ("RHip", "RKnee", "LWrist")),
        ("opencap_walk_first50.trc", 63, 50, "222", 60.0, 1, 0.0, ("Neck", "RShoulder", None)),
        ("freemocap_dao_yin_interpolated_first50.trc", 19, 50, "388", 25.0, 0, 0.0, ("nose", "left_eye", None)),
    ],
)
def test_real_trc_files(name, markers, rows, header_frames, rate, first_frame, first_time, names):
    path = TRC / name
    data = read_trc(path)
    assert data.units == "m" and data.rate == rate and float(data.header["CameraRate"]) == rate
    assert list(data.header) == list(HEADER_KEYS) and data.header["NumMarkers"] == str(markers)
    assert data.header["NumFrames"] == header_frames  # not always the number of rows
    assert len(data.marker_names) == markers and data.markers.shape == (rows, markers, 3)
    assert data.marker_names[:2] == names[:2] and (names[2] is None or data.marker_names[-1] == names[2])
    assert data.frame_numbers.tolist() == list(range(first_frame, first_frame + rows))
    np.testing.assert_allclose(data.times[0], first_time, atol=1e-7)
    np.testing.assert_allclose(np.diff(data.times), 1 / rate, atol=1e-6)
    assert data.path_line.startswith("PathFileType") and np.isfinite(data.markers).all()
    assert np.abs(data.markers).max() < 10.0  # metres, a person in a room
    text = _data_rows(path)
    assert len(text) == rows
    np.testing.assert_array_equal(data.markers[0].ravel(), [float(v) for v in text[0][2 : 2 + 3 * markers]])
    np.testing.assert_array_equal(data.markers[-1, -1], [float(v) for v in text[-1][-3:]])


@needs_formats
def test_real_quirks_are_there():
    """The variations read_trc takes, as the samples have them."""
    opencap = (TRC / "opencap_walk_first50.trc").read_text().splitlines()
    assert opencap[0].startswith("PathFileType  4\t") and opencap[5] == ""  # two spaces; blank line
    pose2sim = (TRC / "pose2sim_demo_BalancingTrial_0-100.trc").read_text().splitlines()
    assert pose2sim[3].endswith("\t\t") and pose2sim[5].startswith("1\t")  # trailing tabs; no blank line
    freemocap = (TRC / "freemocap_dao_yin_interpolated_first50.trc").read_text().splitlines()
    assert freemocap[5] == "" and freemocap[6].startswith("0\t")  # Frame# from 0


# ---------------------------------------------------------------------------------------------
# Writing, and refusals


def test_write_read_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    markers = rng.normal(0, 0.5, (6, 4, 3))
    markers[2] = np.nan  # a missing frame
    markers[4, 1, 2] = np.nan  # a missing value
    path = write_trc(tmp_path / "out" / "walk.trc", markers, ["Hip", "Neck/Nose", "R Knee", "LWrist"], 120.0)
    lines = path.read_text().split("\n")
    assert lines[0] == "PathFileType\t4\t(X/Y/Z)\twalk.trc"
    assert lines[1] == "DataRate\tCameraRate\tNumFrames\tNumMarkers\tUnits\tOrigDataRate\tOrigDataStartFrame\tOrigNumFrames"
    assert lines[2] == "120\t120\t6\t4\tm\t120\t1\t6"
    assert lines[3] == "Frame#\tTime\tHip\t\t\tNeck_Nose\t\t\tR_Knee\t\t\tLWrist\t\t"
    assert lines[4] == "\t\tX1\tY1\tZ1\tX2\tY2\tZ2\tX3\tY3\tZ3\tX4\tY4\tZ4"
    assert lines[7] == "3\t0.016667" + "\t" * 12 and all(len(line.split("\t")) == 14 for line in lines[3:-1])
    data = read_trc(path)
    np.testing.assert_allclose(data.markers, markers, atol=5e-7)
    assert np.isnan(data.markers[2]).all() and np.isnan(data.markers[4, 1, 2])
    assert data.frame_numbers.tolist() == [1, 2, 3, 4, 5, 6] and data.units == "m" and data.rate == 120.0
    np.testing.assert_allclose(data.times, np.arange(6) / 120.0, atol=1e-6)
    assert data.marker_names == ("Hip", "Neck_Nose", "R_Knee", "LWrist")
    mm = read_trc(write_trc(tmp_path / "mm.trc", markers * 1000, ["a", "b", "c", "d"], 30, units="mm", first_frame=0))
    np.testing.assert_allclose(mm.markers, markers * 1000, atol=5e-4)
    assert mm.frame_numbers[0] == 0 and mm.units == "mm"


def test_marker_names():
    assert marker_name("Neck/Nose") == "Neck_Nose" and marker_name("r.ASIS_study") == "r.ASIS_study"


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda lines: ["Hello"] + lines[1:], "line 1 starting with PathFileType"),
        (lambda lines: lines[:2] + ["60\t60\t2\t3\tm"] + lines[3:], r"3 marker names on line 4 \(NumMarkers\)"),
        (lambda lines: lines[:2] + ["sixty\t60\t2\t2\tm\t60\t1\t2"] + lines[3:], "numbers for DataRate"),
        (lambda lines: lines[:3] + ["Time\t" + lines[3]] + lines[4:], "line 4 starting with Frame#, Time"),
        (lambda lines: lines[:5] + [lines[5].replace("0.5", "abc", 1)] + lines[6:], r"numbers or empty .*line 6"),
        (lambda lines: lines[:5] + [lines[5] + "\t9"] + lines[6:], r"8 fields per data row .*9 on line 6"),
        (lambda lines: lines[:3], "5 header lines"),
    ],
)
def test_trc_refusals(tmp_path, change, message):
    markers = np.full((2, 2, 3), 0.5)
    lines = write_trc(tmp_path / "a.trc", markers, ["a", "b"], 60).read_text().splitlines()
    (tmp_path / "b.trc").write_text("\n".join(change(lines)) + "\n")
    with pytest.raises(DataFormatError, match=message):
        read_trc(tmp_path / "b.trc")


def test_short_rows_are_padded_with_missing_values(tmp_path):
    lines = write_trc(tmp_path / "a.trc", np.ones((2, 2, 3)), ["a", "b"], 60).read_text().splitlines()
    lines[5] = "\t".join(lines[5].split("\t")[:5])  # a writer that drops trailing empty fields
    (tmp_path / "a.trc").write_text("\r\n".join(lines) + "\r\n")  # and writes CRLF
    data = read_trc(tmp_path / "a.trc")
    assert data.markers[0, 0].tolist() == [1, 1, 1] and np.isnan(data.markers[0, 1]).all()


# ---------------------------------------------------------------------------------------------
# predict's .trc and .csv outputs


def _poses() -> tuple[np.ndarray, list]:
    rng = np.random.default_rng(1)
    poses = rng.normal(0, 300, (5, 17, 3)).astype(np.float32)
    poses[:, 0] = 0.0  # root-relative
    poses[3] = np.nan  # not lifted
    return poses, [7, "frame_0002", 9, 10, 11]


def test_predict_trc_round_trip(tmp_path):
    poses, image_ids = _poses()
    path = tmp_path / "poses.trc"
    predict.write_poses(path, poses, image_ids, H36M_17.joint_names, fps=60.0)
    first = path.read_text().split("\n")[0].split("\t")
    assert first[:3] == ["PathFileType", "4", "(X/Y/Z)"] and len(first) == 4
    assert first[3].startswith("poses.trc ") and "X=-z Y=-y Z=-x" in first[3]
    data = read_trc(path)
    assert data.units == "m" and data.rate == 60.0 and data.frame_numbers.tolist() == [1, 2, 3, 4, 5]
    assert data.marker_names == tuple(marker_name(n) for n in H36M_17.joint_names) and "Neck_Nose" in data.marker_names
    np.testing.assert_allclose(data.times, np.arange(5) / 60.0, atol=1e-6)
    # Camera (x right, y down, z forward, mm) -> X = -z, Y = -y, Z = -x in metres: a rotation.
    axes = predict.TRC_AXES
    assert np.linalg.det(axes) == pytest.approx(1.0) and np.allclose(axes @ axes.T, np.eye(3))
    expected = np.stack([-poses[..., 2], -poses[..., 1], -poses[..., 0]], -1) / 1000.0
    np.testing.assert_allclose(data.markers, expected, atol=1e-6)
    assert np.isnan(data.markers[3]).all()
    # Head above the pelvis in the camera (smaller y) -> above in OpenSim (larger Y).
    head = H36M_17.index("Head")
    assert ((poses[:, head, 1] < 0) == (data.markers[:, head, 1] > 0))[np.isfinite(poses[:, head, 1])].all()


def test_predict_trc_with_several_poses_per_image_warns(tmp_path):
    poses, _ = _poses()
    with pytest.warns(UserWarning, match="several poses share an image id"):
        predict.write_poses(tmp_path / "p.trc", poses, [1, 1, 2, 3, 4], H36M_17.joint_names, fps=30.0)
    assert len(read_trc(tmp_path / "p.trc").frame_numbers) == 5


def test_predict_csv(tmp_path):
    poses, image_ids = _poses()
    path = tmp_path / "poses.csv"
    predict.write_poses(path, poses, image_ids, H36M_17.joint_names)
    with open(path, newline="") as file:
        rows = list(csv.reader(file))
    assert rows[0][:4] == ["image_id", "Hip_x_mm", "Hip_y_mm", "Hip_z_mm"] and len(rows[0]) == 1 + 17 * 3
    assert rows[0][-1] == f"{H36M_17.joint_names[-1]}_z_mm" and len(rows) == 6
    assert [row[0] for row in rows[1:]] == [str(i) for i in image_ids]
    assert rows[4][1:] == [""] * 51  # not lifted
    for row, pose in zip(rows[1:], poses):
        if np.isfinite(pose).all():
            np.testing.assert_allclose([float(v) for v in row[1:]], pose.ravel(), atol=0.006)


def test_cli_pose2sim_folder_to_trc_and_csv(trained_run, tmp_path):
    """A Pose2Sim-style folder (cam01.0000.json, compact) through the CLI: the .trc and .csv hold the .npz's poses."""
    keypoints, _, K = views(trained_run[1])
    # (body25_from_coco fills the neck right for 3 poses at a time only)
    body25 = np.concatenate([body25_from_coco(coco_from_h36m(keypoints[i : i + 3]), 0.8) for i in (0, 3)])
    folder = tmp_path / "cam01_json"
    folder.mkdir()
    for frame, people in enumerate([[0], [1, 2], [], [3]]):
        document = {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": body25[p].ravel().tolist(),
                                                "face_keypoints_2d": []} for p in people]}  # fmt: skip
        (folder / f"cam01.{frame:04d}.json").write_text(json.dumps(document, separators=(",", ":")))
    intrinsics = [str(v) for v in K[0, [0, 1, 0, 1], [0, 1, 2, 2]]]
    outputs = {}
    for suffix in (".npz", ".trc", ".csv"):
        outputs[suffix] = tmp_path / f"poses{suffix}"
        two_people = pytest.warns(UserWarning, match="share an image id") if suffix == ".trc" else nullcontext()
        with two_people:  # frame 1 holds two people
            predict.main(["--checkpoint", str(trained_run[0]), "--input", str(folder), "--output", str(outputs[suffix]),
                          "--intrinsics", *intrinsics, "--fps", "60"])  # fmt: skip
    with np.load(outputs[".npz"]) as out:
        poses, image_ids = out["pose3d_mm"], out["image_id"].tolist()
    assert image_ids == ["cam01.0000", "cam01.0001", "cam01.0001", "cam01.0003"] and np.isfinite(poses).all()
    data = read_trc(outputs[".trc"])
    assert data.rate == 60.0 and data.markers.shape == (4, 17, 3)
    np.testing.assert_allclose(data.markers, poses @ predict.TRC_AXES.T / 1000.0, atol=1e-6)
    with open(outputs[".csv"], newline="") as file:
        rows = list(csv.reader(file))[1:]
    assert [row[0] for row in rows] == image_ids
    np.testing.assert_allclose(np.array([row[1:] for row in rows], float), poses.reshape(4, -1), atol=0.006)
