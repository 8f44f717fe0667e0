"""Real motion capture as jaxpose's keypoints: the CMU skeleton's joints mapped to COCO-17 and H36M_17.

`mocap_keypoints(bvh, layout)` runs the BVH file's forward kinematics (`jaxpose.formats.bvh`, CMU units
of 1/0.45 inch) and gives the layout's keypoints in jaxpose's world frame (mm, z up, the floor at the
lowest toe of the take, the take's mean root position over the floor's origin: inside a rig's capture
area).  The motion only: CMU's BVH conversions begin with the skeleton's rest pose (frame 0: the root
unrotated, the arms out; 160-500 mm from frame 1 in the mean joint, where the motion moves a joint 1-21 mm
a frame, in every take of ../shared/data/cmu_mocap), which is no instant of the motion and is left out
(`rest_frames`); scored as motion, it cost a smoother 6-19 mm of MPJPE on clips of 10-30 frames.  The CMU skeleton (31 joints) names its bones: a joint's BVH position is its bone's start.

Keypoints that are a CMU joint (COCO name <- CMU joint):
- shoulders <- LeftArm / RightArm (the upper arm's start, the glenohumeral joint),
- elbows <- LeftForeArm / RightForeArm, wrists <- LeftHand / RightHand,
- hips <- LeftUpLeg / RightUpLeg, knees <- LeftLeg / RightLeg, ankles <- LeftFoot / RightFoot.

Keypoints with no mocap joint: the nose, the eyes and the ears.  The CMU head is two points (the Head joint,
at the top of the neck, and its End Site, the top of the head) and the Head joint's rotation.  Each face
point is a fixed offset from the Head joint in the Head joint's frame (CMU's rest pose faces +Z with +Y up
and +X the subject's left), scaled by the take's Head -> head-top length over `NOMINAL_HEAD_MM`
(`_FACE_POINTS_MM`: forward, left, up).  They turn with the head, as a detector's face points do.

H36M_17 (the Human3.6M skeleton jaxpose's lifters also work on): Hip <- the hips' midpoint (Human3.6M's
pelvis is the midpoint of its hip joints), RHip/LHip, knees, RFoot/LFoot (the ankles) as above; Spine <-
Spine (CMU's, halfway up the back); Thorax <- Spine1's end, the base of the neck where the shoulders branch
(CMU's Neck joint); Neck/Nose <- the nose point above; Head <- the head top (Head's End Site).  Shoulders,
elbows, wrists as COCO's.  BODY_25, COCO-18 and Halpe-26's extra points (feet, mid-hip, neck) are not mapped.
"""

from __future__ import annotations

import numpy as np

from jaxpose.formats.bvh import CMU_MM_PER_UNIT, BvhFile, forward_kinematics
from jaxpose.skeleton import COCO_17, H36M_17

MOCAP_LAYOUTS = ("coco17", "h36m17")
NOMINAL_HEAD_MM = 90.0
"""The Head joint to head-top length the face offsets are given for (CMU subject 02's is 92 mm)."""
# Face points: offsets (mm; forward, left, up) from CMU's Head joint in its frame, for a head of
# NOMINAL_HEAD_MM.  The Head joint sits at the top of the neck over the spine; the ears (tragion) are
# about level with it and ~70 mm to each side, the eyes ~90 mm ahead and ~30 mm above the ears'
# level, the nose tip ~115 mm ahead a little below the eyes.
_FACE_POINTS_MM = {
    "nose": (115.0, 0.0, 5.0),
    "left_eye": (90.0, 32.0, 30.0),
    "right_eye": (90.0, -32.0, 30.0),
    "left_ear": (0.0, 70.0, 0.0),
    "right_ear": (0.0, -70.0, 0.0),
}
# COCO keypoints that are a CMU joint.
_COCO_JOINTS = {
    f"{side}_{part}": f"{cmu_side}{joint}"
    for side, cmu_side in (("left", "Left"), ("right", "Right"))
    for part, joint in (("shoulder", "Arm"), ("elbow", "ForeArm"), ("wrist", "Hand"), ("hip", "UpLeg"), ("knee", "Leg"),
                        ("ankle", "Foot"))
}  # fmt: skip
# CMU's rest-pose axes (forward, left, up) in its file frame; and its file frame (Y up) to jaxpose's world (z up).
_HEAD_AXES = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]).T
_Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


