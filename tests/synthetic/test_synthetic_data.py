"""The procedural multi-view data set: body, motion, cameras, detector, and the assembled data set."""

from __future__ import annotations

import dataclasses
import time

import jax
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import spearmanr

from jaxpose.camera import Cameras, project
from jaxpose.data.batch import MultiViewBatch, validate_batch, validate_cameras
from jaxpose.synthetic import (
    ANGLE_NAMES,
    ANKLE_HEIGHT_MM,
    DETECTOR_SIGMA_PX,
    JOINT_LIMITS_DEG,
    MOTION_FAMILIES,
    NOMINAL_BONE_MM,
    SyntheticConfig,
    angle_limits,
    detector_sigma,
    forward_kinematics,
    generate,
    make_rig,
    project_points,
    sample_bone_lengths,
    sample_motion,
    simulate_detector,
    simulate_subject,
)
from jaxpose.skeleton import H36M_17

# Small but complete: 3 subjects x 12 sequences (every family at least once per subject).
CONFIG = SyntheticConfig(num_train_subjects=2, num_test_subjects=1, samples_per_subject=1200, sequence_length=100)
J = H36M_17.num_joints


@pytest.fixture(scope="module")
def dataset():
    return generate(CONFIG)


@pytest.fixture(scope="module")
def subjects():
    return [simulate_subject(CONFIG, s) for s in range(CONFIG.num_subjects)]


def rig_of(dataset, subject: int) -> Cameras:
    return Cameras(K=dataset.rigs.K[subject], R=dataset.rigs.R[subject], t=dataset.rigs.t[subject])


def bone_lengths_of(poses: np.ndarray) -> np.ndarray:
    """[N, J] length of the bone ending at each joint (column 0, the root, is 0)."""
    parents = np.array(H36M_17.parents)
    lengths = np.linalg.norm(poses - poses[:, np.maximum(parents, 0)], axis=-1)
    return np.where(parents >= 0, lengths, 0.0)


# ---------------------------------------------------------------------------------------------- data set


def test_deterministic_for_a_seed(dataset):
    again = generate(CONFIG)
    jax.tree.map(np.testing.assert_array_equal, dataset.samples, again.samples)  # every per-sample array, labels too
    for field in ("K", "R", "t"):
        np.testing.assert_array_equal(getattr(dataset.rigs, field), getattr(again.rigs, field))
    other = generate(dataclasses.replace(CONFIG, seed=1))
    assert not np.allclose(other.samples.target3d, dataset.samples.target3d)


def test_shapes_dtypes_and_labels(dataset):
    N = CONFIG.num_subjects * CONFIG.samples_per_subject
    C = CONFIG.num_views
    assert dataset.skeleton == H36M_17
    assert dataset.samples.keypoints2d.shape == (N, C, J, 2) and dataset.samples.keypoints2d.dtype == np.float32
    assert dataset.samples.confidence.shape == (N, C, J) and dataset.samples.confidence.dtype == np.float32
    assert dataset.samples.target3d.shape == (N, J, 3) and dataset.samples.target3d.dtype == np.float32
    assert dataset.rigs.K.shape == (CONFIG.num_subjects, C, 3, 3) and dataset.rigs.dist is None
    assert all(np.isfinite(a).all() for a in (dataset.samples.keypoints2d, dataset.samples.confidence, dataset.samples.target3d))
    labels = dataset.samples.labels
    assert set(labels) >= {"subject", "split", "motion", "sequence", "frame"}
    train = set(labels["subject"][labels["split"] == "train"])
    test = set(labels["subject"][labels["split"] == "test"])
    assert train == {"S1", "S2"} and test == {"S3"} and not train & test
    assert set(labels["split"]) == {"train", "test"}
    for subject in train | test:
        rows = labels["subject"] == subject
        assert set(labels["motion"][rows]) == set(MOTION_FAMILIES)
        assert len(np.unique(dataset.samples.rig_index[rows])) == 1
    # Sequence ids are unique over the data set; frames count up within each sequence.
    for sequence in np.unique(labels["sequence"]):
        rows = np.flatnonzero(labels["sequence"] == sequence)
        assert len(set(labels["subject"][rows])) == 1 and len(set(labels["motion"][rows])) == 1
        np.testing.assert_array_equal(labels["frame"][rows], np.arange(len(rows)))


