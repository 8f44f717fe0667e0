"""Tests of jaxpose.layouts on hand-made COCO-17 and OpenPose BODY_25 detections."""

import numpy as np
import pytest

from jaxpose.layouts import (
    FORMATS,
    OPENPOSE_25_JOINT_NAMES,
    coco17_to_h36m17,
    halpe26_to_h36m17,
    h36m17_to_h36m17,
    openpose25_to_h36m17,
    to_h36m17,
)
from jaxpose.layouts import infer_layout, layout_of, lifting_skeleton, to_lifting_skeleton, to_skeleton
from jaxpose.skeleton import COCO_17, DETECTOR_LAYOUTS, H36M_17, get_skeleton

H = H36M_17.index

# A person facing the camera, in pixels (y down); the source joint -> position and score.
COCO_POINTS = {
    "nose": (200.0, 100.0, 0.9),
    "left_eye": (210.0, 90.0, 0.8),
    "right_eye": (190.0, 90.0, 0.7),
    "left_ear": (220.0, 95.0, 0.6),
    "right_ear": (180.0, 95.0, 0.6),
    "left_shoulder": (240.0, 150.0, 0.95),
    "right_shoulder": (160.0, 150.0, 0.85),
    "left_elbow": (250.0, 200.0, 0.9),
    "right_elbow": (150.0, 200.0, 0.9),
    "left_wrist": (255.0, 250.0, 0.5),
    "right_wrist": (145.0, 250.0, 0.4),
    "left_hip": (220.0, 270.0, 0.6),
    "right_hip": (180.0, 270.0, 0.75),
    "left_knee": (222.0, 350.0, 0.9),
    "right_knee": (178.0, 350.0, 0.9),
    "left_ankle": (224.0, 430.0, 0.3),
    "right_ankle": (176.0, 430.0, 0.2),
}

# BODY_25 names of the same person; Neck deliberately off the shoulder midpoint to tell them apart.
OPENPOSE_POINTS = {
    "Nose": COCO_POINTS["nose"], "Neck": (200.0, 146.0, 0.88),
    "RShoulder": COCO_POINTS["right_shoulder"], "RElbow": COCO_POINTS["right_elbow"],
    "RWrist": COCO_POINTS["right_wrist"], "LShoulder": COCO_POINTS["left_shoulder"],
    "LElbow": COCO_POINTS["left_elbow"], "LWrist": COCO_POINTS["left_wrist"],
    "MidHip": (205.0, 265.0, 0.99), "RHip": COCO_POINTS["right_hip"], "RKnee": COCO_POINTS["right_knee"],
    "RAnkle": COCO_POINTS["right_ankle"], "LHip": COCO_POINTS["left_hip"], "LKnee": COCO_POINTS["left_knee"],
    "LAnkle": COCO_POINTS["left_ankle"], "REye": COCO_POINTS["right_eye"], "LEye": COCO_POINTS["left_eye"],
    "REar": COCO_POINTS["right_ear"], "LEar": COCO_POINTS["left_ear"],
    "LBigToe": (230.0, 440.0, 0.5), "LSmallToe": (235.0, 438.0, 0.5), "LHeel": (222.0, 436.0, 0.5),
    "RBigToe": (170.0, 440.0, 0.5), "RSmallToe": (165.0, 438.0, 0.5), "RHeel": (178.0, 436.0, 0.5),
}


def arrays(points, names):
    keypoints = np.array([points[name][:2] for name in names], np.float32)
    scores = np.array([points[name][2] for name in names], np.float32)
    return keypoints, scores


# H36M_17 joints that are plain copies of a COCO joint.
COCO_DIRECT = {
    "RHip": "right_hip", "RKnee": "right_knee", "RFoot": "right_ankle",
    "LHip": "left_hip", "LKnee": "left_knee", "LFoot": "left_ankle",
    "Neck/Nose": "nose", "LShoulder": "left_shoulder", "LElbow": "left_elbow", "LWrist": "left_wrist",
    "RShoulder": "right_shoulder", "RElbow": "right_elbow", "RWrist": "right_wrist",
}
OPENPOSE_DIRECT = {
    "RHip": "RHip", "RKnee": "RKnee", "RFoot": "RAnkle", "LHip": "LHip", "LKnee": "LKnee", "LFoot": "LAnkle",
    "Neck/Nose": "Nose", "LShoulder": "LShoulder", "LElbow": "LElbow", "LWrist": "LWrist",
    "RShoulder": "RShoulder", "RElbow": "RElbow", "RWrist": "RWrist", "Thorax": "Neck",
}


