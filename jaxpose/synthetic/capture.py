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
- With `people` > 1, further people in the scene (`people_poses`: apart by `min_distance`, or the
  first two passing each other at `pass_each_other`; the last one out for `absent_frames`), optional
  occlusion of one by another (`occlude`) and false detections seen by one camera (`false_people`).

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
    PEOPLE = 16
    SHUFFLE = 17
    FALSE_PEOPLE = 18


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
    people: int = 1
    """People in the scene, each with their own body and a motion of the recording's family (1-8); with
    more than one, ground_truth.npz holds a person axis and every frame file lists its people shuffled."""
    min_distance: float = 500.0
    """Closest approach (mm, on the floor) of any two people's pelvises, except the pair passing each other."""
    pass_each_other: float = 0.0
    """> 0: the first two people walk straight across the room towards each other on parallel lines this
    far apart (mm) and pass at mid-recording, in the scene only while on their line (needs people >= 2)."""
    false_people_rate: float = 0.0
    """Chance, per camera and frame, of a false detection: a plausible skeleton seen by that camera only."""
    occlusion: bool = False
    """Hide a person's keypoints in a view where they fall in a nearer person's box (its keypoints' extent)."""
    absent_frames: int = 0
    """The last person leaves the scene for this many frames mid-recording (not detected, NaN ground truth)."""

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
        if not 1 <= self.people <= 8:
            raise ValueError(f"people must lie in 1..8, got {self.people}")
        if self.min_distance < 0.0 or self.pass_each_other < 0.0:
            raise ValueError(f"min_distance and pass_each_other must be >= 0 mm, got {self.min_distance}, {self.pass_each_other}")
        if self.pass_each_other > 0.0 and self.people < 2:
            raise ValueError(f"pass_each_other needs people >= 2, got people {self.people}")
        if not 0 <= self.absent_frames <= self.frames_per_recording - 10:
            raise ValueError(f"absent_frames must lie in 0..frames_per_recording - 10, got {self.absent_frames}")
        for name in ("second_person_rate", "second_person_first_rate", "false_people_rate"):
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

    @property
    def shuffled(self) -> bool:
        """Whether frame files list their people in a random order (several people or false detections):
        the single-person project keeps its own order (the passer-by first in some frames)."""
        return self.people > 1 or self.false_people_rate > 0.0

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
    arc = _arc_length(walk)
    camera = int(rng.integers(config.cameras))
    centre = camera_centres(rig.R[camera], rig.t[camera])
    outward = centre[:2] / np.linalg.norm(centre[:2], axis=-1, keepdims=True)
    across = np.array([-outward[1], outward[0]]) * rng.choice([-1.0, 1.0])
    distance = np.linalg.norm(centre[:2]) + rng.uniform(800.0, 2000.0)  # behind that camera
    start_xy = outward * distance + across * (rng.uniform(-1500.0, 1500.0) - arc[-1] / 2.0)
    return _along_line(walk, start_xy, across, arc), bones, start


def _arc_length(walk: np.ndarray) -> np.ndarray:
    """f64[T] distance the pelvis of poses f64[T, 17, 3] has walked on the floor since the first instant."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(walk[:, 0, :2], axis=0), axis=1))])


def _along_line(walk: np.ndarray, origin: np.ndarray, direction: np.ndarray, along: np.ndarray) -> np.ndarray:
    """Re-lay a walk f64[T, 17, 3] on the straight line origin + along[t] * direction (unit, floor plane):
    keep its stride and its pelvis' height, turn each pose to face `direction`."""
    root = walk[:, 0]
    step = np.gradient(root[:, :2], axis=0)
    turn = np.degrees(np.arctan2(direction[1], direction[0]) - np.arctan2(step[:, 1], step[:, 0]))
    relative = np.einsum("tij,tkj->tki", axis_rotation(2, turn), walk - root[:, None])
    path = np.concatenate([origin + along[:, None] * direction, root[:, 2:]], axis=1)
    return relative + path[:, None]


