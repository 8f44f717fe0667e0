"""What the example rig project simulates (`ExampleProjectConfig`), and the simulation: the rig
with its lenses (`rig_calibration`), a passer-by's walk (`passer_by_poses`) and the detector in a
keypoint layout (`detect`).

- One person (one body) seen by one rig (`make_rig`: cameras on a circle around the capture area) in
  every recording; each recording is one motion family (`sample_motion`) with its own random stream.
  The lenses get mild OpenCV-model distortion (k1 barrel, small k2, p1, p2; k3 = 0), which the
  detections include and the calibration file states.
- The detector: `simulate_detector`'s noise, gross outliers, missing joints and confidences, each
  keypoint with the noise of its nearest body joint (`jaxpose.synthetic.keypoints.NOISE_JOINT`);
  confidences are then scaled down for the noisier joints.  Left/right swaps exchange a whole view's
  left and right keypoints and keep their (high) scores, as real detectors are confident in a swap.
  Keypoints whose true position is outside an image (or detected outside it) are not detected, and a
  person with fewer than `MIN_KEYPOINTS` detected keypoints in a view is not listed in that view.
- A second person (another body) walks past behind one of the cameras in about `second_person_rate`
  of each recording's frames: the camera it walks behind never sees it, the camera opposite sees it
  small in the background, those beside it at most at an image's edge.

Every random draw comes from generators keyed by (seed, stream, recording, ...) (`ExampleStream`).
numpy throughout, jax only to project.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Sequence
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import Cameras, camera_centres, project_from_camera, undistort_points, world_to_camera
from jaxpose.formats.rig_cameras import RigCalibration
from jaxpose.rotations import nearest_rotation
from jaxpose.skeleton import H36M_17
from jaxpose.synthetic.body import axis_rotation, sample_bone_lengths
from jaxpose.synthetic.config import Stream, SyntheticConfig, stream_rng
from jaxpose.synthetic.detector import DETECTOR_SIGMA_PX, simulate_detector
from jaxpose.synthetic.keypoints import NOISE_JOINT, mirror, openpose_names
from jaxpose.synthetic.motion import MOTION_FAMILIES, sample_motion
from jaxpose.synthetic.rig import make_rig

# A view's detection of a person is listed only with at least this many detected keypoints.
MIN_KEYPOINTS = 5
# Confidence scale of a keypoint: (the body's smallest sigma / its sigma) ** this: noisy joints score lower.
_SCORE_SIGMA_EXPONENT = 0.25


class ExampleStream(enum.IntEnum):
    """The example project's random streams, numbered after `jaxpose.synthetic.config.Stream`'s so that
    no generator is shared with the simulator's own."""

    LENS = 10
    MOTION = 11
    PASSER_BY = 12
    DETECTOR = 13
    SWAP = 14
    ORDER = 15


@dataclasses.dataclass(frozen=True)
class ExampleProjectConfig:
    """An example rig project written from the synthetic generator (lengths mm, image quantities px).

    The simulator's settings it shares with `SyntheticConfig` carry the same names (with the example's
    defaults and help) and reach it by name (`synthetic_config`); `dataclasses.asdict` of this config is
    what example_truth.json records."""

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
        """The simulator's config for this project: one subject, this rig and detector.  The fields both
        configs have (fps, image size, focal length, room, detector rates, seed) are taken by name;
        `cameras` and `frames_per_recording` are the simulator's `num_views` and `samples_per_subject`."""
        own = {field.name for field in dataclasses.fields(ExampleProjectConfig)}
        shared = {field.name: getattr(self, field.name) for field in dataclasses.fields(SyntheticConfig) if field.name in own}
        return SyntheticConfig(
            num_train_subjects=1, num_test_subjects=0, samples_per_subject=self.frames_per_recording, num_views=self.cameras, **shared
        )

    def rng(self, stream: ExampleStream, *key: int) -> np.random.Generator:
        """The generator of one of the example's random streams, keyed by the seed and `key`."""
        return np.random.default_rng([self.seed, int(stream), *key])

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


def rig_calibration(config: ExampleProjectConfig = ExampleProjectConfig()) -> RigCalibration:
    """The example project's rig as `calibration.toml` holds it: float64 `Cameras` [C] (t mm, OpenCV
    distortion), image sizes, camera names.

    The simulator's room (`make_rig` on the config's seed) with its rotations made exactly orthonormal
    in float64, so that the file (Rodrigues vectors) reproduces the projections that made the
    detections; with `config.distortion`, mild lens distortion per camera from the LENS stream.
    """
    synthetic = config.synthetic_config()
    room = make_rig(stream_rng(synthetic, Stream.ROOM), synthetic)
    R = nearest_rotation(room.R)
    C = config.cameras
    dist = None
    if config.distortion:
        rng = config.rng(ExampleStream.LENS)
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


def field_radius2(cameras: Cameras, image_size: tuple[int, int]) -> np.ndarray:
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