def test_coco_direct_joints_are_copied_with_their_scores():
    keypoints, confidence = coco17_to_h36m17(*arrays(COCO_POINTS, COCO_17.joint_names))
    assert keypoints.shape == (17, 2) and confidence.shape == (17,)
    assert keypoints.dtype == np.float32 and confidence.dtype == np.float32
    for ours, theirs in COCO_DIRECT.items():
        np.testing.assert_array_equal(keypoints[H(ours)], COCO_POINTS[theirs][:2], err_msg=ours)
        assert confidence[H(ours)] == np.float32(COCO_POINTS[theirs][2]), ours


def test_coco_constructed_joints():
    keypoints, confidence = coco17_to_h36m17(*arrays(COCO_POINTS, COCO_17.joint_names))
    # pelvis: mean of hips (200, 270), min(0.6, 0.75); thorax: mean of shoulders (200, 150).
    np.testing.assert_array_equal(keypoints[H("Hip")], [200.0, 270.0])
    assert confidence[H("Hip")] == np.float32(0.6)
    np.testing.assert_array_equal(keypoints[H("Thorax")], [200.0, 150.0])
    assert confidence[H("Thorax")] == np.float32(0.85)
    # spine: halfway from pelvis to thorax; all four sources.
    np.testing.assert_array_equal(keypoints[H("Spine")], [200.0, 210.0])
    assert confidence[H("Spine")] == np.float32(0.6)
    # head: nose (200, 100) + 3 * (eye midpoint (200, 90) - nose) = (200, 70).
    np.testing.assert_array_equal(keypoints[H("Head")], [200.0, 70.0])
    assert confidence[H("Head")] == np.float32(0.7)


def test_head_follows_a_tilted_face():
    points = dict(COCO_POINTS, nose=(100.0, 100.0, 1.0), left_eye=(108.0, 96.0, 1.0), right_eye=(104.0, 88.0, 1.0))
    keypoints, _ = coco17_to_h36m17(*arrays(points, COCO_17.joint_names))
    # eye midpoint (106, 92): 3 * (6, -8) from the nose.
    np.testing.assert_allclose(keypoints[H("Head")], [118.0, 76.0], rtol=0, atol=1e-4)


def test_openpose_direct_and_constructed_joints():
    keypoints, confidence = openpose25_to_h36m17(*arrays(OPENPOSE_POINTS, OPENPOSE_25_JOINT_NAMES))
    for ours, theirs in OPENPOSE_DIRECT.items():
        np.testing.assert_array_equal(keypoints[H(ours)], OPENPOSE_POINTS[theirs][:2], err_msg=ours)
        assert confidence[H(ours)] == np.float32(OPENPOSE_POINTS[theirs][2]), ours
    # pelvis: mean of the hips, not MidHip.
    np.testing.assert_array_equal(keypoints[H("Hip")], [200.0, 270.0])
    assert confidence[H("Hip")] == np.float32(0.6)
    # spine: halfway from pelvis (200, 270) to Neck (200, 146).
    np.testing.assert_array_equal(keypoints[H("Spine")], [200.0, 208.0])
    assert confidence[H("Spine")] == np.float32(0.6)
    np.testing.assert_array_equal(keypoints[H("Head")], [200.0, 70.0])
    assert confidence[H("Head")] == np.float32(0.7)