def test_target_matches_subject_simulation(dataset, subjects):
    for s, motion in enumerate(subjects):
        np.testing.assert_array_equal(dataset.samples.target3d[dataset.samples.rig_index == s], motion.poses)


def test_passes_the_batch_validation(dataset):
    rows = np.arange(0, len(dataset), 7)
    batch = MultiViewBatch(
        keypoints2d=dataset.samples.keypoints2d[rows],
        confidence=dataset.samples.confidence[rows],
        cameras=dataset.cameras_for(rows),
        pseudo3d=dataset.samples.target3d[rows],
        target3d=dataset.samples.target3d[rows],
    )
    validate_batch(batch)


# ---------------------------------------------------------------------------------------------- body


def test_bone_lengths_symmetric_constant_and_adult(subjects):
    nominal = np.array([0.0] + [NOMINAL_BONE_MM[name] for name in H36M_17.joint_names[1:]])
    per_subject = []
    for motion in subjects:
        lengths = bone_lengths_of(motion.poses.astype(np.float64))
        # Constant over time (float32 storage of coordinates ~2 m is the only error).
        np.testing.assert_allclose(lengths, np.broadcast_to(motion.bone_lengths, lengths.shape), atol=0.01)
        for left, right in H36M_17.left_right_pairs:
            np.testing.assert_allclose(lengths[:, left], lengths[:, right], atol=0.01)
        ratio = motion.bone_lengths[1:] / nominal[1:]
        assert np.all(np.abs(ratio - 1.0) <= 0.15), ratio
        per_subject.append(motion.bone_lengths)
    assert np.ptp(np.array(per_subject)[:, 1:], axis=0).max() > 5.0  # subjects differ


def test_bone_length_sampling_spread():
    nominal = np.array([NOMINAL_BONE_MM[name] for name in H36M_17.joint_names[1:]])
    ratios = np.array([sample_bone_lengths(np.random.default_rng(i))[1:] / nominal for i in range(300)])
    assert ratios.min() >= 0.85 and ratios.max() <= 1.15
    heights = ratios.mean(1)
    assert heights.std() > 0.03  # body size does vary by several percent


def test_joint_angles_within_limits_and_drive_the_poses(subjects):
    limits = angle_limits()
    assert set(JOINT_LIMITS_DEG) == {name[2:] if name[:2] in ("l_", "r_") else name for name in ANGLE_NAMES}
    assert JOINT_LIMITS_DEG["knee_flex"][0] == 0.0 and JOINT_LIMITS_DEG["elbow_flex"][0] == 0.0
    for motion in subjects:
        assert motion.angles.shape == (CONFIG.samples_per_subject, len(ANGLE_NAMES))
        assert np.all(motion.angles >= limits[:, 0]) and np.all(motion.angles <= limits[:, 1])
        # The angles are those that produced the poses: forward kinematics reproduces them.
        relative = forward_kinematics(motion.angles, motion.heading, motion.bone_lengths)
        root_relative = motion.poses - motion.poses[:, :1]
        np.testing.assert_allclose(relative, root_relative, atol=0.05)


def test_knees_and_elbows_bend_within_limits_geometrically(subjects):
    def angle_between(a, b):
        cos = np.sum(a * b, -1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))

    index = H36M_17.index
    for motion in subjects:
        p = motion.poses.astype(np.float64)
        for upper, middle, lower in (("LHip", "LKnee", "LFoot"), ("LShoulder", "LElbow", "LWrist")):
            for side in ("L", "R"):
                u, m, l = (index(side + name[1:]) for name in (upper, middle, lower))
                bend = angle_between(p[:, m] - p[:, u], p[:, l] - p[:, m])
                assert bend.max() <= 150.0 + 1e-3


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_forward_kinematics_mirror_symmetry(seed):
    """Equal left and right angles with a straight trunk give a pose mirror-symmetric in the body's y."""
    rng = np.random.default_rng(seed)
    limits = angle_limits()
    angles = rng.uniform(limits[:, 0], limits[:, 1], (1, len(ANGLE_NAMES)))
    for name in ANGLE_NAMES:
        if name.startswith("r_"):
            angles[0, ANGLE_NAMES.index(name)] = angles[0, ANGLE_NAMES.index("l_" + name[2:])]
        elif any(name.endswith(axis) for axis in ("_roll", "_bend", "_twist")):
            angles[0, ANGLE_NAMES.index(name)] = 0.0
    bones = sample_bone_lengths(rng)
    pose = forward_kinematics(angles, np.zeros(1), bones)[0]
    mirrored = pose[H36M_17.flip_permutation()] * np.array([1.0, -1.0, 1.0])
    np.testing.assert_allclose(mirrored, pose, atol=1e-6)
    np.testing.assert_allclose(bone_lengths_of(pose[None])[0], bones, atol=1e-6)


