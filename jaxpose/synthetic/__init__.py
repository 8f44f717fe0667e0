"""Procedural multi-view human-motion data: the project's embedded default data set.

Real data sets cannot be downloaded here, so this package simulates one that has the structure the
method relies on: a kinematic skeleton with per-subject bone lengths, joint angles inside anatomical
limits that move smoothly in several motion families, a calibrated Human3.6M-like camera room, and a
2D detector with joint-dependent noise, gross outliers, left/right swaps and missing joints.

Conventions (docs/conventions.md): world z up, floor at z = 0, millimetres; cameras
`x_cam = R @ x_world + t` with the image y axis pointing down; detections in pixels.  The body frame
has x forward, y to the subject's left, z up.  Joint angles are in degrees, columns `ANGLE_NAMES`;
left and right limbs use the same anatomical angle (the right side is mirrored in the kinematics),
so `JOINT_LIMITS_DEG` holds one range per anatomical angle.

Everything is numpy and vectorized over time; randomness comes from generators keyed by
(seed, stream, subject), so one subject's motion, a rig or the detector can be regenerated alone.

The modules, in the order the data is made: `config` (what to simulate, random streams), `body`,
`motion`, `rig`, `detector`, `dataset` (`generate`); `project` writes an example rig project (a
calibration file, OpenPose JSON frames, ground truth) from them, with `capture` (what the example
simulates: its config, rig, passer-by and detector) and `keypoints` (a detector's keypoints on the
body).  Their public names are re-exported here.  `mocap` (imported from its module) gives real motion
capture (CMU BVH takes) as COCO-17 or H36M_17 keypoints.
"""

import importlib

from jaxpose.synthetic.body import (
    ANGLE_NAMES,
    JOINT_LIMITS_DEG,
    NOMINAL_BONE_MM,
    angle_limits,
    forward_kinematics,
    sample_bone_lengths,
)
from jaxpose.synthetic.config import SyntheticConfig
from jaxpose.synthetic.dataset import generate
from jaxpose.synthetic.detector import DETECTOR_SIGMA_PX, SimulatedDetections, detector_sigma, simulate_detector
from jaxpose.synthetic.motion import ANKLE_HEIGHT_MM, MOTION_FAMILIES, Motion, SubjectMotion, sample_motion, simulate_subject
from jaxpose.synthetic.rig import make_rig, project_points

__all__ = [
    "ANGLE_NAMES", "ANKLE_HEIGHT_MM", "DETECTOR_SIGMA_PX", "JOINT_LIMITS_DEG", "MOTION_FAMILIES", "NOMINAL_BONE_MM",
    "Motion", "ExampleProjectConfig", "SimulatedDetections", "SubjectMotion", "SyntheticConfig", "angle_limits",
    "detector_sigma", "forward_kinematics", "generate", "keypoints3d", "make_rig", "project_points",
    "rig_calibration", "sample_bone_lengths", "sample_motion", "simulate_detector", "simulate_subject",
    "write_rig_project",
]  # fmt: skip

# The example project's names are imported on first use (PEP 562), so that `python -m
# jaxpose.synthetic.project` does not find its module already imported by this package, and the
# simulator alone does not import the calibration formats.
_EXAMPLE_NAMES = {
    "ExampleProjectConfig": "capture", "rig_calibration": "capture", "keypoints3d": "keypoints",
    "write_rig_project": "project",
}  # fmt: skip


def __getattr__(name: str):
    if name in _EXAMPLE_NAMES:
        return getattr(importlib.import_module(f"jaxpose.synthetic.{_EXAMPLE_NAMES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
