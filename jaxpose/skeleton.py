"""Joint sets as data: names, kinematic parents and left/right pairs.

Every lifting skeleton has its root (the pelvis) at joint 0; nothing in the library branches on a
skeleton's name, so a new joint set is one more `Skeleton(...)` value.  `COCO_17` is a detector
layout, not a lifting skeleton: convert it (and OpenPose BODY_25) with `jaxpose.keypoint_formats`
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
# `jaxpose.keypoint_formats`, not a lifting skeleton; the tree below is rooted at the nose.
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

SKELETONS: dict[str, Skeleton] = {s.name: s for s in (H36M_17, H36M_16, HUMANEVA_15, MPI_INF_3DHP_17, COCO_17)}


def get_skeleton(name: str) -> Skeleton:
    try:
        return SKELETONS[name]
    except KeyError:
        raise KeyError(f"unknown skeleton {name!r}; known: {sorted(SKELETONS)}") from None
