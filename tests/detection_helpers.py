"""Detections as detectors write them, built from the synthetic test split, for the inference tests."""

from __future__ import annotations

import numpy as np

from jaxpose.layouts import OPENPOSE_25_JOINT_NAMES
from jaxpose.skeleton import COCO_17, H36M_17


def views(test):
    """Every test view as one single-view sample: keypoints [M, J, 2], confidence [M, J], K [M, 3, 3]."""
    N, C, J, _ = test.samples.keypoints2d.shape
    K = np.asarray(test.rigs.K)[test.samples.rig_index].reshape(N * C, 3, 3)
    return test.samples.keypoints2d.reshape(N * C, J, 2), test.samples.confidence.reshape(N * C, J), K


def coco_from_h36m(keypoints: np.ndarray) -> np.ndarray:
    """COCO-17 keypoints [N, 17, 2] that a detector could have given for H36M_17 poses [N, 17, 2]:
    limbs copied, eyes and ears placed around the face line from Neck/Nose to Head."""
    joint = {name: keypoints[:, H36M_17.index(name)] for name in H36M_17.joint_names}
    nose, up = joint["Neck/Nose"], (joint["Head"] - joint["Neck/Nose"]) / 3.0
    side = np.stack([-up[:, 1], up[:, 0]], axis=1)  # perpendicular to the face line
    coco = {
        "nose": nose, "left_eye": nose + up + 0.4 * side, "right_eye": nose + up - 0.4 * side,
        "left_ear": nose + 0.8 * up + 1.0 * side, "right_ear": nose + 0.8 * up - 1.0 * side,
    }  # fmt: skip
    for side_name, letter in (("left", "L"), ("right", "R")):
        for coco_joint, h36m_joint in (("shoulder", "Shoulder"), ("elbow", "Elbow"), ("wrist", "Wrist"),
                                       ("hip", "Hip"), ("knee", "Knee"), ("ankle", "Foot")):  # fmt: skip
            coco[f"{side_name}_{coco_joint}"] = joint[letter + h36m_joint]
    return np.stack([coco[name] for name in COCO_17.joint_names], axis=1)


def body25_from_coco(coco: np.ndarray, score: float) -> np.ndarray:
    """OpenPose BODY_25 [x, y, score] [N, 25, 3] with the joints COCO-17 shares, the neck between the
    shoulders; feet and mid-hip undetected (score 0)."""
    body25 = np.zeros((len(coco), 25, 3), np.float32)
    for b, name in enumerate(OPENPOSE_25_JOINT_NAMES):
        side = {"L": "left_", "R": "right_"}.get(name[0], "")
        coco_name = side + name[1:].lower() if side else name.lower()  # "LShoulder" -> "left_shoulder"
        if coco_name in COCO_17.joint_names:
            body25[:, b] = np.concatenate([coco[:, COCO_17.index(coco_name)], np.full((len(coco), 1), score)], 1)
    shoulders = [COCO_17.index("left_shoulder"), COCO_17.index("right_shoulder")]
    neck = coco[:, shoulders].mean(1)  # [N, 2]
    body25[:, OPENPOSE_25_JOINT_NAMES.index("Neck")] = np.concatenate([neck, np.full((len(coco), 1), score)], 1)
    return body25
