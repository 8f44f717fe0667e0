"""A detector's keypoints on the simulated body, for the example rig project: the names written per
layout (COCO-17, OpenPose BODY_25), their true 3D positions (`keypoints3d`), the body joint whose
detector noise each keypoint gets, and the ground truth's joint names.

Joints the body has are used as they are (a detector's hips are taken to be Human3.6M's hip joints,
the ankles its "Foot" joints); BODY_25's MidHip and Neck are the hips' and shoulders' midpoints; the
face and feet points are rigid offsets in a head frame and in foot frames built from the body's
joints (`_HEAD_POINTS_MM`, `_FOOT_POINTS_MM`), so every keypoint has a true 3D position.
"""

from __future__ import annotations

import numpy as np

from jaxpose.layouts import OPENPOSE_25_JOINT_NAMES
from jaxpose.skeleton import COCO_17
from jaxpose.synthetic.body import JOINT_INDEX, NOMINAL_BONE_MM, axis_rotation

# The body's H36M_17 joints a detector keypoint is (OpenPose names; COCO names map onto them).
_BODY_JOINT = {
    f"{side}{part}": f"{side}{joint}"
    for side in "LR"
    for part, joint in (("Shoulder", "Shoulder"), ("Elbow", "Elbow"), ("Wrist", "Wrist"), ("Hip", "Hip"),
                        ("Knee", "Knee"), ("Ankle", "Foot"))
}  # fmt: skip

# Face points: offsets (mm; forward, left, up) from the body's "Head" joint in the head frame (origin
# the Head joint, which sits mid-head at about forehead height; up from the thorax to it; forward
# towards the nose).  Adult values: eyes 64 mm apart and ~80 mm ahead of the head's axis, ~35 mm
# below the forehead; nose tip ~100 mm ahead, ~75 mm below; ears (tragion) ~145 mm apart, level with
# the nose bridge, just behind the axis.  Scaled with the subject's neck + head bone lengths.
_HEAD_POINTS_MM = {
    "Nose": (100.0, 0.0, -75.0),
    "LEye": (80.0, 32.0, -35.0),
    "REye": (80.0, -32.0, -35.0),
    "LEar": (-5.0, 72.0, -55.0),
    "REar": (-5.0, -72.0, -55.0),
}
# Foot points of the left foot (the right mirrors left): offsets (mm; forward, left, up) from the ankle
# in the foot frame.  A 260 mm foot: the heel's back ~55 mm behind the ankle centre and ~70 mm below it
# (the simulator's lowest ankle is 80 mm above the floor), the big toe ~170 mm ahead, 25 mm medial and
# ~25 mm above the floor, the small toe ~135 mm ahead, 35 mm lateral, ~20 mm up.  Lengths scale with
# the shank.
_FOOT_POINTS_MM = {"BigToe": (170.0, -25.0, -55.0), "SmallToe": (135.0, 35.0, -60.0), "Heel": (-55.0, 0.0, -70.0)}
# Feet point outwards by this much (degrees) from the shank's forward direction.
_TOE_OUT_DEG = 7.0
# A foot follows its shank's tilt only this much (the rest the ankle flexes away: feet stay near flat).
_FOOT_TILT_SHARE = 0.2

# The body joint whose detector noise each keypoint gets: its nearest joint of the body.
NOISE_JOINT = {
    "Nose": "Neck/Nose", "Neck": "Thorax", "MidHip": "Hip",
    **{f"{side}{point}": "Head" for side in "LR" for point in ("Eye", "Ear")},
    **{f"{side}{point}": f"{side}Foot" for side in "LR" for point in ("BigToe", "SmallToe", "Heel")},
    **_BODY_JOINT,
}  # fmt: skip


def _openpose_name(coco_name: str) -> str:
    """COCO's "left_shoulder" -> OpenPose's "LShoulder"; "nose" -> "Nose"."""
    for prefix, side in (("left_", "L"), ("right_", "R")):
        if coco_name.startswith(prefix):
            return side + coco_name[len(prefix) :].capitalize()
    return coco_name.capitalize()


