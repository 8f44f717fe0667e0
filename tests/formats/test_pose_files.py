"""Lifted poses out to a file (`jaxpose.formats.pose_files`): the .trc and .csv outputs, and jaxpose.predict
writing them from a Pose2Sim-style folder."""

from __future__ import annotations

import csv
import json
from contextlib import nullcontext

import numpy as np
import pytest

from detection_helpers import body25_from_coco, coco_from_h36m, views
from jaxpose import predict
from jaxpose.formats import pose_files
from jaxpose.formats.trc import marker_name, read_trc
from jaxpose.skeleton import H36M_17


def _poses() -> tuple[np.ndarray, list]:
    rng = np.random.default_rng(1)
    poses = rng.normal(0, 300, (5, 17, 3)).astype(np.float32)
    poses[:, 0] = 0.0  # root-relative
    poses[3] = np.nan  # not lifted
    return poses, [7, "frame_0002", 9, 10, 11]


def test_trc_round_trip(tmp_path):
    poses, image_ids = _poses()
    path = tmp_path / "poses.trc"
    pose_files.write_poses(path, poses, image_ids, H36M_17.joint_names, fps=60.0)
    first = path.read_text().split("\n")[0].split("\t")
    assert first[:3] == ["PathFileType", "4", "(X/Y/Z)"] and len(first) == 4
    assert first[3].startswith("poses.trc ") and "X=-z Y=-y Z=-x" in first[3]
    data = read_trc(path)
    assert data.units == "m" and data.rate == 60.0 and data.frame_numbers.tolist() == [1, 2, 3, 4, 5]
    assert data.marker_names == tuple(marker_name(n) for n in H36M_17.joint_names) and "Neck_Nose" in data.marker_names
    np.testing.assert_allclose(data.times, np.arange(5) / 60.0, atol=1e-6)
    # Camera (x right, y down, z forward, mm) -> X = -z, Y = -y, Z = -x in metres: a rotation.
    axes = pose_files.TRC_AXES
    assert np.linalg.det(axes) == pytest.approx(1.0) and np.allclose(axes @ axes.T, np.eye(3))
    expected = np.stack([-poses[..., 2], -poses[..., 1], -poses[..., 0]], -1) / 1000.0
    np.testing.assert_allclose(data.markers, expected, atol=1e-6)
    assert np.isnan(data.markers[3]).all()
    # Head above the pelvis in the camera (smaller y) -> above in OpenSim (larger Y).
    head = H36M_17.index("Head")
    assert ((poses[:, head, 1] < 0) == (data.markers[:, head, 1] > 0))[np.isfinite(poses[:, head, 1])].all()


def test_trc_with_several_poses_per_image_warns(tmp_path):
    poses, _ = _poses()
    with pytest.warns(UserWarning, match="several poses share an image id"):
        pose_files.write_poses(tmp_path / "p.trc", poses, [1, 1, 2, 3, 4], H36M_17.joint_names, fps=30.0)
    assert len(read_trc(tmp_path / "p.trc").frame_numbers) == 5


def test_csv(tmp_path):
    poses, image_ids = _poses()
    path = tmp_path / "poses.csv"
    pose_files.write_poses(path, poses, image_ids, H36M_17.joint_names)
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
                          "--format", "body25", "--intrinsics", *intrinsics, "--fps", "60"])  # fmt: skip
    with np.load(outputs[".npz"]) as out:
        poses, image_ids = out["pose3d_mm"], out["image_id"].tolist()
    assert image_ids == ["cam01.0000", "cam01.0001", "cam01.0001", "cam01.0003"] and np.isfinite(poses).all()
    data = read_trc(outputs[".trc"])
    assert data.rate == 60.0 and data.markers.shape == (4, 17, 3)
    np.testing.assert_allclose(data.markers, poses @ pose_files.TRC_AXES.T / 1000.0, atol=1e-6)
    with open(outputs[".csv"], newline="") as file:
        rows = list(csv.reader(file))[1:]
    assert [row[0] for row in rows] == image_ids
    np.testing.assert_allclose(np.array([row[1:] for row in rows], float), poses.reshape(4, -1), atol=0.006)