def people_bones(config: ExampleProjectConfig) -> list[np.ndarray]:
    """Each person's bone lengths f64[17]: person 0 is the single-person project's subject; body 1 is
    the passer-by's, so person p > 0 gets body p + 1."""
    synthetic = config.synthetic_config()
    return [sample_bone_lengths(stream_rng(synthetic, Stream.BODY, 0 if p == 0 else p + 1)) for p in range(config.people)]


def pelvis_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """f64[T] floor distance (mm) of two people's pelvises from poses [T, 17, 3]; NaN where either is absent."""
    return np.linalg.norm(np.asarray(a, np.float64)[:, 0, :2] - np.asarray(b, np.float64)[:, 0, :2], axis=-1)


def _crossing_walks(config: ExampleProjectConfig, recording: int, bones: list[np.ndarray], instants: int) -> list[np.ndarray]:
    """People 0 and 1 walking towards each other on parallel lines `pass_each_other` mm apart through the
    room's centre, level at instant T // 2; each is in the scene (else NaN) within capture_area / 2 of it."""
    synthetic = config.synthetic_config()
    rng = config.rng(ExampleStream.PEOPLE, recording, 0)
    angle = rng.uniform(0.0, 2.0 * np.pi)
    direction = np.array([np.cos(angle), np.sin(angle)])
    across = np.array([-direction[1], direction[0]])
    walks = []
    for person, sign in ((0, 1.0), (1, -1.0)):
        walk = sample_motion(config.rng(ExampleStream.PEOPLE, recording, 1 + person), "walking", bones[person], instants, synthetic)
        walk = walk.poses.astype(np.float64)
        along = _arc_length(walk)
        along = along - along[instants // 2]
        poses = _along_line(walk, sign * config.pass_each_other / 2.0 * across, sign * direction, along)
        poses[np.abs(along) > config.capture_area / 2.0] = np.nan  # walked out of the room
        walks.append(poses)
    return walks


# Draws of a person's motion tried before giving up on keeping `min_distance` from the others.
_PLACEMENT_TRIES = 200


def people_poses(config: ExampleProjectConfig, recording: int, bones: list[np.ndarray], instants: int) -> list[np.ndarray]:
    """Every person's H36M_17 poses f[T, 17, 3] world mm, NaN while out of the scene.

    Person 0 is the single-person project's subject (the same motion), unless the first two pass each
    other (`_crossing_walks`).  Each further person draws a motion of the recording's family, turned a
    random number of quarter turns about the room's vertical axis (the capture square maps onto itself)
    and moved at random within the square (no further than it must when already touching it), until its pelvis keeps `min_distance` from everyone placed before at every instant both are in the
    scene.  Then the last person leaves for `absent_frames` instants around the recording's middle."""
    synthetic = config.synthetic_config()
    family = config.motion(recording)
    if config.pass_each_other > 0.0:
        placed = _crossing_walks(config, recording, bones, instants)
    else:
        placed = [sample_motion(config.rng(ExampleStream.MOTION, recording), family, bones[0], instants, synthetic).poses]
    for person in range(len(placed), config.people):
        for attempt in range(_PLACEMENT_TRIES):
            rng = config.rng(ExampleStream.PEOPLE, recording, 1 + person, attempt)
            poses = sample_motion(rng, family, bones[person], instants, synthetic).poses.astype(np.float64)
            quarter = [(1, 0), (0, 1), (-1, 0), (0, -1)][int(rng.integers(4))]
            turn = np.array([[quarter[0], -quarter[1], 0], [quarter[1], quarter[0], 0], [0, 0, 1]], np.float64)
            poses = poses @ turn.T
            # Anywhere in the capture square: in-place motions are drawn near its centre.
            low, high = poses[..., :2].min(axis=(0, 1)), poses[..., :2].max(axis=(0, 1))
            half = config.capture_area / 2.0
            poses[..., :2] += rng.uniform(np.minimum(-half - low, 0.0), np.maximum(half - high, 0.0))
            gaps = [pelvis_distance(poses, other) for other in placed]
            if all(np.nanmin(gap, initial=np.inf) >= config.min_distance for gap in gaps):
                placed.append(poses)
                break
        else:
            raise ValueError(
                f"could not place person {person + 1} of {config.people} {config.min_distance:g} mm from the others"
                f" in a {config.capture_area:g} mm capture area ({family}); lower people or min_distance, or widen capture_area"
            )
    if config.absent_frames:
        start = instants // 2 - config.absent_frames // 2
        placed[-1] = np.array(placed[-1], copy=True)
        placed[-1][start : start + config.absent_frames] = np.nan
    return placed


def false_people(
    config: ExampleProjectConfig, rig: RigCalibration, max_radius2: np.ndarray, points: np.ndarray, recording: int
) -> list[Person]:
    """Per camera, its false detections: in about `false_people_rate` of the instants a skeleton (a pose
    of keypoints f[T, K, 3], one person's, at a random instant) turned and put at a random place of the
    capture area, detected by that camera only."""
    present = np.flatnonzero(np.isfinite(points).all(axis=(1, 2)))
    T = len(points)
    half = config.capture_area / 2.0
    found = []
    for camera in range(config.cameras):
        rng = config.rng(ExampleStream.FALSE_PEOPLE, recording, camera)
        seen = np.flatnonzero(rng.random(T) < config.false_people_rate)
        pose = np.asarray(points[rng.choice(present, len(seen))], np.float64)
        centre = pose.mean(1, keepdims=True) * np.array([1.0, 1.0, 0.0])
        turned = np.einsum("nij,nkj->nki", axis_rotation(2, rng.uniform(0.0, 360.0, len(seen))), pose - centre)
        false = np.full((T, points.shape[1], 3), np.nan)
        false[seen] = turned + np.concatenate([rng.uniform(-half, half, (len(seen), 2)), np.zeros((len(seen), 1))], 1)[:, None]
        person = detect(config, rig, max_radius2, false, (recording, 100 + camera))
        only_here = np.arange(config.cameras) == camera
        found.append(dataclasses.replace(person, listed=person.listed & only_here))
    return found


def occlude(rig: RigCalibration, people: list[Person]) -> list[Person]:
    """Hide each person's keypoints, in each view, that lie inside a nearer person's box (the extent of
    its projected keypoints) and behind that person's mean keypoint depth; unlist views left with fewer
    than `MIN_KEYPOINTS`.  A box is a body's silhouette, generously."""
    projected = []
    for person in people:
        present = np.isfinite(person.points).all(axis=(1, 2))
        pixels, depth, _ = _project(rig.cameras, np.where(present[:, None, None], person.points, 0.0))
        projected.append((present, pixels, depth))
    hidden_people = []
    for p, person in enumerate(people):
        _, pixels, depth = projected[p]
        hidden = np.zeros(person.scores.shape, bool)  # [T, C, K]
        for q, (present, other, other_depth) in enumerate(projected):
            if q == p:
                continue
            low, high = other.min(axis=2, keepdims=True), other.max(axis=2, keepdims=True)  # [T, C, 1, 2]
            inside = ((pixels >= low) & (pixels <= high)).all(-1)
            hidden |= present[:, None, None] & inside & (depth > other_depth.mean(-1, keepdims=True))
        keypoints = np.where(hidden[..., None], 0.0, person.keypoints)
        scores = np.where(hidden, 0.0, person.scores)
        listed = person.listed & ((scores > 0).sum(-1) >= MIN_KEYPOINTS)
        hidden_people.append(Person(points=person.points, keypoints=keypoints, scores=scores, listed=listed))
    return hidden_people


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