def test_missing_sources_give_zero_confidence_and_zero_coordinates():
    points = dict(COCO_POINTS, left_hip=(np.nan, np.nan, 0.0), right_eye=(0.0, 0.0, 0.0), left_wrist=(17.0, 3.0, 0.0))
    keypoints, confidence = coco17_to_h36m17(*arrays(points, COCO_17.joint_names))
    assert np.isfinite(keypoints).all() and np.isfinite(confidence).all()
    for joint in ("LHip", "Hip", "Spine", "Head", "LWrist"):
        assert confidence[H(joint)] == 0.0, joint
        np.testing.assert_array_equal(keypoints[H(joint)], [0.0, 0.0], err_msg=joint)
    # Joints that do not use the missing sources are untouched.
    assert confidence[H("Thorax")] == np.float32(0.85)
    assert confidence[H("Neck/Nose")] == np.float32(0.9)
    np.testing.assert_array_equal(keypoints[H("RHip")], [180.0, 270.0])


def test_nan_coordinates_with_a_positive_score_count_as_missing():
    keypoints, scores = arrays(OPENPOSE_POINTS, OPENPOSE_25_JOINT_NAMES)
    keypoints[OPENPOSE_25_JOINT_NAMES.index("Neck")] = np.nan
    out, confidence = openpose25_to_h36m17(keypoints, scores)
    assert np.isfinite(out).all()
    assert confidence[H("Thorax")] == 0.0 and confidence[H("Spine")] == 0.0
    assert confidence[H("Hip")] == np.float32(0.6)


def test_scores_are_clipped_and_none_means_one():
    keypoints, scores = arrays(COCO_POINTS, COCO_17.joint_names)
    _, confidence = coco17_to_h36m17(keypoints, np.full(17, 1.7, np.float32))
    np.testing.assert_array_equal(confidence, np.ones(17, np.float32))
    out, confidence = coco17_to_h36m17(keypoints, None)
    np.testing.assert_array_equal(confidence, np.ones(17, np.float32))
    np.testing.assert_array_equal(out, coco17_to_h36m17(keypoints, scores)[0])


def test_batch_dims_match_single_samples():
    base_keypoints, base_scores = arrays(COCO_POINTS, COCO_17.joint_names)
    rng = np.random.default_rng(0)
    keypoints = base_keypoints + rng.normal(scale=5.0, size=(2, 3, 17, 2)).astype(np.float32)
    scores = np.broadcast_to(base_scores, (2, 3, 17)).copy()
    scores[1, 2, COCO_17.index("nose")] = 0.0
    out, confidence = coco17_to_h36m17(keypoints, scores)
    assert out.shape == (2, 3, 17, 2) and confidence.shape == (2, 3, 17)
    for b in range(2):
        for c in range(3):
            single = coco17_to_h36m17(keypoints[b, c], scores[b, c])
            np.testing.assert_array_equal(out[b, c], single[0])
            np.testing.assert_array_equal(confidence[b, c], single[1])
    assert confidence[1, 2, H("Head")] == 0.0 and confidence[1, 1, H("Head")] > 0.0


def test_registry_dispatches_and_identity_keeps_h36m():
    keypoints, scores = arrays(COCO_POINTS, COCO_17.joint_names)
    assert FORMATS == {
        "coco17": coco17_to_h36m17, "body25": openpose25_to_h36m17, "halpe26": halpe26_to_h36m17, "h36m17": h36m17_to_h36m17,
    }  # fmt: skip
    for got, expected in zip(to_h36m17("coco17", keypoints, scores), coco17_to_h36m17(keypoints, scores)):
        np.testing.assert_array_equal(got, expected)
    h36m, confidence = coco17_to_h36m17(keypoints, scores)
    same, same_confidence = to_h36m17("h36m17", h36m, confidence)
    np.testing.assert_array_equal(same, h36m)
    np.testing.assert_array_equal(same_confidence, confidence)


def test_unknown_format_is_a_value_error():
    with pytest.raises(ValueError, match="unknown keypoint format 'mpii'.*coco17"):
        to_h36m17("mpii", np.zeros((16, 2)), np.ones(16))