def _coco17(joints: dict[str, np.ndarray], head_rotation: np.ndarray) -> dict[str, np.ndarray]:
    points = {name: joints[cmu] for name, cmu in _COCO_JOINTS.items()}
    scale = np.linalg.norm(joints["Head_End"] - joints["Head"], axis=-1)[:, None] / NOMINAL_HEAD_MM
    for name, offset in _FACE_POINTS_MM.items():
        points[name] = joints["Head"] + scale * np.einsum("fij,j->fi", head_rotation @ _HEAD_AXES, np.asarray(offset))
    return points


def rest_frames(bvh: BvhFile) -> int:
    """1 where the take's frame 0 is the rest pose CMU's conversions put first (the root's rotation channels
    all exactly 0), else 0.  The root is the hierarchy's first joint, its channels the motion's first columns."""
    root = [column for column, name in enumerate(bvh.channels[0]) if name.endswith("rotation")]
    return int(bvh.frame_count > 1 and not np.any(bvh.motion[0, root]))


def mocap_keypoints(bvh: BvhFile, layout: str, mm_per_unit: float = CMU_MM_PER_UNIT,
                    frames: slice | np.ndarray = slice(None)) -> np.ndarray:  # fmt: skip
    """float64[F, K, 3] the `layout`'s keypoints (COCO-17 or H36M_17, in its order) of a CMU-skeleton BVH
    take's motion, world mm, z up (module docstring); `frames` chooses among the motion's frames (the file's
    from `rest_frames` on)."""
    if layout not in MOCAP_LAYOUTS:
        raise ValueError(f"layout must be one of {MOCAP_LAYOUTS}, got {layout!r}")
    missing = [name for name in ("Head", "Head_End", "Spine", "Neck", *_COCO_JOINTS.values()) if name not in bvh.joint_names]
    if missing:
        raise ValueError(f"not a CMU-skeleton BVH file: no joints {missing}")
    positions, rotations = forward_kinematics(bvh, mm_per_unit, slice(rest_frames(bvh), None))
    positions = positions @ _Y_UP_TO_Z_UP.T
    rotations = _Y_UP_TO_Z_UP @ rotations
    feet = [bvh.index(name) for name in bvh.joint_names if "Toe" in name or name.endswith("Foot")]
    floor = positions[:, feet, 2].min()
    centre = positions[:, bvh.index("Hips"), :2].mean(0)
    positions = (positions - np.array([*centre, floor]))[frames]
    joints = {name: positions[:, index] for index, name in enumerate(bvh.joint_names)}
    points = _coco17(joints, rotations[frames, bvh.index("Head")])
    if layout == "coco17":
        return np.stack([points[name] for name in COCO_17.joint_names], axis=1)
    h36m = {
        "Hip": 0.5 * (points["left_hip"] + points["right_hip"]), "Spine": joints["Spine"], "Thorax": joints["Neck"],
        "Neck/Nose": points["nose"], "Head": joints["Head_End"],
        **{f"{side[0].upper()}{part}": points[f"{side}_{coco}"] for side in ("left", "right")
           for part, coco in (("Hip", "hip"), ("Knee", "knee"), ("Foot", "ankle"), ("Shoulder", "shoulder"),
                              ("Elbow", "elbow"), ("Wrist", "wrist"))},
    }  # fmt: skip
    return np.stack([h36m[name] for name in H36M_17.joint_names], axis=1)
