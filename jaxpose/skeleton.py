"""Joint sets as data: names, kinematic parents and left/right pairs.

Every lifting skeleton has its root (the pelvis) at joint 0; nothing in the library branches on a
skeleton's name, so a new joint set is one more `Skeleton(...)` value.  `COCO_17` is a detector
layout, not a lifting skeleton: convert it (and OpenPose BODY_25) with `jaxpose.layouts`
before lifting.
"""

from __future__ import annotations

import dataclasses

import numpy as np

ROOT = 0  # the root joint (the pelvis) of every lifting skeleton


@dataclasses.dataclass(frozen=True)
class Skeleton:
    """A joint set.  `parents[j]` is the parent joint of j (-1 for the root)."""

    name: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    left_right_pairs: tuple[tuple[int, int], ...]

    def __post_init__(self):
        count = len(self.joint_names)
        if len(self.parents) != count:
            raise ValueError(f"skeleton {self.name}: {count} joint names but {len(self.parents)} parents")
        if len(set(self.joint_names)) != count:
            raise ValueError(f"skeleton {self.name}: joint names are not unique")
        roots = [j for j, p in enumerate(self.parents) if p < 0]
        if roots != [0]:
            raise ValueError(f"skeleton {self.name}: joint 0 must be the only root, found roots {roots}")
        for child, parent in enumerate(self.parents):
            if parent >= count or (parent >= 0 and parent == child):
                raise ValueError(f"skeleton {self.name}: joint {child} has invalid parent {parent}")
        for left, right in self.left_right_pairs:
            if not (0 <= left < count and 0 <= right < count):
                raise ValueError(f"skeleton {self.name}: left/right pair ({left}, {right}) out of range")

    @property
    def num_joints(self) -> int:
        return len(self.joint_names)

    @property
    def bones(self) -> tuple[tuple[int, int], ...]:
        """(child, parent) pairs, one per non-root joint."""
        return tuple((child, parent) for child, parent in enumerate(self.parents) if parent >= 0)

    def index(self, joint_name: str) -> int:
        try:
            return self.joint_names.index(joint_name)
        except ValueError:
            raise KeyError(f"skeleton {self.name} has no joint {joint_name!r}; joints: {self.joint_names}") from None

    def flip_permutation(self) -> np.ndarray:
        """Joint permutation that swaps every left/right pair (for mirroring augmentation)."""
        permutation = np.arange(self.num_joints)
        for left, right in self.left_right_pairs:
            permutation[left], permutation[right] = right, left
        return permutation


H36M_17 = Skeleton(
    name="h36m17",
    joint_names=(
        "Hip", "RHip", "RKnee", "RFoot", "LHip", "LKnee", "LFoot", "Spine", "Thorax", "Neck/Nose",
        "Head", "LShoulder", "LElbow", "LWrist", "RShoulder", "RElbow", "RWrist",
    ),
    parents=(-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 9, 8, 11, 12, 8, 14, 15),
    left_right_pairs=((4, 1), (5, 2), (6, 3), (11, 14), (12, 15), (13, 16)),
)

# Indices of H36M_17's joints in the 32-joint Human3.6M mocap layout (docs/conventions.md).
H36M_32_TO_17 = (0, 1, 2, 3, 6, 7, 8, 12, 13, 14, 15, 17, 18, 19, 25, 26, 27)

# The Stacked Hourglass detections of Martinez et al. in our order: H36M_17 without the nose.
H36M_16 = Skeleton(
    name="h36m16",
    joint_names=(
        "Hip", "RHip", "RKnee", "RFoot", "LHip", "LKnee", "LFoot", "Spine", "Thorax", "Head",
        "LShoulder", "LElbow", "LWrist", "RShoulder", "RElbow", "RWrist",
    ),
    parents=(-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 8, 10, 11, 8, 13, 14),
    left_right_pairs=((4, 1), (5, 2), (6, 3), (10, 13), (11, 14), (12, 15)),
)

# HumanEva-I, the 15 joints of the VideoPose3D "humaneva15" layout (root = pelvis).
HUMANEVA_15 = Skeleton(
    name="humaneva15",
    joint_names=(
        "Pelvis", "Thorax", "LShoulder", "LElbow", "LWrist", "RShoulder", "RElbow", "RWrist",
        "LHip", "LKnee", "LAnkle", "RHip", "RKnee", "RAnkle", "Head",
    ),
    parents=(-1, 0, 1, 2, 3, 1, 5, 6, 0, 8, 9, 0, 11, 12, 1),
    left_right_pairs=((2, 5), (3, 6), (4, 7), (8, 11), (9, 12), (10, 13)),
)