def mirror(name: str) -> str:
    """OpenPose name of the keypoint on the other side ("LEye" <-> "REye"); midline names unchanged."""
    if name[:1] in ("L", "R") and name[1:2].isupper():
        return {"L": "R", "R": "L"}[name[0]] + name[1:]
    return name


def layout_names(layout: str) -> tuple[str, ...]:
    """The keypoint names written for `layout`, in the file's order."""
    return {"coco17": COCO_17.joint_names, "body25": OPENPOSE_25_JOINT_NAMES}[layout]


def openpose_names(layout: str) -> tuple[str, ...]:
    """The keypoint names of `layout` as OpenPose spells them ("LShoulder"), in the file's order."""
    names = layout_names(layout)
    return tuple(_openpose_name(name) for name in names) if layout == "coco17" else names


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def keypoints3d(poses: np.ndarray, bone_lengths: np.ndarray, layout: str) -> np.ndarray:
    """H36M_17 poses f[T, 17, 3] (world mm, z up) -> f64[T, K, 3] the layout's keypoints, file order."""
    poses = np.asarray(poses, np.float64)
    joint = {name: poses[:, index] for name, index in JOINT_INDEX.items()}
    points = {name: joint[source] for name, source in _BODY_JOINT.items()}
    points["MidHip"] = 0.5 * (joint["LHip"] + joint["RHip"])
    points["Neck"] = 0.5 * (joint["LShoulder"] + joint["RShoulder"])
    # Head frame: up along thorax -> Head, forward towards the (rigidly attached) Neck/Nose joint.
    up = _unit(joint["Head"] - joint["Thorax"])
    forward = joint["Neck/Nose"] - joint["Thorax"]
    forward = _unit(forward - np.sum(forward * up, -1, keepdims=True) * up)
    head = np.stack([forward, np.cross(up, forward), up], axis=-1)  # columns: forward, left, up
    head_scale = (bone_lengths[JOINT_INDEX["Neck/Nose"]] + bone_lengths[JOINT_INDEX["Head"]]) / (
        NOMINAL_BONE_MM["Neck/Nose"] + NOMINAL_BONE_MM["Head"]
    )
    for name, offset in _HEAD_POINTS_MM.items():
        points[name] = joint["Head"] + head_scale * head @ np.asarray(offset)
    # Foot frames: forward is perpendicular to the shank in the legs' plane (the pelvis' left-right
    # axis is the knee's hinge), mostly levelled, then turned outwards by the toe-out angle.
    z = np.array([0.0, 0.0, 1.0])
    pelvis_left = _unit(joint["LHip"] - joint["RHip"])
    for side, sign in (("L", 1.0), ("R", -1.0)):
        shank_down = _unit(joint[f"{side}Foot"] - joint[f"{side}Knee"])
        forward = _unit(np.cross(shank_down, pelvis_left))
        forward = _unit(forward - (1.0 - _FOOT_TILT_SHARE) * (forward @ z)[:, None] * z)
        forward = forward @ axis_rotation(2, np.array(sign * _TOE_OUT_DEG)).T
        foot_up = _unit(z - (forward @ z)[:, None] * forward)
        foot = np.stack([forward, np.cross(foot_up, forward), foot_up], axis=-1)
        scale = bone_lengths[JOINT_INDEX[f"{side}Foot"]] / NOMINAL_BONE_MM[f"{side}Foot"]
        for point, (ahead, left, above) in _FOOT_POINTS_MM.items():
            # Lengths scale with the body; heights not: the simulator's ankle height is the same for all.
            points[side + point] = joint[f"{side}Foot"] + foot @ np.array([scale * ahead, scale * sign * left, above])
    return np.stack([points[name] for name in openpose_names(layout)], axis=1)


def ground_truth_names(layout: str) -> tuple[str, ...]:
    """The written keypoints plus the root: COCO has none, so "pelvis" (the hips' midpoint) is added."""
    return layout_names(layout) + (("pelvis",) if layout == "coco17" else ())