@dataclasses.dataclass(frozen=True)
class Person:
    """One person's keypoints over a recording's instants and their detection in every camera."""

    points: np.ndarray  # f64[T, K, 3] world mm (NaN where the person is not in the scene)
    keypoints: np.ndarray  # f64[T, C, K, 2] px, 0 where not detected
    scores: np.ndarray  # f64[T, C, K] in (0, 1], 0 where not detected
    listed: np.ndarray  # bool[T, C] the view's detection is written


def passer_by_poses(
    config: ExampleProjectConfig, rig: Cameras, recording: int, instants: int
) -> tuple[np.ndarray, np.ndarray, int]:
    """The second person's H36M_17 poses f64[E, 17, 3] walking straight past behind one camera, its
    bone lengths, and the first instant (index) of its E-instant passage."""
    synthetic = config.synthetic_config()
    rng = config.rng(ExampleStream.PASSER_BY, recording)
    bones = sample_bone_lengths(stream_rng(synthetic, Stream.BODY, 1))
    length = int(np.clip(round(config.second_person_rate * instants), 2, instants))
    start = int(rng.integers(0, instants - length + 1))
    walk = sample_motion(rng, "walking", bones, length, synthetic).poses.astype(np.float64)
    # Re-lay the walk along a straight line: keep its stride (arc length) and its pelvis' sway.
    root = walk[:, 0]
    step = np.gradient(root[:, :2], axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(root[:, :2], axis=0), axis=1))])
    camera = int(rng.integers(config.cameras))
    centre = camera_centres(rig.R[camera], rig.t[camera])
    outward = centre[:2] / np.linalg.norm(centre[:2], axis=-1, keepdims=True)
    across = np.array([-outward[1], outward[0]]) * rng.choice([-1.0, 1.0])
    distance = np.linalg.norm(centre[:2]) + rng.uniform(800.0, 2000.0)  # behind that camera
    start_xy = outward * distance + across * (rng.uniform(-1500.0, 1500.0) - arc[-1] / 2.0)
    turn = np.degrees(np.arctan2(across[1], across[0]) - np.arctan2(step[:, 1], step[:, 0]))
    relative = np.einsum("tij,tkj->tki", axis_rotation(2, turn), walk - root[:, None])
    path = np.concatenate([start_xy + arc[:, None] * across, root[:, 2:]], axis=1)
    return relative + path[:, None], bones, start


def detect(
    config: ExampleProjectConfig,
    rig: RigCalibration,
    max_radius2: np.ndarray,
    points: np.ndarray,
    key: Sequence[int],
) -> Person:
    """Detect keypoints f64[T, K, 3] (NaN rows: absent) in every camera as the simulated detector would;
    keypoints beyond a camera's `max_radius2` (`field_radius2`) are outside its lens' field."""
    synthetic = dataclasses.replace(config.synthetic_config(), swap_rate=0.0)  # swaps below, per layout
    names = openpose_names(config.layout)
    T, K, _ = points.shape
    present = np.isfinite(points).all(axis=(1, 2))
    clean, depth, radius2 = _project(rig.cameras, np.where(present[:, None, None], points, 0.0))
    width, height = config.image_size

    def inside(pixels: np.ndarray) -> np.ndarray:
        return (pixels[..., 0] >= 0.0) & (pixels[..., 0] < width) & (pixels[..., 1] >= 0.0) & (pixels[..., 1] < height)

    visible = present[:, None, None] & (depth > 100.0) & (radius2 < max_radius2[:, None]) & inside(clean)
    # simulate_detector works on H36M_17 arrays: each keypoint goes to the slot of its nearest body
    # joint (whose noise it gets), over as many passes as one joint has keypoints (4: the eyes and ears,
    # or an ankle and its foot points).
    slots = [H36M_17.joint_names.index(NOISE_JOINT[name]) for name in names]
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
        result = simulate_detector(config.rng(ExampleStream.DETECTOR, *key, index), packed, synthetic)
        detected[:, :, keypoint_list] = result.keypoints2d[:, :, slot_list]
        confidence[:, :, keypoint_list] = result.confidence[:, :, slot_list]
        missing[:, :, keypoint_list] = result.missing[:, :, slot_list]
    sigma = np.array([DETECTOR_SIGMA_PX[NOISE_JOINT[name]] for name in names])
    confidence = confidence * (min(DETECTOR_SIGMA_PX.values()) / sigma) ** _SCORE_SIGMA_EXPONENT
    missing |= ~visible
    # Whole-view left/right swaps: the detector confidently labels the left keypoints right and back.
    flip = np.array([names.index(mirror(name)) for name in names])
    swapped = config.rng(ExampleStream.SWAP, *key).random((T, config.cameras)) < config.swap_rate
    for array in (detected, confidence, missing):
        array[swapped] = array[swapped][:, flip]
    missing |= ~inside(detected)
    detected[missing] = 0.0
    confidence[missing] = 0.0
    listed = present[:, None] & ((~missing).sum(-1) >= MIN_KEYPOINTS)
    return Person(points=points, keypoints=detected, scores=confidence, listed=listed)