# MPI-INF-3DHP's 17 evaluation joints, re-ordered so that joint k corresponds to H36M_17 joint k
# (pelvis first; 3DHP "neck" ~ H36M thorax, 3DHP "head" ~ H36M neck/nose, "head_top" ~ H36M head).
MPI_INF_3DHP_17 = Skeleton(
    name="mpi_inf_3dhp17",
    joint_names=(
        "Pelvis", "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "Spine", "Neck", "Head",
        "HeadTop", "LShoulder", "LElbow", "LWrist", "RShoulder", "RElbow", "RWrist",
    ),
    parents=H36M_17.parents,
    left_right_pairs=H36M_17.left_right_pairs,
)

# COCO-17 detector layout.  Its joint 0 is the nose, so it is a source format for
# `jaxpose.layouts`, not a lifting skeleton; the tree below is rooted at the nose.
COCO_17 = Skeleton(
    name="coco17",
    joint_names=(
        "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
        "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip",
        "left_knee", "right_knee", "left_ankle", "right_ankle",
    ),
    parents=(-1, 0, 0, 1, 2, 0, 0, 5, 6, 7, 8, 5, 6, 11, 12, 13, 14),
    left_right_pairs=((1, 2), (3, 4), (5, 6), (7, 8), (9, 10), (11, 12), (13, 14), (15, 16)),
)


@dataclasses.dataclass(frozen=True)
class DetectorLayout:
    """A 2D detector's keypoint order, and the lifting skeleton made of the detector's own joints.

    A lifter trained on a user's rig (`experiments.rig`) lifts the detector's keypoints as they are,
    rather than converting them to a mocap skeleton: nothing is invented, and a self-supervised lifter
    learns the detector's joint definitions anyway.  Its skeleton (`lifting_skeleton`, named
    "<layout>_lifting") has the layout's `root` first, then the other keypoints in the detector's
    order.  Where the detector has no pelvis, the root is derived: the midpoint of `root_from`
    (the two hips), named `root`.
    """

    name: str
    joint_names: tuple[str, ...]
    root: str
    """The lifting root: a joint of the layout (its mid-hip), or the name of the derived one."""
    parents: tuple[tuple[str, str], ...]
    """(child, parent) by name for every joint of the lifting skeleton but the root."""
    root_from: tuple[str, str] | None = None
    """The two hips whose midpoint is the root, for a layout without a mid-hip keypoint."""

    @property
    def lifting_skeleton(self) -> Skeleton:
        names = (self.root, *(name for name in self.joint_names if name != self.root))
        parent_of = dict(self.parents)
        missing = [name for name in names[1:] if name not in parent_of]
        if missing:
            raise ValueError(f"layout {self.name}: no parent for {missing}")
        pairs = []
        for left in names:
            right = _mirror_name(left)
            if right != left and right in names and left.lower().startswith("l"):
                pairs.append((names.index(left), names.index(right)))
        return Skeleton(
            name=f"{self.name}_lifting",
            joint_names=names,
            parents=(-1, *(names.index(parent_of[name]) for name in names[1:])),
            left_right_pairs=tuple(pairs),
        )


def _mirror_name(name: str) -> str:
    """The joint on the other side: LEye <-> REye, left_eye <-> right_eye; other names unchanged."""
    for left, right in (("left_", "right_"), ("L", "R")):
        if name.startswith(left):
            return right + name[len(left):]
        if name.startswith(right):
            return left + name[len(right):]
    return name


def _tree(*chains: str) -> tuple[tuple[str, str], ...]:
    """(child, parent) pairs from chains written "parent>child>grandchild"."""
    pairs = []
    for chain in chains:
        names = chain.split(">")
        pairs += [(child, parent) for parent, child in zip(names, names[1:])]
    return tuple(pairs)


def _limbs(prefix_left: str, prefix_right: str, root: str, neck: str, names: dict[str, str]) -> tuple[str, ...]:
    """The arm and leg chains of both sides, for layouts whose limb joints follow one naming scheme."""
    chains = []
    for side in (prefix_left, prefix_right):
        chains.append(f"{root}>{side}{names['hip']}>{side}{names['knee']}>{side}{names['ankle']}")
        chains.append(f"{neck}>{side}{names['shoulder']}>{side}{names['elbow']}>{side}{names['wrist']}")
    return tuple(chains)