# ---------------------------------------------------------------------------------------------- motion


def test_feet_on_the_floor_and_body_in_the_capture_area(subjects):
    feet = [H36M_17.index("LFoot"), H36M_17.index("RFoot")]
    half = CONFIG.capture_area / 2.0
    for motion in subjects:
        np.testing.assert_allclose(motion.poses[:, feet, 2].min(1), ANKLE_HEIGHT_MM, atol=1e-3)
        assert motion.poses[..., 2].min() > 0.0
        assert np.abs(motion.poses[:, 0, :2]).max() <= half
        # Walking is upright: the head top is most of the way up the chain of bones from the ankle.
        chain = ANKLE_HEIGHT_MM + sum(motion.bone_lengths[H36M_17.index(name)] for name in
                                      ("RFoot", "RKnee", "Spine", "Thorax", "Neck/Nose", "Head"))
        head = motion.poses[motion.motion == "walking", H36M_17.index("Head"), 2]
        assert 0.85 * chain < np.median(head) < chain and 1400.0 < chain < 2000.0


def test_motion_is_smooth_not_noise(subjects):
    for motion in subjects:
        for sequence in np.unique(motion.sequence):
            poses = motion.poses[motion.sequence == sequence].astype(np.float64)
            step = np.linalg.norm(poses[1:] - poses[:-1], axis=-1)  # mm per frame
            # A brisk walk's swing foot peaks near 5 m/s; 8 m/s would not be everyday motion.
            assert step.max() * CONFIG.fps < 8000.0
            # Smooth trajectories move less in one frame than in five; independent noise would not.
            five = np.linalg.norm(poses[5:] - poses[:-5], axis=-1)
            assert np.median(step) < 0.6 * np.median(five)


def test_walking_travels_and_in_place_families_keep_their_feet():
    config = dataclasses.replace(CONFIG, samples_per_subject=16)
    bones = sample_bone_lengths(np.random.default_rng(0))
    feet = [H36M_17.index("LFoot"), H36M_17.index("RFoot")]
    for family in MOTION_FAMILIES:
        for seed in range(5):
            motion = sample_motion(np.random.default_rng(seed), family, bones, 100, config)
            assert motion.angles.shape == (100, len(ANGLE_NAMES)) and motion.poses.shape == (100, J, 3)
            if family in ("walking", "turning"):
                speed = np.linalg.norm(np.diff(motion.poses[:, 0, :2], axis=0), axis=-1).mean() * config.fps
                assert 400.0 < speed < 1800.0, (family, speed)
            else:
                centre = motion.poses[:, feet, :2].mean(1)
                assert np.linalg.norm(centre - centre.mean(0), axis=-1).max() < 300.0, family
    with pytest.raises(ValueError, match="unknown motion family"):
        sample_motion(np.random.default_rng(0), "dancing", bones, 10, config)


# ---------------------------------------------------------------------------------------------- cameras


def test_rig_geometry(dataset):
    for s in range(CONFIG.num_subjects):
        rig = rig_of(dataset, s)
        validate_cameras(rig, (CONFIG.num_views,))
        centers = -np.einsum("cji,cj->ci", rig.R.astype(np.float64), rig.t)
        radius = np.linalg.norm(centers[:, :2], axis=-1)
        assert np.all(radius > CONFIG.camera_distance[0] - 100.0) and np.all(radius < CONFIG.camera_distance[1] + 100.0)
        assert np.all(centers[:, 2] > CONFIG.camera_height[0] - 100.0)
        assert np.all(centers[:, 2] < CONFIG.camera_height[1] + 100.0)
        focal = rig.K[:, [0, 1], [0, 1]]
        assert np.all(np.abs(focal / CONFIG.focal_length - 1.0) < 0.07)
        assert np.all(np.abs(rig.K[:, :2, 2] - 500.0) < 50.0)
        # Optical axes point at the middle of the room (about 1 m up).
        forward = rig.R[:, 2].astype(np.float64)
        to_centre = np.array([0.0, 0.0, 1000.0]) - centers
        to_centre /= np.linalg.norm(to_centre, axis=-1, keepdims=True)
        assert np.all(np.sum(forward * to_centre, -1) > np.cos(np.radians(10.0)))
    # Each subject has its own slightly different calibration of the same room.
    K0, K1 = dataset.rigs.K[0], dataset.rigs.K[1]
    assert not np.array_equal(K0, K1) and np.abs(K0 - K1).max() < 30.0


