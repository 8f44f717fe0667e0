"""The embedded example rig project: a complete multi-camera recording project written from the simulator.

`write_rig_project(root, config)` writes what a user of `python -m experiments.rig --data.root PROJECT`
brings, so that the rig experiment runs with no download and the tests can drive the whole path::

    PROJECT/
      calibration.toml            the rig, Anipose/Pose2Sim layout, translations in metres
      <recording>/                one folder per recording (a motion family: walking01, reaching02, ...)
        <camera>_json/            OpenPose JSON frames <recording>_<camera>_<frame:012d>_keypoints.json
        ground_truth.npz          points3d f32[N, J', 3] world mm, frames int64[N], joint_names str[J']
      example_truth.json          what was simulated, for tests (see `write_rig_project`)

What is simulated, and how it mirrors real captures:
- One person (one body) seen by one rig (`make_rig`: cameras on a circle around the capture area) in
  every recording; each recording is one motion family (`sample_motion`) with its own random stream.
  The lenses get mild OpenCV-model distortion (k1 barrel, small k2, p1, p2; k3 = 0), which the
  detections include and the calibration file states.
- Keypoints in a detector's layout, COCO-17 or OpenPose BODY_25, not the simulator's H36M_17: joints
  the body has are used as they are (a detector's hips are taken to be Human3.6M's hip joints, the
  ankles its "Foot" joints); BODY_25's MidHip and Neck are the hips' and shoulders' midpoints; the
  face and feet points are rigid offsets in a head frame and in foot frames built from the body's
  joints (`_HEAD_POINTS_MM`, `_FOOT_POINTS_MM`), so every keypoint has a true 3D position.
- The detector: `simulate_detector`'s noise, gross outliers, missing joints and confidences, each
  keypoint with the noise of its nearest body joint (`_SIGMA_JOINT`); confidences are then scaled down
  for the noisier joints.  Left/right swaps exchange a whole view's left and right keypoints and keep
  their (high) scores, as real detectors are confident in a swap.  Keypoints whose true position is
  outside an image (or detected outside it) are not detected; undetected keypoints are written
  0, 0, 0 as OpenPose does, and a person with fewer than `MIN_KEYPOINTS` detected keypoints in a view
  is not listed in that view.
- A second person (another body) walks past behind one of the cameras in about `second_person_rate`
  of each recording's frames: the camera it walks behind never sees it, the camera opposite sees it
  small in the background, those beside it at most at an image's edge.  Where a camera sees both,
  the passer-by is listed first in about `second_person_first_rate` of the frames.
- One camera out of sync: its file numbered f holds the instant of the other cameras' frame
  f + `desync_frames` (it started late for a positive offset); every camera's files are numbered
  0 .. frames_per_recording - 1.

Every random draw comes from generators keyed by (seed, stream, recording, ...), so a seed and a
config write the same project byte for byte.  numpy throughout, jax only to project.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import shutil
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from jaxpose.camera import Cameras, project_from_camera, undistort_points, world_to_camera
from jaxpose.formats.anipose_toml import write_anipose_toml
from jaxpose.formats.calibrated_rig import RigCalibration
from jaxpose.formats.rig_folder import CALIBRATION_TOML, GROUND_TRUTH_NPZ, json_folder, write_ground_truth
from jaxpose.synthetic.body import JOINT_INDEX, NOMINAL_BONE_MM, axis_rotation, sample_bone_lengths
from jaxpose.synthetic.config import Stream, SyntheticConfig, stream_rng
from jaxpose.synthetic.detector import DETECTOR_SIGMA_PX, simulate_detector
from jaxpose.synthetic.motion import MOTION_FAMILIES, sample_motion
from jaxpose.synthetic.rig import make_rig
from jaxpose.layouts import OPENPOSE_25_JOINT_NAMES
from jaxpose.skeleton import COCO_17, H36M_17

__all__ = [
    "EXAMPLE_TRUTH_JSON", "MIN_KEYPOINTS", "ExampleProjectConfig", "keypoints3d", "layout_names", "main", "rig_calibration",
    "write_rig_project",
]  # fmt: skip

EXAMPLE_TRUTH_JSON = "example_truth.json"
# A view's detection of a person is written only with at least this many detected keypoints.
MIN_KEYPOINTS = 5
# example_truth.json's frame lists, per recording and camera (in the camera's file numbers).
_FRAME_LISTS = ("second_person_frames", "second_person_first_frames", "subject_undetected_frames")


@dataclasses.dataclass(frozen=True)
class ExampleProjectConfig:
    """An example rig project written from the synthetic generator (lengths mm, image quantities px)."""

    layout: Literal["coco17", "body25"] = "coco17"
    """Keypoint layout of the OpenPose JSON files: coco17 (COCO's 17 keypoints, 51 values per person)
    or body25 (OpenPose BODY_25, 75 values per person)."""
    recordings: int = 3
    """Number of recordings (one folder each) of the same person, each a different motion."""
    frames_per_recording: int = 600
    """Frames of each recording, per camera."""
    fps: float = 50.0
    """Frame rate of the cameras, frames per second."""
    cameras: int = 4
    """Number of cameras of the rig (at least 2), named cam01, cam02, ..."""
    seed: int = 0
    """Random seed: one seed and one config write the same project, byte for byte."""
    motions: tuple[str, ...] = (
        "walking", "reaching", "crouching", "gesturing", "turning", "sitting", "waving", "bending",
    )  # fmt: skip
    """Motion family of each recording in turn (cycled when there are more recordings); known families:
    walking, turning, sitting, crouching, reaching, waving, gesturing, bending."""
    desync_camera: int = 2
    """Index (from 0) of the camera that is out of sync; -1 keeps every camera in sync."""
    desync_frames: int = 3
    """How far that camera is out of sync: its file numbered f holds the instant of the other
    cameras' frame f + this many frames (positive: it started late)."""
    second_person_rate: float = 0.15
    """Fraction of each recording's frames during which a second person walks past behind one of the
    cameras (0 = never)."""
    second_person_first_rate: float = 0.5
    """Where a camera sees both people, the chance that the passer-by is listed first in that frame."""
    image_size: tuple[int, int] = (1920, 1080)
    """Width and height of the cameras' images, pixels."""
    focal_length: float = 1200.0
    """Focal length in pixels, jittered a few percent per camera."""
    distortion: bool = True
    """Give the lenses mild OpenCV-model distortion (barrel k1, small k2, p1, p2); off = pinhole cameras."""
    camera_distance: tuple[float, float] = (4000.0, 5500.0)
    """Range of the cameras' distances from the room centre, mm."""
    camera_height: tuple[float, float] = (1200.0, 2000.0)
    """Range of the cameras' heights above the floor, mm."""
    capture_area: float = 3000.0
    """Side of the square (mm) in which the person moves, centred in the camera circle."""
    noise_sigma_scale: float = 1.0
    """Multiplies the detector's per-joint noise (3-8 px standard deviation per axis)."""
    outlier_rate: float = 0.02
    """Fraction of keypoint detections displaced by a gross error (30-150 px)."""
    swap_rate: float = 0.01
    """Fraction of a person's detections in one view with left and right exchanged."""
    missing_rate: float = 0.01
    """Fraction of keypoint detections missing at random (besides those outside the image)."""

    def __post_init__(self):
        if self.recordings < 1 or self.frames_per_recording < 10:
            raise ValueError("need at least one recording of at least 10 frames")
        if self.fps <= 0.0:
            raise ValueError(f"fps must be positive, got {self.fps}")
        if not -1 <= self.desync_camera < self.cameras:
            raise ValueError(
                f"desync_camera must be -1 or a camera index below {self.cameras}, got {self.desync_camera}"
            )
        if abs(self.desync_frames) >= self.frames_per_recording // 2:
            raise ValueError(f"desync_frames {self.desync_frames} must be smaller than half a recording")
        for name in ("second_person_rate", "second_person_first_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)}")
        unknown = [motion for motion in self.motions if motion not in MOTION_FAMILIES]
        if not self.motions or unknown:
            raise ValueError(f"motions must name motion families of {MOTION_FAMILIES}, got {self.motions}")
        if min(self.image_size) < 16:
            raise ValueError(f"image_size {self.image_size} is too small")
        self.synthetic_config()  # SyntheticConfig checks the rest (cameras, rates, the room's geometry)

    def synthetic_config(self) -> SyntheticConfig:
        """The simulator's config for this project (one subject, this rig and detector)."""
        return SyntheticConfig(
            num_train_subjects=1,
            num_test_subjects=0,
            samples_per_subject=self.frames_per_recording,
            num_views=self.cameras,
            fps=self.fps,
            image_size=tuple(self.image_size),
            focal_length=self.focal_length,
            camera_distance=tuple(self.camera_distance),
            camera_height=tuple(self.camera_height),
            capture_area=self.capture_area,
            noise_sigma_scale=self.noise_sigma_scale,
            outlier_rate=self.outlier_rate,
            swap_rate=self.swap_rate,
            missing_rate=self.missing_rate,
            seed=self.seed,
        )

    @property
    def camera_names(self) -> tuple[str, ...]:
        return tuple(f"cam{c + 1:02d}" for c in range(self.cameras))

    @property
    def recording_names(self) -> tuple[str, ...]:
        return tuple(f"{self.motion(r)}{r + 1:02d}" for r in range(self.recordings))

    def motion(self, recording: int) -> str:
        return self.motions[recording % len(self.motions)]

    def frame_offsets(self) -> np.ndarray:
        """int[C]: camera c's file f holds the instant of the synchronized cameras' frame f + offset[c]."""
        offsets = np.zeros(self.cameras, np.int64)
        if self.desync_camera >= 0:
            offsets[self.desync_camera] = self.desync_frames
        return offsets


class _Stream(enum.IntEnum):
    """This module's random streams, numbered after `jaxpose.synthetic.config.Stream`'s so that
    no generator is shared with the simulator's own."""

    LENS = 10
    MOTION = 11
    PASSER_BY = 12
    DETECTOR = 13
    SWAP = 14
    ORDER = 15


def _rng(config: ExampleProjectConfig, stream: _Stream, *key: int) -> np.random.Generator:
    return np.random.default_rng([config.seed, int(stream), *key])


# ----------------------------------------------------------------------------------------------
# Keypoints: names, 3D positions, detector noise

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
_SIGMA_JOINT = {
    "Nose": "Neck/Nose", "Neck": "Thorax", "MidHip": "Hip",
    **{f"{side}{point}": "Head" for side in "LR" for point in ("Eye", "Ear")},
    **{f"{side}{point}": f"{side}Foot" for side in "LR" for point in ("BigToe", "SmallToe", "Heel")},
    **_BODY_JOINT,
}  # fmt: skip
# Confidence scale of a keypoint: (the body's smallest sigma / its sigma) ** this: noisy joints score lower.
_SCORE_SIGMA_EXPONENT = 0.25


def _openpose_name(coco_name: str) -> str:
    """COCO's "left_shoulder" -> OpenPose's "LShoulder"; "nose" -> "Nose"."""
    for prefix, side in (("left_", "L"), ("right_", "R")):
        if coco_name.startswith(prefix):
            return side + coco_name[len(prefix) :].capitalize()
    return coco_name.capitalize()


def _mirror(name: str) -> str:
    """OpenPose name of the keypoint on the other side ("LEye" <-> "REye"); midline names unchanged."""
    if name[:1] in ("L", "R") and name[1:2].isupper():
        return {"L": "R", "R": "L"}[name[0]] + name[1:]
    return name


def layout_names(layout: str) -> tuple[str, ...]:
    """The keypoint names written for `layout`, in the file's order."""
    return {"coco17": COCO_17.joint_names, "body25": OPENPOSE_25_JOINT_NAMES}[layout]


def _layout_openpose_names(layout: str) -> tuple[str, ...]:
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
    for side, mirror in (("L", 1.0), ("R", -1.0)):
        shank_down = _unit(joint[f"{side}Foot"] - joint[f"{side}Knee"])
        forward = _unit(np.cross(shank_down, pelvis_left))
        forward = _unit(forward - (1.0 - _FOOT_TILT_SHARE) * (forward @ z)[:, None] * z)
        forward = forward @ axis_rotation(2, np.array(mirror * _TOE_OUT_DEG)).T
        foot_up = _unit(z - (forward @ z)[:, None] * forward)
        foot = np.stack([forward, np.cross(foot_up, forward), foot_up], axis=-1)
        scale = bone_lengths[JOINT_INDEX[f"{side}Foot"]] / NOMINAL_BONE_MM[f"{side}Foot"]
        for point, (ahead, left, above) in _FOOT_POINTS_MM.items():
            # Lengths scale with the body; heights not: the simulator's ankle height is the same for all.
            points[side + point] = joint[f"{side}Foot"] + foot @ np.array([scale * ahead, scale * mirror * left, above])
    return np.stack([points[name] for name in _layout_openpose_names(layout)], axis=1)


def _ground_truth_names(layout: str) -> tuple[str, ...]:
    """The written keypoints plus the root: COCO has none, so "pelvis" (the hips' midpoint) is added."""
    return layout_names(layout) + (("pelvis",) if layout == "coco17" else ())


# ----------------------------------------------------------------------------------------------
# The rig


def rig_calibration(config: ExampleProjectConfig = ExampleProjectConfig()) -> RigCalibration:
    """The example project's rig as `calibration.toml` holds it: float64 `Cameras` [C] (t mm, OpenCV
    distortion), image sizes, camera names.

    The simulator's room (`make_rig` on the config's seed) with its rotations made exactly orthonormal
    in float64, so that the file (Rodrigues vectors) reproduces the projections that made the
    detections; with `config.distortion`, mild lens distortion per camera from the LENS stream.
    """
    synthetic = config.synthetic_config()
    room = make_rig(stream_rng(synthetic, Stream.ROOM), synthetic)
    u, _, vt = np.linalg.svd(np.asarray(room.R, np.float64))
    R = u @ vt
    C = config.cameras
    dist = None
    if config.distortion:
        rng = _rng(config, _Stream.LENS)
        dist = np.zeros((C, 5))
        dist[:, 0] = rng.uniform(-0.08, -0.02, C)  # barrel, as most wide-ish lenses
        dist[:, 1] = rng.uniform(-0.01, 0.04, C)
        dist[:, 2:4] = rng.normal(0.0, 3e-4, (C, 2))
    cameras = Cameras(
        K=np.asarray(room.K, np.float64), R=R, t=np.asarray(room.t, np.float64), dist=dist, distortion_model="opencv"
    )
    return RigCalibration(
        camera_names=config.camera_names,
        cameras=cameras,
        image_size=np.tile(np.asarray(config.image_size, np.int64), (C, 1)),
        source=f"jaxpose.synthetic.project (seed {config.seed})",
        unit="m",
    )


@jax.jit
def _project_jit(cameras: Cameras, points: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    points_camera = world_to_camera(cameras, points[:, None])  # [T, C, K, 3]
    depth = points_camera[..., 2]
    radius2 = jnp.sum((points_camera[..., :2] / jnp.maximum(depth, 1.0)[..., None]) ** 2, -1)
    return project_from_camera(cameras, points_camera), depth, radius2


def _project(cameras: Cameras, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points f[T, K, 3] -> (pixels f64[T, C, K, 2], depth f64[T, C, K] mm, the squared radius
    f64[T, C, K] of the undistorted normalized image point), in float64 through `jaxpose.camera`."""
    with jax.enable_x64(True):
        rig = jax.tree.map(lambda field: jnp.asarray(field, jnp.float64), cameras)
        return tuple(np.asarray(array) for array in _project_jit(rig, jnp.asarray(points, jnp.float64)))


def _field_radius2(cameras: Cameras, image_size: tuple[int, int]) -> np.ndarray:
    """f64[C] squared undistorted normalized radius of each image's farthest corner, plus 10%: points
    farther off the axis are outside the lens' field (where a barrel model would fold them back in)."""
    width, height = image_size
    corners = np.array([[0.0, 0.0], [width, 0.0], [0.0, height], [width, height]])
    with jax.enable_x64(True):
        rig = jax.tree.map(lambda field: jnp.asarray(field, jnp.float64), cameras)
        pixels = undistort_points(rig, jnp.broadcast_to(jnp.asarray(corners), (len(cameras.K), 4, 2)))
        K = rig.K
        x = (pixels[..., 0] - K[:, None, 0, 2]) / K[:, None, 0, 0]
        y = (pixels[..., 1] - K[:, None, 1, 2]) / K[:, None, 1, 1]
        return 1.1**2 * np.asarray(jnp.max(x * x + y * y, axis=-1))


# ----------------------------------------------------------------------------------------------
# Bodies, motions, detections


@dataclasses.dataclass(frozen=True)
class _Person:
    """One person's keypoints over a recording's instants and their detection in every camera."""

    points: np.ndarray  # f64[T, K, 3] world mm (NaN where the person is not in the scene)
    keypoints: np.ndarray  # f64[T, C, K, 2] px, 0 where not detected
    scores: np.ndarray  # f64[T, C, K] in (0, 1], 0 where not detected
    listed: np.ndarray  # bool[T, C] the view's detection is written


def _passer_by_poses(
    config: ExampleProjectConfig, rig: Cameras, recording: int, instants: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """The second person's H36M_17 poses f64[E, 17, 3] walking straight past behind one camera, its
    bone lengths, and the first instant (index) of its E-instant passage."""
    synthetic = config.synthetic_config()
    rng = _rng(config, _Stream.PASSER_BY, recording)
    bones = sample_bone_lengths(stream_rng(synthetic, Stream.BODY, 1))
    length = int(np.clip(round(config.second_person_rate * instants), 2, instants))
    start = int(rng.integers(0, instants - length + 1))
    walk = sample_motion(rng, "walking", bones, length, synthetic).poses.astype(np.float64)
    # Re-lay the walk along a straight line: keep its stride (arc length) and its pelvis' sway.
    root = walk[:, 0]
    step = np.gradient(root[:, :2], axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(root[:, :2], axis=0), axis=1))])
    camera = int(rng.integers(config.cameras))
    centre = -np.asarray(rig.R[camera]).T @ np.asarray(rig.t[camera])
    outward = _unit(centre[:2])
    across = np.array([-outward[1], outward[0]]) * rng.choice([-1.0, 1.0])
    distance = np.linalg.norm(centre[:2]) + rng.uniform(800.0, 2000.0)  # behind that camera
    start_xy = outward * distance + across * (rng.uniform(-1500.0, 1500.0) - arc[-1] / 2.0)
    turn = np.degrees(np.arctan2(across[1], across[0]) - np.arctan2(step[:, 1], step[:, 0]))
    relative = np.einsum("tij,tkj->tki", axis_rotation(2, turn), walk - root[:, None])
    path = np.concatenate([start_xy + arc[:, None] * across, root[:, 2:]], axis=1)
    return relative + path[:, None], bones, start


def _detect(
    config: ExampleProjectConfig,
    rig: RigCalibration,
    field_radius2: np.ndarray,
    points: np.ndarray,
    key: Sequence[int],
) -> _Person:
    """Detect keypoints f64[T, K, 3] (NaN rows: absent) in every camera as the simulated detector would."""
    synthetic = dataclasses.replace(config.synthetic_config(), swap_rate=0.0)  # swaps below, per layout
    names = _layout_openpose_names(config.layout)
    T, K, _ = points.shape
    present = np.isfinite(points).all(axis=(1, 2))
    clean, depth, radius2 = _project(rig.cameras, np.where(present[:, None, None], points, 0.0))
    width, height = config.image_size

    def inside(pixels: np.ndarray) -> np.ndarray:
        return (pixels[..., 0] >= 0.0) & (pixels[..., 0] < width) & (pixels[..., 1] >= 0.0) & (pixels[..., 1] < height)

    visible = present[:, None, None] & (depth > 100.0) & (radius2 < field_radius2[:, None]) & inside(clean)
    # simulate_detector works on H36M_17 arrays: each keypoint goes to the slot of its nearest body
    # joint (whose noise it gets), over as many passes as one joint has keypoints (4: the eyes and ears,
    # or an ankle and its foot points).
    slots = [H36M_17.joint_names.index(_SIGMA_JOINT[name]) for name in names]
    passes: list[dict[int, int]] = []
    for k, slot in enumerate(slots):
        free = next((p for p in passes if slot not in p), None)
        if free is None:
            passes.append(free := {})
        free[slot] = k
    detected = np.zeros((T, config.cameras, K, 2))
    confidence = np.zeros((T, config.cameras, K))
    missing = np.zeros((T, config.cameras, K), bool)
    for index, assignment in enumerate(passes):
        packed = np.zeros((T, config.cameras, H36M_17.num_joints, 2))
        slot_list, keypoint_list = list(assignment), list(assignment.values())
        packed[:, :, slot_list] = clean[:, :, keypoint_list]
        result = simulate_detector(_rng(config, _Stream.DETECTOR, *key, index), packed, synthetic)
        detected[:, :, keypoint_list] = result.keypoints2d[:, :, slot_list]
        confidence[:, :, keypoint_list] = result.confidence[:, :, slot_list]
        missing[:, :, keypoint_list] = result.missing[:, :, slot_list]
    sigma = np.array([DETECTOR_SIGMA_PX[_SIGMA_JOINT[name]] for name in names])
    confidence = confidence * (min(DETECTOR_SIGMA_PX.values()) / sigma) ** _SCORE_SIGMA_EXPONENT
    missing |= ~visible
    # Whole-view left/right swaps: the detector confidently labels the left keypoints right and back.
    flip = np.array([names.index(_mirror(name)) for name in names])
    swapped = _rng(config, _Stream.SWAP, *key).random((T, config.cameras)) < config.swap_rate
    for array in (detected, confidence, missing):
        array[swapped] = array[swapped][:, flip]
    missing |= ~inside(detected)
    detected[missing] = 0.0
    confidence[missing] = 0.0
    listed = present[:, None] & ((~missing).sum(-1) >= MIN_KEYPOINTS)
    return _Person(points=points, keypoints=detected, scores=confidence, listed=listed)


# ----------------------------------------------------------------------------------------------
# Files


def _format_value(value: float) -> str:
    """A number as OpenPose writes it: 6 significant digits, shortest form ("505.232", "0.664216", "0")."""
    return f"{value:.6g}"


def _person_json(keypoints: np.ndarray, scores: np.ndarray) -> str:
    """One `people` entry, compact, in OpenPose's key order; undetected keypoints are 0,0,0."""
    values = []
    for (x, y), score in zip(keypoints.tolist(), scores.tolist()):
        values.append("0,0,0" if score <= 0.0 else f"{_format_value(x)},{_format_value(y)},{_format_value(score)}")
    return (
        '{"person_id":[-1],"pose_keypoints_2d":[' + ",".join(values) + '],"face_keypoints_2d":[],'
        '"hand_left_keypoints_2d":[],"hand_right_keypoints_2d":[],"pose_keypoints_3d":[],'
        '"face_keypoints_3d":[],"hand_left_keypoints_3d":[],"hand_right_keypoints_3d":[]}'
    )


def _clear_previous(root: Path) -> None:
    """Remove an earlier example project at `root` (only what its truth file lists); refuse to write
    into any other non-empty folder."""
    truth_path = root / EXAMPLE_TRUTH_JSON
    if not truth_path.exists():
        if root.exists() and any(root.iterdir()):
            raise FileExistsError(
                f"{root} is not empty and holds no example project ({EXAMPLE_TRUTH_JSON}); choose an empty folder"
            )
        return
    try:
        previous = json.loads(truth_path.read_text())["recordings"]
    except (ValueError, KeyError, TypeError):
        raise FileExistsError(f"{truth_path} is not an example project's truth file; choose an empty folder") from None
    for name in previous:
        if isinstance(name, str) and Path(name).name == name and name not in (".", "..") and (root / name).is_dir():
            shutil.rmtree(root / name)
    (root / CALIBRATION_TOML).unlink(missing_ok=True)
    truth_path.unlink()


def _write_camera(
    folder: Path,
    prefix: str,
    rows: np.ndarray,
    subject: _Person,
    passer: _Person | None,
    passer_first: np.ndarray,
    c: int,
) -> dict[str, list[int]]:
    """Write camera c's frame files (file f holds instant index rows[f]); returns its `_FRAME_LISTS`."""
    folder.mkdir(parents=True)
    lists: dict[str, list[int]] = {key: [] for key in _FRAME_LISTS}
    for frame, i in enumerate(rows):
        people = []
        if subject.listed[i, c]:
            people.append(_person_json(subject.keypoints[i, c], subject.scores[i, c]))
        else:
            lists["subject_undetected_frames"].append(frame)
        if passer is not None and passer.listed[i, c]:
            entry = _person_json(passer.keypoints[i, c], passer.scores[i, c])
            lists["second_person_frames"].append(frame)
            if people and passer_first[i, c]:
                people.insert(0, entry)
                lists["second_person_first_frames"].append(frame)
            else:
                people.append(entry)
        with open(folder / f"{prefix}_{frame:012d}_keypoints.json", "w", encoding="utf-8") as file:
            file.write('{"version":1.3,"people":[' + ",".join(people) + "]}")
    return lists


def write_rig_project(root: str | Path, config: ExampleProjectConfig = ExampleProjectConfig()) -> Path:
    """Write the example rig project described in this module's docstring into `root`; returns `root`.

    `root` must be empty or missing, or hold an earlier example project (which is replaced).
    `example_truth.json` records what a test needs: the layout, fps, cameras, image size, the
    desynchronized camera and its offset (file f holds instant f + offset), the ground truth's joint
    names and root, and per recording its motion and, per camera (in that camera's file numbers), the
    frames listing the passer-by, those listing it first, and those not listing the subject.
    """
    root = Path(root)
    _clear_previous(root)
    root.mkdir(parents=True, exist_ok=True)
    truth_path = root / EXAMPLE_TRUTH_JSON
    # Written first, so that an interrupted write can be replaced by the next one (`_clear_previous`).
    truth_path.write_text(json.dumps({"complete": False, "recordings": dict.fromkeys(config.recording_names)}))
    rig = rig_calibration(config)
    write_anipose_toml(root / CALIBRATION_TOML, rig, unit="m")
    field_radius2 = _field_radius2(rig.cameras, config.image_size)
    bones = sample_bone_lengths(stream_rng(config.synthetic_config(), Stream.BODY, 0))
    N, C = config.frames_per_recording, config.cameras
    offsets = config.frame_offsets()
    first_instant = int(min(offsets.min(), 0))  # instants simulated: first_instant .. first_instant + T - 1
    T = N + int(offsets.max() - first_instant)
    rows = np.arange(N)[None, :] + offsets[:, None] - first_instant  # [C, N] instant index of each file
    recordings = {}
    for r, name in enumerate(config.recording_names):
        motion = sample_motion(_rng(config, _Stream.MOTION, r), config.motion(r), bones, T, config.synthetic_config())
        subject_points = keypoints3d(motion.poses, bones, config.layout)
        subject = _detect(config, rig, field_radius2, subject_points, (r, 0))
        passer = None
        if config.second_person_rate > 0.0:
            walk, passer_bones, start = _passer_by_poses(config, rig.cameras, r, T)
            points = np.full(subject_points.shape, np.nan)
            points[start : start + len(walk)] = keypoints3d(walk, passer_bones, config.layout)
            passer = _detect(config, rig, field_radius2, points, (r, 1))
        passer_first = _rng(config, _Stream.ORDER, r).random((T, C)) < config.second_person_first_rate
        record = {"motion": config.motion(r)} | {key: {} for key in _FRAME_LISTS}
        for c, camera in enumerate(config.camera_names):
            folder = root / name / json_folder(camera)
            lists = _write_camera(folder, f"{name}_{camera}", rows[c], subject, passer, passer_first, c)
            for key, frames in lists.items():
                record[key][camera] = frames
        truth_points = subject_points[-first_instant : -first_instant + N]
        if config.layout == "coco17":
            hips = [COCO_17.joint_names.index("left_hip"), COCO_17.joint_names.index("right_hip")]
            truth_points = np.concatenate([truth_points, truth_points[:, hips].mean(1, keepdims=True)], axis=1)
        write_ground_truth(root / name / GROUND_TRUTH_NPZ, truth_points, np.arange(N), _ground_truth_names(config.layout))
        recordings[name] = record
    desync = config.desync_camera >= 0 and config.desync_frames != 0
    truth = {
        "description": "jaxpose's synthetic example rig project: what was simulated, for checking a pipeline on it",
        "complete": True,
        "layout": config.layout,
        "fps": config.fps,
        "frames_per_recording": N,
        "cameras": list(config.camera_names),
        "image_size": list(config.image_size),
        "calibration": CALIBRATION_TOML,
        "calibration_unit": "m",
        "desynchronized_camera": config.camera_names[config.desync_camera] if desync else None,
        "desync_offset_frames": int(config.desync_frames) if desync else 0,
        "frame_offsets": {camera: int(offset) for camera, offset in zip(config.camera_names, offsets)},
        "frame_offset_meaning": (
            "camera c's file numbered f holds the instant of the synchronized cameras' frame f + offset[c]"
        ),
        "ground_truth_joint_names": list(_ground_truth_names(config.layout)),
        "ground_truth_root": "pelvis" if config.layout == "coco17" else "MidHip",
        "min_keypoints_per_person": MIN_KEYPOINTS,
        "config": dataclasses.asdict(config),
        "recordings": recordings,
    }
    truth_path.write_text(json.dumps(truth, indent=1) + "\n")
    return root


# ----------------------------------------------------------------------------------------------
# Command line


@dataclasses.dataclass(frozen=True, kw_only=True)
class WriteArgs(ExampleProjectConfig):
    """Write jaxpose's synthetic example rig project (calibration, OpenPose JSON, ground truth)."""

    output: Path
    """The project folder to write: empty or new (an earlier example project there is replaced)."""


def main(argv: Sequence[str] | None = None) -> Path:
    args = tyro.cli(
        WriteArgs, args=argv, prog="python -m jaxpose.synthetic.project", description=WriteArgs.__doc__
    )
    fields = dataclasses.fields(ExampleProjectConfig)
    config = ExampleProjectConfig(**{field.name: getattr(args, field.name) for field in fields})
    began = time.perf_counter()
    try:
        root = write_rig_project(args.output, config)
    except (ValueError, FileExistsError) as error:
        raise SystemExit(f"error: {error}") from None
    files = [path for path in root.rglob("*") if path.is_file()]
    size_mb = sum(path.stat().st_size for path in files) / 1e6
    print(
        f"wrote {root}: {config.recordings} recordings x {config.cameras} cameras x {config.frames_per_recording}"
        f" frames ({len(files)} files, {size_mb:.1f} MB) in {time.perf_counter() - began:.1f} s"
    )
    if config.desync_camera >= 0 and config.desync_frames:
        camera = config.camera_names[config.desync_camera]
        print(
            f"{camera} is {config.desync_frames} frames out of sync: pass"
            f" --data.frame-offsets {camera}={config.desync_frames} or --data.sync auto"
        )
    print(f"train a lifter on it: python -m experiments.rig --data.root {root}")
    return root


if __name__ == "__main__":
    main()