_OPENPOSE_LIMBS = {"hip": "Hip", "knee": "Knee", "ankle": "Ankle", "shoulder": "Shoulder", "elbow": "Elbow", "wrist": "Wrist"}
_COCO_LIMBS = {"hip": "hip", "knee": "knee", "ankle": "ankle", "shoulder": "shoulder", "elbow": "elbow", "wrist": "wrist"}
_OPENPOSE_FEET = ("LAnkle>LBigToe>LSmallToe", "LAnkle>LHeel", "RAnkle>RBigToe>RSmallToe", "RAnkle>RHeel")
_OPENPOSE_FACE = ("Nose>LEye>LEar", "Nose>REye>REar")

COCO_17_LAYOUT = DetectorLayout(
    name="coco17",
    joint_names=COCO_17.joint_names,
    root="pelvis",
    root_from=("left_hip", "right_hip"),
    # COCO has no neck: the shoulders and the head hang from the pelvis (drawing only).
    parents=_tree(
        *_limbs("left_", "right_", "pelvis", "pelvis", _COCO_LIMBS),
        "pelvis>nose>left_eye>left_ear", "nose>right_eye>right_ear",
    ),
)
# OpenPose's COCO model (18 keypoints, 54 values per person).
COCO_18_LAYOUT = DetectorLayout(
    name="coco18",
    joint_names=(
        "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "RHip", "RKnee",
        "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar",
    ),
    root="MidHip",
    root_from=("LHip", "RHip"),
    parents=_tree(*_limbs("L", "R", "MidHip", "Neck", _OPENPOSE_LIMBS), "MidHip>Neck>Nose", *_OPENPOSE_FACE),
)
BODY_25_LAYOUT = DetectorLayout(
    name="body25",
    joint_names=(
        "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "MidHip",
        "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar",
        "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel",
    ),
    root="MidHip",
    parents=_tree(
        *_limbs("L", "R", "MidHip", "Neck", _OPENPOSE_LIMBS), "MidHip>Neck>Nose", *_OPENPOSE_FACE, *_OPENPOSE_FEET
    ),
)
# OpenPose's experimental BODY_25B (Pose2Sim's default): COCO-like order, then neck, head top and feet.
# Also 75 values per person, so it cannot be told from BODY_25 by the count.
BODY_25B_LAYOUT = DetectorLayout(
    name="body25b",
    joint_names=(
        "Nose", "LEye", "REye", "LEar", "REar", "LShoulder", "RShoulder", "LElbow", "RElbow", "LWrist",
        "RWrist", "LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle", "Neck", "HeadTop",
        "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel",
    ),
    root="MidHip",
    root_from=("LHip", "RHip"),
    parents=_tree(
        *_limbs("L", "R", "MidHip", "Neck", _OPENPOSE_LIMBS), "MidHip>Neck>HeadTop", "Neck>Nose", *_OPENPOSE_FACE,
        *_OPENPOSE_FEET,
    ),
)
# HALPE-26 (AlphaPose, RTMPose): COCO-17's keypoints under OpenPose-style names, then head top, neck,
# a mid-hip ("Hip") and the feet.
HALPE_26_LAYOUT = DetectorLayout(
    name="halpe26",
    joint_names=(
        "Nose", "LEye", "REye", "LEar", "REar", "LShoulder", "RShoulder", "LElbow", "RElbow", "LWrist",
        "RWrist", "LHip", "RHip", "LKnee", "RKnee", "LAnkle", "RAnkle", "Head", "Neck", "Hip",
        "LBigToe", "RBigToe", "LSmallToe", "RSmallToe", "LHeel", "RHeel",
    ),
    root="Hip",
    parents=_tree(
        *_limbs("L", "R", "Hip", "Neck", _OPENPOSE_LIMBS), "Hip>Neck>Head", "Neck>Nose", *_OPENPOSE_FACE,
        *_OPENPOSE_FEET,
    ),
)

DETECTOR_LAYOUTS: dict[str, DetectorLayout] = {
    layout.name: layout for layout in (COCO_17_LAYOUT, COCO_18_LAYOUT, BODY_25_LAYOUT, BODY_25B_LAYOUT, HALPE_26_LAYOUT)
}

SKELETONS: dict[str, Skeleton] = {
    s.name: s
    for s in (
        H36M_17, H36M_16, HUMANEVA_15, MPI_INF_3DHP_17, COCO_17,
        *(layout.lifting_skeleton for layout in DETECTOR_LAYOUTS.values()),
    )
}  # fmt: skip


def get_skeleton(name: str) -> Skeleton:
    try:
        return SKELETONS[name]
    except KeyError:
        raise KeyError(f"unknown skeleton {name!r}; known: {sorted(SKELETONS)}") from None
