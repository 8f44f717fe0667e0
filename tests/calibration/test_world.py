"""The upright metric world from the person (`jaxpose.calibration.world`).

The simulator's motions stand on a known floor (z = 0, world z up, the lower ankle 80 mm above it,
`jaxpose.synthetic.ANKLE_HEIGHT_MM`).  Each test puts a motion into a "recovered rig's" frame by a
random similarity (any orientation, a scale off by up to 10%, anywhere), adds triangulation-like
noise (15 mm per coordinate), gross errors and missing joints, and checks the world found from it
against the truth: up, the floor over the whole 4 m capture area, the scale.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from jaxpose.calibration.world import (
    ANKLE_HEIGHT_FRACTION, SHOULDER_HEIGHT_FRACTION, WorldFrame, cameras_to_world, points_to_world, world_frame,
)  # fmt: skip
from jaxpose.camera import Cameras, project
from jaxpose.layouts import lifting_skeleton
from jaxpose.skeleton import COCO_17, H36M_17, Skeleton
from jaxpose.synthetic import ANGLE_NAMES, SyntheticConfig, forward_kinematics, keypoints3d, sample_bone_lengths, sample_motion
from jaxpose.synthetic.body import JOINT_INDEX

CONFIG = SyntheticConfig()
NOISE_MM = 15.0
# The floor is checked over the capture area: a tilt shows up at its edges.
FLOOR_GRID = np.stack(np.meshgrid(np.linspace(-2000, 2000, 9), np.linspace(-2000, 2000, 9), [0.0]), -1).reshape(-1, 3)


def subject(seed: int, family: str, frames: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """(bone lengths, H36M_17 poses f64[T, 17, 3] world mm, z up, floor z = 0) of one simulated motion."""
    rng = np.random.default_rng(seed)
    bones = sample_bone_lengths(rng)
    return bones, sample_motion(rng, family, bones, frames, CONFIG).poses.astype(np.float64)


def into_rig(seed: int, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple[float, np.ndarray, np.ndarray]]:
    """The poses as a recovered rig sees them: X_rig = s Q X + u, noisy, 2% gross errors, 5% missing (NaN);
    returns (points, valid, (s, Q, u))."""
    rng = np.random.default_rng(seed + 7)
    Q = Rotation.random(random_state=seed).as_matrix()
    s, u = rng.uniform(0.9, 1.1), rng.normal(0.0, 3000.0, 3)
    noisy = poses + rng.normal(0.0, NOISE_MM, poses.shape)
    gross = rng.random(poses.shape[:2]) < 0.02
    noisy[gross] += rng.normal(0.0, 300.0, (gross.sum(), 3))
    valid = rng.random(poses.shape[:2]) > 0.05
    points = s * noisy @ Q.T + u
    points[~valid] = np.nan  # what a triangulation leaves where it has too few views
    return points, valid, (s, Q, u)


def h36m_height(bones: np.ndarray) -> float:
    """The height the module's table gives a simulated body: its rest pose's shoulders stand
    (0.818 - 0.039) of it above its ankles."""
    rest = forward_kinematics(np.zeros((1, len(ANGLE_NAMES))), np.zeros(1), bones)[0]
    above = rest[[JOINT_INDEX["LShoulder"], JOINT_INDEX["RShoulder"]], 2].mean() - rest[[JOINT_INDEX["LFoot"], JOINT_INDEX["RFoot"]], 2].mean()
    return above / (SHOULDER_HEIGHT_FRACTION - ANKLE_HEIGHT_FRACTION)


def errors(frame: WorldFrame, truth: tuple[float, np.ndarray, np.ndarray]) -> tuple[float, float, float]:
    """(up error degrees, largest |height| of the true floor in the found world mm, scale error)."""
    s, Q, u = truth
    up = np.degrees(np.arccos(np.clip(frame.R[1] @ Q[:, 2], -1.0, 1.0)))
    floor = points_to_world(frame, s * FLOOR_GRID @ Q.T + u)[:, 1]
    return float(up), float(np.abs(floor).max()), frame.scale * s - 1.0


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), family=st.sampled_from(["walking", "turning"]))
def test_a_walking_subject_gives_up_floor_and_scale_in_any_rig_orientation(seed, family):
    bones, poses = subject(seed, family)
    points, valid, truth = into_rig(seed, poses)
    frame = world_frame(points, valid, H36M_17, height_mm=h36m_height(bones))
    up, floor, scale = errors(frame, truth)
    assert frame.up_source == "floor" and frame.scale_source == "height"
    assert up < 2.0
    assert floor < 30.0  # the default ankle height (0.039 of the height: ~68 mm) against the simulator's 80 mm
    assert abs(scale) < 0.02
    # The subject's own limb lengths instead of the height: the same 2%.
    limbs = tuple(bones[JOINT_INDEX[name]] for name in ("LElbow", "LWrist", "LKnee", "LFoot"))
    by_limbs = world_frame(points, valid, H36M_17, limb_lengths_mm=limbs)
    assert by_limbs.scale_source == "limbs" and abs(errors(by_limbs, truth)[2]) < 0.02
    # The world's axes: a rotation, Y up, the origin on the floor below the subject's start.
    np.testing.assert_allclose(frame.R @ frame.R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(frame.R) == pytest.approx(1.0)
    hips = [JOINT_INDEX["LHip"], JOINT_INDEX["RHip"]]
    first = np.flatnonzero(valid[:, hips].all(1))[:50]  # the first 50 frames that see both hips
    s, Q, u = truth
    start = points_to_world(frame, s * poses[first][:, hips].mean((0, 1)) @ Q.T + u)  # their true mean position
    assert np.linalg.norm(start[[0, 2]]) < 30.0


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), scale=st.floats(0.8, 1.25))
def test_the_world_does_not_depend_on_the_rigs_frame(seed, scale):
    """The same recording given in two rig frames (any similarity apart) lands on the same world points."""
    bones, poses = subject(seed, "walking", 300)
    points, valid, _ = into_rig(seed, poses)
    Q = Rotation.random(random_state=seed + 1).as_matrix()
    moved = scale * points @ Q.T + np.array([1e3, -2e3, 5e2])
    height = h36m_height(bones)
    a = points_to_world(world_frame(points, valid, H36M_17, height_mm=height), points)
    b = points_to_world(world_frame(moved, valid, H36M_17, height_mm=height), moved)
    np.testing.assert_allclose(a, b, atol=1e-6 * np.nanmax(np.abs(a)))  # NaN where missing, in both


@pytest.mark.parametrize("family", ["reaching", "sitting", "waving"])
def test_a_subject_who_stays_on_one_spot_gives_up_from_the_body(family):
    """Without the floor covered, up is the body axis: as good as the posture is upright (the simulated
    stance leans the trunk forward by up to ~15 degrees: 3-7 degrees off here)."""
    bones, poses = subject(12, family)
    points, valid, truth = into_rig(12, poses)
    frame = world_frame(points, valid, H36M_17, height_mm=h36m_height(bones))
    up, _, scale = errors(frame, truth)
    assert frame.up_source == "body" and frame.body_axis_deg == 0.0
    assert up < 8.0
    assert abs(scale) < 0.02  # the height along the body axis is as good


def test_a_detectors_skeleton():
    """COCO keypoints (the example project's), with the pelvis derived from the hips as the lifting skeleton has it."""
    skeleton = lifting_skeleton("coco17")
    bones, poses = subject(5, "turning")

    def coco(h36m: np.ndarray) -> np.ndarray:
        keypoints = keypoints3d(h36m, bones, "coco17")
        hips = [COCO_17.joint_names.index("left_hip"), COCO_17.joint_names.index("right_hip")]
        return np.concatenate([keypoints[:, hips].mean(1, keepdims=True), keypoints], axis=1)  # pelvis first

    points, valid, truth = into_rig(5, coco(poses))
    frame = world_frame(points, valid, skeleton, height_mm=h36m_height(bones))
    up, floor, scale = errors(frame, truth)
    assert up < 2.0 and floor < 30.0 and abs(scale) < 0.02


def test_cameras_and_points_move_together():
    """Projection is unchanged: rig points through the rig's cameras = world points through `cameras_to_world`."""
    bones, poses = subject(3, "walking", 200)
    points, valid, _ = into_rig(3, poses)
    frame = world_frame(points, valid, H36M_17, height_mm=1700.0)
    rng = np.random.default_rng(0)
    R = Rotation.random(3, random_state=1).as_matrix()
    centres = points[:, 0].mean(0) - 5000.0 * R[:, 2]  # each camera 5 m back along its optical axis
    cameras = Cameras(K=np.tile(np.diag([1000.0, 1000.0, 1.0]), (3, 1, 1)) + np.array([[0, 0, 500], [0, 0, 500], [0, 0, 0]]),
                      R=R, t=-np.einsum("cij,cj->ci", R, centres), dist=rng.normal(0.0, 0.01, (3, 5)))  # fmt: skip
    before = np.asarray(project(cameras, points[:20].reshape(1, -1, 3)))
    after = np.asarray(project(cameras_to_world(frame, cameras), points_to_world(frame, points[:20]).reshape(1, -1, 3)))
    np.testing.assert_allclose(after, before, atol=1e-2)


def test_refusals_name_what_is_missing():
    points = np.zeros((50, 17, 3))
    with pytest.raises(ValueError, match=r"points must be \[T, 17, 3\]"):
        world_frame(points[:, :5], np.ones((50, 5), bool), H36M_17)
    no_feet = Skeleton("armless", ("Hip", "LHip", "RHip"), (-1, 0, 0), ((1, 2),))
    with pytest.raises(ValueError, match=r"no left and right \['ankle', 'shoulder'\]"):
        world_frame(np.zeros((50, 3, 3)), np.ones((50, 3), bool), no_feet)
    _, poses = subject(1, "walking", 100)
    with pytest.raises(ValueError, match="only 0 frames see both ankles and shoulders"):
        world_frame(poses, np.zeros(poses.shape[:2], bool), H36M_17)
    with pytest.raises(ValueError, match="height must be positive"):
        world_frame(poses, np.ones(poses.shape[:2], bool), H36M_17, height_mm=-1.0)