@pytest.mark.parametrize("views", [2, 3, 7])
def test_make_rig_any_view_count(views):
    config = dataclasses.replace(CONFIG, num_views=views)
    rig = make_rig(np.random.default_rng(views), config)
    assert rig.K.shape == (views, 3, 3) and rig.R.shape == (views, 3, 3) and rig.t.shape == (views, 3)
    assert rig.dist is None and isinstance(rig.K, np.ndarray) and rig.K.dtype == np.float32
    validate_cameras(rig, (views,))


def test_joints_in_front_of_every_camera_inside_the_image_and_upright(dataset):
    width, height = CONFIG.image_size
    head, foot = H36M_17.index("Head"), H36M_17.index("LFoot")
    for s in range(CONFIG.num_subjects):
        rows = dataset.samples.rig_index == s
        rig = rig_of(dataset, s)
        pixels, depth = project_points(rig, dataset.samples.target3d[rows])
        assert depth.min() > 0.0
        inside = (pixels[..., 0] >= 0) & (pixels[..., 0] < width) & (pixels[..., 1] >= 0) & (pixels[..., 1] < height)
        assert inside.mean() > 0.99
        # Image y points down: a walking person's head is above (smaller y than) the feet in every view.
        walking = dataset.samples.labels["motion"][rows] == "walking"
        assert np.all(pixels[walking, :, head, 1] < pixels[walking, :, foot, 1])
        # Same projection as the library's (pinhole, x_cam = R x + t).
        library = np.asarray(project(rig, dataset.samples.target3d[rows][:, None]))  # [N, C, J, 2]
        np.testing.assert_allclose(library, pixels, atol=0.05)


def test_config_validation():
    with pytest.raises(ValueError, match="num_views"):
        SyntheticConfig(num_views=1)
    with pytest.raises(ValueError, match="camera_distance"):
        SyntheticConfig(camera_distance=(2500.0, 3000.0))
    with pytest.raises(ValueError, match="missing_rate"):
        SyntheticConfig(missing_rate=1.5)


# ---------------------------------------------------------------------------------------------- detector


@pytest.fixture(scope="module")
def clean2d(dataset):
    """Exact projections of the first subject, repeated to 24k samples for tight statistics."""
    rows = dataset.samples.rig_index == 0
    pixels, _ = project_points(rig_of(dataset, 0), dataset.samples.target3d[rows])
    return np.tile(pixels, (20, 1, 1, 1))


@pytest.mark.parametrize("scale", [1.0, 1.7])
def test_detector_noise_matches_sigma(clean2d, scale):
    config = dataclasses.replace(CONFIG, noise_sigma_scale=scale)
    detections = simulate_detector(np.random.default_rng(0), clean2d, config)
    sigma = detector_sigma(config)
    np.testing.assert_allclose(sigma, scale * np.array([DETECTOR_SIGMA_PX[n] for n in H36M_17.joint_names]))
    assert 3.0 * scale <= sigma.min() and sigma.max() <= 8.0 * scale
    clean = ~detections.outlier & ~detections.missing & ~detections.swapped[..., None]
    error = detections.keypoints2d - clean2d  # [N, C, J, 2]
    for j in range(J):
        rms = np.sqrt(np.mean(error[..., j, :][clean[..., j]] ** 2))  # per axis
        assert abs(rms / sigma[j] - 1.0) < 0.05, (H36M_17.joint_names[j], rms, sigma[j])


