"""CMU motion capture as jaxpose's keypoints (`jaxpose.synthetic.mocap`) and the motion benchmark built on
it (benchmarks/motion.py): the mapping against the BVH's own joints, the detections against the ground
truth's projections, and the benchmark's table on one short take."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from benchmarks import motion
from jaxpose.synthetic import project_points
from jaxpose.formats.bvh import CMU_MM_PER_UNIT, read_bvh, world_joints
from jaxpose.skeleton import COCO_17, H36M_17
from jaxpose.synthetic.mocap import mocap_keypoints, rest_frames
import paths

CMU = paths.SHARED_DATA / "cmu_mocap"
needs_cmu = pytest.mark.skipif(not CMU.is_dir(), reason=f"{CMU} (the CMU motion capture files) is absent")
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@needs_cmu
def test_coco_joints_are_the_cmu_joints_rotated_to_z_up():
    bvh = read_bvh(CMU / "02" / "02_01.bvh")
    coco = mocap_keypoints(bvh, "coco17")
    joints = world_joints(bvh, CMU_MM_PER_UNIT)[rest_frames(bvh) :] @ Y_UP_TO_Z_UP.T
    pairs = {"left_knee": "LeftLeg", "right_wrist": "RightHand", "left_shoulder": "LeftArm", "right_ankle": "RightFoot"}
    for name, cmu in pairs.items():
        moved = coco[:, COCO_17.joint_names.index(name)] - joints[:, bvh.index(cmu)]
        np.testing.assert_allclose(moved, np.broadcast_to(moved[0], moved.shape), atol=1e-6)  # one shift for the take
    assert moved[0, 2] == pytest.approx(-joints[..., 2].min(), abs=1e-6)  # the floor at the lowest point (a toe)
    h36m = mocap_keypoints(bvh, "h36m17")
    assert h36m.shape == (len(coco), 17, 3)
    np.testing.assert_allclose(h36m[:, H36M_17.index("Neck/Nose")], coco[:, COCO_17.joint_names.index("nose")])


@needs_cmu
@pytest.mark.parametrize("take", ["02/02_01", "02/02_03", "05/05_01", "06/06_01"])
def test_the_rest_pose_frame_is_left_out_of_the_motion(take):
    """CMU's conversions put the skeleton's rest pose first: 160-500 mm from the motion's first frame, which
    moves its joints 1-21 mm a frame.  It is left out; a take that starts with motion keeps every frame."""
    bvh = read_bvh(CMU / f"{take}.bvh")
    assert rest_frames(bvh) == 1
    points = mocap_keypoints(bvh, "coco17")
    assert len(points) == bvh.frame_count - 1
    steps = np.linalg.norm(np.diff(points[:10], axis=0), axis=-1).mean(-1)  # mm per frame at 120 fps
    assert steps.max() < 40, steps
    moving = dataclasses.replace(bvh, motion=bvh.motion[1:])  # frame 1 first: its root is rotated
    assert rest_frames(moving) == 0
    np.testing.assert_allclose(mocap_keypoints(moving, "coco17")[1:], points[1:], atol=1e-6)


@needs_cmu
@pytest.mark.parametrize("take", ["02/02_01", "02/02_03"])
def test_face_points_are_rigid_on_the_head_face_forward_and_left_is_left(take):
    bvh = read_bvh(CMU / f"{take}.bvh")
    coco = mocap_keypoints(bvh, "coco17")
    head = world_joints(bvh, CMU_MM_PER_UNIT)[rest_frames(bvh) :, bvh.index("Head")] @ Y_UP_TO_Z_UP.T
    face = coco[:, :5] - coco[:, None, 0]
    shift = coco[:, 0] - head  # take's shift included: compare distances among the face points and the head
    distances = np.linalg.norm(coco[:, :5, None] - coco[:, None, :5], axis=-1)
    np.testing.assert_allclose(distances, np.broadcast_to(distances[0], distances.shape), atol=1e-6)
    assert np.ptp(np.linalg.norm(shift - shift.mean(0), axis=-1)) < 200  # the nose stays by the head
    # The walk and the jog go forward: the nose is ahead of the ears' midpoint along the travel direction,
    # and the left hip is on the left of it (z up).
    travel = coco[-1, 11, :2] - coco[0, 11, :2]
    travel = np.append(travel / np.linalg.norm(travel), 0.0)
    ears = 0.5 * (coco[:, 3] + coco[:, 4])
    assert np.median((coco[:, 0] - ears) @ travel) > 50
    left = np.cross([0.0, 0.0, 1.0], travel)
    assert np.median((coco[:, 11] - coco[:, 12]) @ left) > 100
    assert np.isfinite(face).all()


@needs_cmu
def test_detections_are_the_ground_truths_projections_with_the_detectors_noise():
    bvh = read_bvh(CMU / "02" / "02_03.bvh")
    points = mocap_keypoints(bvh, "coco17", frames=slice(0, 120, 4))
    inputs = motion.seen_by_rig("jog", points, cameras=4, fps=30.0, seed=0, key=0)
    assert inputs.keypoints.shape == (30, 4, 18, 2) and inputs.target3d.shape == (30, 18, 3)
    np.testing.assert_allclose(inputs.target3d[:, 1:], points, rtol=1e-6)  # the truth is the mapped mocap
    np.testing.assert_allclose(inputs.target3d[:, 0], points[:, 11:13].mean(1), rtol=1e-6)  # pelvis: the hips' midpoint
    projected = project_points(inputs.cameras, inputs.target3d)[0]
    detected = inputs.confidence > 0
    assert detected.mean() > 0.9
    error = np.linalg.norm(inputs.keypoints - projected, axis=-1)[detected]
    assert 2 < np.median(error) < 10  # the detector's 3-8 px per axis, outliers and swaps aside


@needs_cmu
@pytest.mark.slow
@pytest.mark.trains
def test_the_benchmark_on_one_short_take(tmp_path, rig_run):
    data = tmp_path / "cmu"
    (data / "02").mkdir(parents=True)
    (data / "02" / "02_03.bvh").symlink_to(CMU / "02" / "02_03.bvh")
    args = motion.MotionArgs(output=tmp_path / "out", checkpoint=rig_run.run_dir, data=data, rates=(30,), seeds=(0, 1),
                             max_frames=60, peers=())  # fmt: skip
    report = motion.run(args)
    assert report["takes"] == {"walk": (), "jog": ("02/02_03",), "rest of 02": (), "dance": (), "basketball": ()}
    cell = report["results"]["jog"]["30"]
    truth = cell.pop("ground truth")
    assert len(truth) == 2 and all(s["mpjpe_mm"] == 0 and s["accel_error_mm_per_frame2"] == 0 for s in truth)
    assert set(cell) == set(motion.METHOD_NAMES.values())
    assert all(len(seeds) == 2 and seeds[0]["mpjpe_mm"] > 0 for seeds in cell.values())
    table = (tmp_path / "out" / "report.md").read_text().splitlines()
    rows = [line for line in table if line.startswith("| jog |")]
    assert len(rows) == 2 and all(len(row.split("|")) == 10 and "±" in row for row in rows)
    assert json.loads((tmp_path / "out" / "report.json").read_text())["results"]["jog"]["30"]
    priors = [seed["02/02_03"] for seed in report["priors"]["jog"]["30"]]  # the default's estimate, per seed
    assert len(priors) == 2 and all(len(prior["motion_prior_mm_s2"]) == 18 and prior["accelerations"] == 18 * 15
                                    and min(prior["motion_prior_mm_s2"].values()) > 0 for prior in priors)  # fmt: skip
    assert any(line.startswith("| 30 | jog | ") and "(" in line for line in table)


def test_a_bad_take_stops_the_benchmark_with_one_line_naming_it(tmp_path):
    (tmp_path / "02").mkdir()
    (tmp_path / "02" / "02_03.bvh").write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    args = motion.MotionArgs(output=tmp_path / "out", checkpoint=tmp_path, data=tmp_path, peers=())
    with pytest.raises(SystemExit) as raised:
        motion.recordings(args, 30, 0)
    message = str(raised.value)
    assert "02_03.bvh" in message and "line 4" in message and "\n" not in message


@pytest.mark.parametrize("flags, fault", [(["--cameras", "9"], "--cameras 9"), (["--rates", "50"], "--rates 50"),
                                          (["--checkpoint", "no_such_run"], "no_such_run")])  # fmt: skip
def test_bad_flags_stop_the_benchmark_with_one_line(tmp_path, flags, fault):
    argv = ["--output", str(tmp_path / "out"), "--checkpoint", str(tmp_path / "run"), "--peers", *flags]
    with pytest.raises(SystemExit) as raised:
        motion.main(argv)
    assert fault in str(raised.value) and "\n" not in str(raised.value)