@pytest.mark.parametrize(
    "fmt, keypoints_shape, scores_shape, message",
    [
        ("coco17", (18, 2), (18,), r"coco17: expected keypoints of shape \[\.\.\., 17, 2\], got \(18, 2\)"),
        ("body25", (4, 17, 2), (4, 17),
         r"body25: expected keypoints of shape \[\.\.\., 25, 2\], got \(4, 17, 2\)"),
        ("coco17", (17, 3), (17,), r"coco17: expected keypoints .* got \(17, 3\)"),
        ("h36m17", (17,), (17,), r"h36m17: expected keypoints .* got \(17,\)"),
        ("coco17", (2, 17, 2), (17,), r"coco17: expected scores of shape \(2, 17\).* got \(17,\)"),
    ],
)
def test_wrong_shapes_name_format_expected_and_got(fmt, keypoints_shape, scores_shape, message):
    with pytest.raises(ValueError, match=message):
        to_h36m17(fmt, np.zeros(keypoints_shape), np.ones(scores_shape))


# --- Lifting on the detector's own joints ---------------------------------------------------------


@pytest.mark.parametrize("layout", sorted(DETECTOR_LAYOUTS))
def test_lifting_skeleton_is_the_detectors_joints_root_first(layout):
    detector = DETECTOR_LAYOUTS[layout]
    skeleton = lifting_skeleton(layout)
    assert skeleton.joint_names[0] == detector.root and get_skeleton(skeleton.name) == skeleton
    assert set(skeleton.joint_names) - {detector.root} == set(detector.joint_names) - {detector.root}
    rng = np.random.default_rng(0)
    keypoints = rng.uniform(0, 1000, (3, len(detector.joint_names), 2))
    scores = rng.uniform(0.1, 1.0, (3, len(detector.joint_names)))
    scores[0, 2] = 0.0  # one missing keypoint
    out, confidence = to_lifting_skeleton(layout, keypoints, scores)
    for j, name in enumerate(skeleton.joint_names):
        if name in detector.joint_names:
            source = detector.joint_names.index(name)
            np.testing.assert_allclose(out[:, j], np.where(scores[:, source, None] > 0, keypoints[:, source], 0.0), rtol=1e-6)
            np.testing.assert_allclose(confidence[:, j], scores[:, source], rtol=1e-6)
        else:  # the derived root: the hips' midpoint, as confident as the less confident hip
            left, right = (detector.joint_names.index(hip) for hip in detector.root_from)
            np.testing.assert_allclose(out[:, j], (keypoints[:, left] + keypoints[:, right]) / 2, rtol=1e-5)
            np.testing.assert_allclose(confidence[:, j], np.minimum(scores[:, left], scores[:, right]), rtol=1e-6)
    # Left/right pairs mirror each other's names.
    for left, right in skeleton.left_right_pairs:
        assert skeleton.joint_names[left].lower().replace("left_", "l").lstrip("l") == (
            skeleton.joint_names[right].lower().replace("right_", "r").lstrip("r")
        )


def test_layout_inference_and_the_lifters_input():
    assert infer_layout(51, "x") == "coco17" and infer_layout(78, "x") == "halpe26" and infer_layout(54, "x") == "coco18"
    with pytest.raises(ValueError, match="BODY_25 or BODY_25B.*--data.skeleton body25"):
        infer_layout(75, "cam01_json")
    with pytest.raises(ValueError, match="cam01_json: cannot infer the keypoint layout from 60 values"):
        infer_layout(60, "cam01_json")
    with pytest.raises(ValueError, match=r"pass --format body25 or --format body25b$"):
        infer_layout(75, "cam01_json", flag="--format")  # the flag of the command that asks
    keypoints, scores = arrays(COCO_POINTS, COCO_17.joint_names)
    for got, expected in zip(to_skeleton("coco17", lifting_skeleton("coco17"), keypoints, scores),
                             to_lifting_skeleton("coco17", keypoints, scores)):  # fmt: skip
        np.testing.assert_array_equal(got, expected)
    with pytest.raises(ValueError, match="skeleton 'body25b_lifting' cannot take keypoints in layout 'coco17'"):
        to_skeleton("coco17", lifting_skeleton("body25b"), keypoints, scores)
    assert layout_of(lifting_skeleton("halpe26")) == "halpe26" and layout_of(H36M_17) is None