def test_detector_corruption_rates_and_missing_joints(clean2d):
    config = dataclasses.replace(CONFIG, outlier_rate=0.05, swap_rate=0.03, missing_rate=0.02)
    d = simulate_detector(np.random.default_rng(1), clean2d, config)
    assert abs(d.outlier.mean() - 0.05 * (1 - 0.02)) < 0.003
    assert abs(d.swapped.mean() - 0.03) < 0.003
    assert abs(d.missing.mean() - 0.02) < 0.002
    # Missing: coordinates and confidence exactly 0, never NaN; everything else is detected.
    assert np.all(d.keypoints2d[d.missing] == 0.0) and np.all(d.confidence[d.missing] == 0.0)
    assert np.all(d.confidence[~d.missing] > 0.0) and np.all(d.confidence <= 1.0)
    assert np.isfinite(d.keypoints2d).all()
    # Gross outliers are displaced by 30-150 px (plus the Gaussian noise).
    error = np.linalg.norm(d.keypoints2d - clean2d, axis=-1)
    assert np.percentile(error[d.outlier], 5) > 20.0 and np.percentile(error[d.outlier], 95) < 170.0
    # A swapped view shows the right limbs' positions for the left joints.
    n, c = np.argwhere(d.swapped & ~d.outlier.any(-1) & ~d.missing.any(-1))[0]
    flipped = clean2d[n, c, H36M_17.flip_permutation()]
    assert np.abs(d.keypoints2d[n, c] - flipped).max() < 50.0


def test_root_stays_triangulable_with_many_missing_joints(clean2d):
    config = dataclasses.replace(CONFIG, num_views=2, missing_rate=0.5)
    d = simulate_detector(np.random.default_rng(2), clean2d[:, :2], config)
    assert np.all((~d.missing[:, :, 0]).sum(1) >= 2)
    assert abs(d.missing[..., 1:].mean() - 0.5) < 0.01


def test_confidence_falls_with_error(clean2d):
    d = simulate_detector(np.random.default_rng(3), clean2d, CONFIG)
    error = np.linalg.norm(d.keypoints2d - clean2d, axis=-1)
    detected = ~d.missing
    rho = spearmanr(d.confidence[detected][::7], error[detected][::7]).statistic
    assert rho < -0.3, rho
    clean = detected & ~d.outlier & ~d.swapped[..., None]
    assert d.confidence[clean].mean() > 0.75
    assert d.confidence[d.outlier].mean() < 0.4
    # Swapped views: the lateral joints (far from their mirror partner) score low.
    lateral = np.zeros(J, bool)
    lateral[[j for pair in H36M_17.left_right_pairs for j in pair]] = True
    assert d.confidence[d.swapped][:, lateral].mean() < 0.5


def test_generated_detections_have_configured_noise_and_missing_rate(dataset):
    """On the assembled data set: robust per-joint error scale and the missing fraction."""
    sigma = detector_sigma(CONFIG)
    missing = dataset.samples.confidence == 0.0
    assert abs(missing.mean() - CONFIG.missing_rate) < 0.003
    assert np.all(dataset.samples.keypoints2d[missing] == 0.0)
    for s in range(CONFIG.num_subjects):
        rows = dataset.samples.rig_index == s
        pixels, _ = project_points(rig_of(dataset, s), dataset.samples.target3d[rows])
        error = np.abs(dataset.samples.keypoints2d[rows] - pixels)  # [N, C, J, 2]
        for j in range(J):
            seen = ~missing[rows][..., j]
            # The median absolute error of a Gaussian is 0.6745 sigma; outliers and swaps barely move it.
            scale = np.median(error[..., j, :][seen]) / 0.6745
            assert abs(scale / sigma[j] - 1.0) < 0.1, (s, H36M_17.joint_names[j], scale, sigma[j])


# ---------------------------------------------------------------------------------------------- speed


def test_generates_100k_samples_fast():
    config = SyntheticConfig(samples_per_subject=100_000 // 7 + 1)  # 5 train + 2 test subjects
    # The CPU seconds of this process (all its threads), not wall time: the suite runs on every core
    # (pytest-xdist), and a neighbouring worker's load must not make this test fail or pass.
    start = time.process_time()
    data = generate(config)
    seconds = time.process_time() - start
    assert len(data) >= 100_000
    print(f"generated {len(data)} samples x {config.num_views} views in {seconds:.2f} CPU s")
    assert seconds < 30.0
