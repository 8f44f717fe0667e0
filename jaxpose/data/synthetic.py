"""Procedural multi-view human-motion data: the project's embedded default data set.

Real data sets cannot be downloaded here, so this module simulates one that has the structure the
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
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.camera import Cameras, project_from_camera, world_to_camera
from jaxpose.data.dataset import MultiViewDataset
from jaxpose.skeleton import H36M_17

MOTION_FAMILIES = ("walking", "turning", "sitting", "crouching", "reaching", "waving", "gesturing", "bending")

# Anatomical angle -> (min, max) degrees.  Sign conventions: flexion moves a limb (or the trunk,
# neck) forward, knee flexion moves the shin backward; abduction moves a limb away from the body's
# midline; "pelvis_pitch" tilts the whole pelvis forward over the legs (the hips compensate).
JOINT_LIMITS_DEG: dict[str, tuple[float, float]] = {
    "pelvis_pitch": (-10.0, 70.0),
    "pelvis_roll": (-10.0, 10.0),
    "lumbar_flex": (-15.0, 40.0),
    "lumbar_bend": (-15.0, 15.0),
    "lumbar_twist": (-20.0, 20.0),
    "thoracic_flex": (-15.0, 30.0),
    "thoracic_bend": (-15.0, 15.0),
    "thoracic_twist": (-25.0, 25.0),
    "neck_flex": (-40.0, 50.0),
    "neck_bend": (-30.0, 30.0),
    "neck_twist": (-60.0, 60.0),
    "hip_flex": (-25.0, 125.0),
    "hip_abd": (-15.0, 40.0),
    "hip_rot": (-30.0, 40.0),
    "knee_flex": (0.0, 150.0),
    "shoulder_flex": (-50.0, 170.0),
    "shoulder_abd": (-10.0, 160.0),
    "shoulder_rot": (-70.0, 90.0),
    "elbow_flex": (0.0, 150.0),
}

_AXIAL = ("pelvis_pitch", "pelvis_roll") + tuple(
    f"{segment}_{motion}" for segment in ("lumbar", "thoracic", "neck") for motion in ("flex", "bend", "twist")
)
_LIMB = ("hip_flex", "hip_abd", "hip_rot", "knee_flex", "shoulder_flex", "shoulder_abd", "shoulder_rot", "elbow_flex")
ANGLE_NAMES: tuple[str, ...] = _AXIAL + tuple(f"{side}_{name}" for side in ("l", "r") for name in _LIMB)


def angle_limits(names: tuple[str, ...] = ANGLE_NAMES) -> np.ndarray:
    """f64[D, 2] (min, max) degrees of the given angle columns (the side prefix is ignored)."""
    return np.array([JOINT_LIMITS_DEG[name[2:] if name[:2] in ("l_", "r_") else name] for name in names])


# Adult bone lengths (mm) by the joint a bone ends at; roughly the Human3.6M subjects' means.
NOMINAL_BONE_MM: dict[str, float] = {
    "RHip": 130.0, "RKnee": 450.0, "RFoot": 440.0,
    "LHip": 130.0, "LKnee": 450.0, "LFoot": 440.0,
    "Spine": 230.0, "Thorax": 250.0, "Neck/Nose": 120.0, "Head": 115.0,
    "LShoulder": 170.0, "LElbow": 290.0, "LWrist": 260.0,
    "RShoulder": 170.0, "RElbow": 290.0, "RWrist": 260.0,
}  # fmt: skip

# Bone directions at rest (all angles 0: upright, arms hanging) in the parent segment's frame, for
# the left side and the midline; the right side mirrors y.  The nose sits in front of the neck axis
# and the head top slightly behind it, as in Human3.6M's "Neck/Nose" and "Head" markers.
_REST_DIRECTION: dict[str, tuple[float, float, float]] = {
    "LHip": (0.0, 1.0, 0.0), "LKnee": (0.0, 0.0, -1.0), "LFoot": (0.0, 0.0, -1.0),
    "Spine": (0.0, 0.0, 1.0), "Thorax": (0.0, 0.0, 1.0), "Neck/Nose": (0.35, 0.0, 0.94), "Head": (-0.25, 0.0, 0.97),
    "LShoulder": (0.0, 1.0, -0.1), "LElbow": (0.0, 0.0, -1.0), "LWrist": (0.0, 0.0, -1.0),
}  # fmt: skip

# Walkers slow down in tight turns to keep their lateral acceleration below this (mm/s^2): it
# bounds the turning rate and the lean into the turn (atan(1.5 / 9.81) ~ 9 degrees).
_MAX_TURN_ACCELERATION = 1500.0

# The "Foot" joint is the ankle: the lower ankle of a pose sits this high above the floor.
ANKLE_HEIGHT_MM = 80.0

# Per-axis standard deviation (px) of the detector's Gaussian noise at noise_sigma_scale 1: the
# torso is easy to localize, distal joints (wrists, ankles) move fast and are small.
DETECTOR_SIGMA_PX: dict[str, float] = {
    "Hip": 3.0, "RHip": 3.5, "RKnee": 5.0, "RFoot": 8.0, "LHip": 3.5, "LKnee": 5.0, "LFoot": 8.0,
    "Spine": 3.0, "Thorax": 3.0, "Neck/Nose": 4.0, "Head": 4.5,
    "LShoulder": 4.0, "LElbow": 6.0, "LWrist": 8.0, "RShoulder": 4.0, "RElbow": 6.0, "RWrist": 8.0,
}  # fmt: skip

# Independent random streams: (seed, stream, subject) keys a generator.
_STREAM_ROOM, _STREAM_RIG, _STREAM_BODY, _STREAM_MOTION, _STREAM_DETECTOR = range(5)

_JOINT = {name: index for index, name in enumerate(H36M_17.joint_names)}


@dataclasses.dataclass(frozen=True)
class SyntheticConfig:
    """What to simulate.  Lengths mm, image quantities px, rates are fractions in [0, 1]."""

    num_train_subjects: int = 5
    num_test_subjects: int = 2
    samples_per_subject: int = 8000  # instants per subject, split over sequences of the motion families
    num_views: int = 4  # any C >= 2
    fps: float = 10.0  # sampling rate of the generated sequences
    image_size: tuple[int, int] = (1000, 1000)  # (width, height)
    focal_length: float = 1150.0  # px, jittered a few % per camera
    camera_distance: tuple[float, float] = (4000.0, 6000.0)  # mm from the room centre
    camera_height: tuple[float, float] = (1200.0, 2000.0)  # mm
    capture_area: float = 4000.0  # mm, side of the square the subject moves in
    noise_sigma_scale: float = 1.0  # multiplies the per-joint detector sigma (3-8 px)
    outlier_rate: float = 0.02  # fraction of joint detections replaced by gross outliers
    swap_rate: float = 0.01  # fraction of view-detections with a left/right swap
    missing_rate: float = 0.01  # fraction of joint detections missing (confidence 0, coords 0)
    seed: int = 0
    sequence_length: int = 250  # nominal frames per sequence (a subject's samples split evenly)
    outlier_distance: tuple[float, float] = (30.0, 150.0)  # px, range of a gross outlier's displacement

    def __post_init__(self):
        if self.num_views < 2:
            raise ValueError(f"num_views must be >= 2 for multi-view geometry, got {self.num_views}")
        if self.num_train_subjects < 0 or self.num_test_subjects < 0 or self.num_subjects == 0:
            raise ValueError("need at least one subject and no negative subject counts")
        if self.samples_per_subject < 1 or self.sequence_length < 1 or self.fps <= 0:
            raise ValueError("samples_per_subject, sequence_length and fps must be positive")
        for name in ("outlier_rate", "swap_rate", "missing_rate"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)}")
        # Cameras on a circle outside the capture square's corners keep every joint in front of them.
        if self.camera_distance[0] <= self.capture_area / np.sqrt(2.0) + 500.0:
            raise ValueError(
                f"camera_distance {self.camera_distance} must exceed the capture area's half diagonal"
                f" ({self.capture_area / np.sqrt(2.0):.0f} mm) by 500 mm so that no joint is behind a camera"
            )

    @property
    def num_subjects(self) -> int:
        return self.num_train_subjects + self.num_test_subjects


def _rng(config: SyntheticConfig, stream: int, subject: int = 0) -> np.random.Generator:
    return np.random.default_rng([config.seed, stream, subject])


# ----------------------------------------------------------------------------------------------
# Body: bone lengths and forward kinematics


def sample_bone_lengths(rng: np.random.Generator) -> np.ndarray:
    """f64[J] length of the bone ending at each H36M_17 joint (0 for the root), one subject.

    A global scale (body size, +-9%) times a per-bone factor (+-4%, proportions) shared by the left
    and right bone, so the skeleton is exactly symmetric and within +-14% of `NOMINAL_BONE_MM`.
    """
    scale = rng.uniform(0.91, 1.09)
    lengths = np.zeros(H36M_17.num_joints)
    for name, nominal in NOMINAL_BONE_MM.items():
        if name[0] != "R":  # the right bone copies its left partner's factor below
            lengths[_JOINT[name]] = nominal * scale * rng.uniform(0.96, 1.04)
    for left, right in H36M_17.left_right_pairs:
        lengths[right] = lengths[left]
    return lengths


def _rotation(axis: int, degrees: np.ndarray) -> np.ndarray:
    """[T, 3, 3] rotations by `degrees` about the coordinate axis `axis` (0 x, 1 y, 2 z)."""
    radians = np.radians(degrees)
    cos, sin = np.cos(radians), np.sin(radians)
    i, j = ((1, 2), (2, 0), (0, 1))[axis]
    matrix = np.zeros(radians.shape + (3, 3))
    matrix[..., axis, axis] = 1.0
    matrix[..., i, i] = cos
    matrix[..., j, j] = cos
    matrix[..., i, j] = -sin
    matrix[..., j, i] = sin
    return matrix


def _limb_rotation(flex: np.ndarray, abd: np.ndarray, rot: np.ndarray, mirror: float) -> np.ndarray:
    """Ball joint of a limb hanging along -z: twist about the limb, then abduction, then flexion.

    Flexion about -y moves the limb forward; abduction and twist change sign on the right side
    (`mirror` -1) because mirroring y flips rotations about x and z.
    """
    return _rotation(1, -flex) @ _rotation(0, mirror * abd) @ _rotation(2, mirror * rot)


def _trunk_rotation(flex: np.ndarray, bend: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """Joint of a segment pointing along +z (spine, neck): twist, then side bend, then flexion."""
    return _rotation(1, flex) @ _rotation(0, bend) @ _rotation(2, twist)


def forward_kinematics(angles: np.ndarray, heading: np.ndarray, bone_lengths: np.ndarray) -> np.ndarray:
    """Joint angles f[T, D] (degrees, `ANGLE_NAMES`) and heading f[T] (degrees about world z) ->
    f64[T, J, 3] H36M_17 positions (mm) with the pelvis at the origin, in world axes.

    Rotations only (no bone ever stretches), so bone lengths are constant over time by construction.
    """
    angle = {name: angles[:, column].astype(np.float64) for column, name in enumerate(ANGLE_NAMES)}
    joints = np.zeros((len(heading), H36M_17.num_joints, 3))

    def attach(child: str, parent: str, frame: np.ndarray, mirror: float = 1.0) -> None:
        rest_name = child if child[0] != "R" else "L" + child[1:]
        direction = np.asarray(_REST_DIRECTION[rest_name]) * np.array([1.0, mirror, 1.0])
        offset = bone_lengths[_JOINT[child]] * direction / np.linalg.norm(direction)
        joints[:, _JOINT[child]] = joints[:, _JOINT[parent]] + frame @ offset

    pelvis = _rotation(2, heading) @ _rotation(1, angle["pelvis_pitch"]) @ _rotation(0, angle["pelvis_roll"])
    lumbar = pelvis @ _trunk_rotation(angle["lumbar_flex"], angle["lumbar_bend"], angle["lumbar_twist"])
    thorax = lumbar @ _trunk_rotation(angle["thoracic_flex"], angle["thoracic_bend"], angle["thoracic_twist"])
    neck = thorax @ _trunk_rotation(angle["neck_flex"], angle["neck_bend"], angle["neck_twist"])
    attach("Spine", "Hip", lumbar)
    attach("Thorax", "Spine", thorax)
    attach("Neck/Nose", "Thorax", neck)
    attach("Head", "Neck/Nose", neck)
    for side, mirror in (("l", 1.0), ("r", -1.0)):
        S = side.upper()
        a = {name: angle[f"{side}_{name}"] for name in _LIMB}
        thigh = pelvis @ _limb_rotation(a["hip_flex"], a["hip_abd"], a["hip_rot"], mirror)
        shank = thigh @ _rotation(1, a["knee_flex"])  # +y rotation swings the shin backward
        upper_arm = thorax @ _limb_rotation(a["shoulder_flex"], a["shoulder_abd"], a["shoulder_rot"], mirror)
        forearm = upper_arm @ _rotation(1, -a["elbow_flex"])  # -y rotation swings the forearm forward
        attach(f"{S}Hip", "Hip", pelvis, mirror)
        attach(f"{S}Knee", f"{S}Hip", thigh, mirror)
        attach(f"{S}Foot", f"{S}Knee", shank, mirror)
        attach(f"{S}Shoulder", "Thorax", thorax, mirror)
        attach(f"{S}Elbow", f"{S}Shoulder", upper_arm, mirror)
        attach(f"{S}Wrist", f"{S}Elbow", forearm, mirror)
    return joints


# ----------------------------------------------------------------------------------------------
# Motion: smooth signals, paths and the motion families


def _wobble(rng: np.random.Generator, t: np.ndarray, amplitude: float, max_hz: float = 0.3) -> np.ndarray:
    """Slow random drift (two sinusoids of random frequency and phase) of about `amplitude` peak."""
    frequency = rng.uniform(0.02, max_hz, 2)
    phase = rng.uniform(0.0, 2.0 * np.pi, 2)
    return 0.5 * amplitude * np.sin(2.0 * np.pi * frequency[:, None] * t + phase[:, None]).sum(0)


def _key_times(rng: np.random.Generator, duration: float, move: tuple, hold: tuple) -> np.ndarray:
    """Knot times (s) for keyframes: each key is reached after a move of U(move) s and held U(hold) s.

    The first knot lies before t = 0, so sequences start at a random point of the cycle.
    """
    mean_cycle = 0.5 * (sum(move) + sum(hold))
    count = int(np.ceil(duration / max(min(move) + min(hold), 1e-3))) + 2
    moves, holds = rng.uniform(*move, count), rng.uniform(*hold, count)
    knots = np.cumsum(np.stack([moves, holds], axis=1).ravel())
    return knots - knots[0] - rng.uniform(0.0, mean_cycle)


def _keyframes(t: np.ndarray, knot_times: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """Smoothstep interpolation through keys [K, ...] at knots (key k spans knots 2k and 2k+1).

    Interpolation is a convex combination of neighbouring keys, so the result never leaves the
    range the keys were drawn from (a cubic spline would overshoot the joint limits), and it has zero
    velocity at the knots, as a person starting and ending a movement.
    """
    values = np.repeat(keys, 2, axis=0)
    index = np.clip(np.searchsorted(knot_times, t, side="right") - 1, 0, len(knot_times) - 2)
    u = np.clip((t - knot_times[index]) / (knot_times[index + 1] - knot_times[index]), 0.0, 1.0)
    weight = (u * u * (3.0 - 2.0 * u)).reshape(u.shape + (1,) * (keys.ndim - 1))
    return values[index] + weight * (values[index + 1] - values[index])


def _alternating(rng: np.random.Generator, t: np.ndarray, move: tuple, hold: tuple) -> np.ndarray:
    """A 0 -> 1 -> 0 ... activation in [0, 1] with smooth transitions and pauses (e.g. sit / stand)."""
    knots = _key_times(rng, t[-1] + 1.0, move, hold)
    keys = (np.arange(len(knots) // 2) + rng.integers(2)) % 2
    return _keyframes(t, knots, keys.astype(np.float64))


def _loop_path(
    rng: np.random.Generator, radius: float, wobble: float, half_extent: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A random smooth closed curve inside the square [-half_extent, half_extent]^2.

    Returns a dense polyline (xy [P, 2]), its cumulative arc length [P] and its tangent heading
    (degrees, unwrapped) [P]: r(theta) = radius (1 + harmonics 2 and 3 of random amplitude and phase),
    shrunk if needed to fit and placed at random inside the square.
    """
    theta = np.linspace(0.0, 2.0 * np.pi, 2049)
    amplitude = rng.uniform(0.0, wobble, 2) * np.array([1.0, 0.4])
    phase = rng.uniform(0.0, 2.0 * np.pi, 2)
    r = radius * (1.0 + amplitude[0] * np.cos(2 * theta + phase[0]) + amplitude[1] * np.cos(3 * theta + phase[1]))
    xy = np.stack([r * np.cos(theta), r * np.sin(theta)], axis=1)
    if rng.random() < 0.5:  # walk the loop clockwise
        xy = xy[::-1]
    xy *= min(1.0, half_extent / np.abs(xy).max())
    slack = np.maximum(half_extent - np.abs(xy).max(0), 0.0)
    xy += rng.uniform(-slack, slack)
    step = np.diff(xy, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(step, axis=1))])
    heading = np.degrees(np.unwrap(np.arctan2(step[:, 1], step[:, 0])))
    return xy, arc, np.concatenate([heading, heading[-1:]])


def _gait(rng: np.random.Generator, dof: dict, phase: np.ndarray, stride: float) -> None:
    """Leg, arm and trunk angles of walking at gait phase `phase` (rad; right leg forward at pi/2)
    with strides of `stride` mm (one gait cycle, two steps)."""
    # Each foot travels a quarter stride ahead of and behind the hip: swing angle ~ stride / (4 leg).
    hip_amplitude = np.degrees(stride / (4.0 * 900.0)) * rng.uniform(0.9, 1.1)
    knee_amplitude, hip_offset = rng.uniform(45.0, 60.0), rng.uniform(4.0, 10.0)
    arm_amplitude = hip_amplitude * rng.uniform(0.6, 1.3)
    for side, leg_phase in (("r", phase), ("l", phase + np.pi)):
        dof[f"{side}_hip_flex"] = dof["pelvis_pitch"] + hip_offset + hip_amplitude * np.sin(leg_phase)
        # Peak knee flexion in early swing, a nearly straight knee at heel strike.
        dof[f"{side}_knee_flex"] = 5.0 + knee_amplitude * ((1.0 + np.cos(leg_phase + 0.3)) / 2.0) ** 2
        # Each arm swings with the opposite leg, the elbow bends more as the arm comes forward.
        dof[f"{side}_shoulder_flex"] = 5.0 - arm_amplitude * np.sin(leg_phase)
        dof[f"{side}_elbow_flex"] = 20.0 - 10.0 * np.sin(leg_phase)
    dof["lumbar_twist"] = dof["lumbar_twist"] - rng.uniform(4.0, 9.0) * np.sin(phase)  # counter-rotation
    dof["pelvis_roll"] = dof["pelvis_roll"] + 2.0 * np.cos(2.0 * phase)


def _walk(
    rng: np.random.Generator, t: np.ndarray, dof: dict, half_extent: float, turning: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Walk along a loop: "walking" on wide, nearly straight loops, "turning" on tight curves.

    Returns the pelvis path xy [T, 2] (mm) and heading [T] (degrees).
    """
    if turning:
        xy, arc, tangent = _loop_path(rng, rng.uniform(450.0, 900.0), 0.15, half_extent)
        mean_speed = rng.uniform(600.0, 1000.0)
    else:
        xy, arc, tangent = _loop_path(rng, rng.uniform(900.0, 1500.0), 0.3, half_extent)
        mean_speed = rng.uniform(900.0, 1400.0)
    curvature = np.radians(np.gradient(tangent, arc))  # 1/mm along the loop, positive = left turn
    # Speed varies a little along the loop, and walkers slow down in tight turns: the lateral
    # acceleration v^2 * curvature stays below _MAX_TURN_ACCELERATION.
    speed = mean_speed * (1.0 + 0.08 * np.sin(2.0 * np.pi * arc / arc[-1] * rng.integers(1, 4) + rng.uniform(0, 7)))
    speed = np.minimum(speed, np.sqrt(_MAX_TURN_ACCELERATION / np.maximum(np.abs(curvature), 1e-9)))
    # Time as a function of arc length inverts to arc length as a function of time without a loop.
    lap_time = np.concatenate([[0.0], np.cumsum(np.diff(arc) / speed[:-1])])
    laps, within = np.divmod(t + rng.uniform(0.0, lap_time[-1]), lap_time[-1])
    s = np.interp(within, lap_time, arc)
    path = np.stack([np.interp(s, arc, xy[:, 0]), np.interp(s, arc, xy[:, 1])], axis=1)
    # People walk faster with both longer strides (about 1.0 m at 0.6 m/s, 1.5 m at 1.4 m/s) and a
    # higher cadence; the gait phase advances one cycle per stride walked, so the legs keep pace.
    stride = (650.0 + 0.6 * mean_speed) * rng.uniform(0.9, 1.1)
    phase = 2.0 * np.pi * (laps * arc[-1] + s) / stride + rng.uniform(0.0, 2.0 * np.pi)
    dof["lumbar_flex"] = dof["lumbar_flex"] + rng.uniform(0.0, 6.0)
    _gait(rng, dof, phase, stride)
    # Lean into the curve as a body balancing the centripetal force: tan(lean) = v^2 curvature / g.
    lean = np.degrees(np.arctan(np.interp(s, arc, speed**2 * curvature) / 9810.0))
    # Shared by the pelvis and the spine; positive roll and bend tilt to the right, a left turn leans left.
    dof["pelvis_roll"] = dof["pelvis_roll"] - 0.5 * lean
    dof["lumbar_bend"] = dof["lumbar_bend"] - 0.3 * lean
    dof["thoracic_bend"] = dof["thoracic_bend"] - 0.2 * lean
    dof["neck_twist"] = dof["neck_twist"] + 1.5 * lean  # look into the turn
    heading = np.interp(s, arc, tangent) + 3.0 * np.sin(phase)  # the pelvis yaws with the stride
    return path, heading


def _legs(dof: dict, thigh: np.ndarray, knee: np.ndarray) -> None:
    """Set both legs from the thigh's forward angle to the vertical and the knee flexion.

    The hip flexion is relative to the pelvis, so a forward-tilted pelvis needs more of it.
    """
    for side in ("l", "r"):
        dof[f"{side}_hip_flex"] = dof["pelvis_pitch"] + thigh
        dof[f"{side}_knee_flex"] = knee


def _sitting(rng: np.random.Generator, t: np.ndarray, dof: dict) -> None:
    """Sit down on a chair, stay, stand up, stay: the trunk leans forward during each transition."""
    s = _alternating(rng, t, move=(1.2, 2.5), hold=(2.0, 6.0))
    transition = np.sin(np.pi * s) ** 2
    dof["pelvis_pitch"] = dof["pelvis_pitch"] + rng.uniform(0.0, 12.0) * s + rng.uniform(20.0, 35.0) * transition
    # Thigh horizontal, shin about vertical when seated.
    _legs(dof, rng.uniform(80.0, 95.0) * s, dof["l_knee_flex"] * (1.0 - s) + rng.uniform(80.0, 105.0) * s)
    for side in ("l", "r"):
        dof[f"{side}_hip_abd"] = dof[f"{side}_hip_abd"] + rng.uniform(0.0, 15.0) * s
        # Hands go to the thighs when seated and forward for momentum while rising or sitting down.
        dof[f"{side}_shoulder_flex"] = dof[f"{side}_shoulder_flex"] + rng.uniform(10.0, 35.0) * s + 20.0 * transition
        dof[f"{side}_elbow_flex"] = dof[f"{side}_elbow_flex"] + rng.uniform(30.0, 70.0) * s


def _crouching(rng: np.random.Generator, t: np.ndarray, dof: dict) -> None:
    """Squat down and up: knees ahead of the feet, trunk forward, arms forward for balance."""
    s = _alternating(rng, t, move=(0.8, 2.0), hold=(1.0, 4.0))
    dof["pelvis_pitch"] = dof["pelvis_pitch"] + rng.uniform(15.0, 30.0) * s
    dof["lumbar_flex"] = dof["lumbar_flex"] + rng.uniform(0.0, 15.0) * s
    dof["neck_flex"] = dof["neck_flex"] - rng.uniform(0.0, 20.0) * s  # keep looking ahead
    thigh = rng.uniform(60.0, 88.0) * s
    shin_lean = rng.uniform(20.0, 45.0) * s  # the shin tilts forward, so the knee flexes past the thigh angle
    _legs(dof, thigh, dof["l_knee_flex"] * (1.0 - s) + thigh + shin_lean)
    for side in ("l", "r"):
        dof[f"{side}_hip_abd"] = dof[f"{side}_hip_abd"] + rng.uniform(5.0, 20.0) * s
        dof[f"{side}_shoulder_flex"] = dof[f"{side}_shoulder_flex"] + rng.uniform(20.0, 80.0) * s
        dof[f"{side}_elbow_flex"] = dof[f"{side}_elbow_flex"] + rng.uniform(0.0, 50.0) * s


def _bending(rng: np.random.Generator, t: np.ndarray, dof: dict) -> None:
    """Bend forward from the hips (as to pick something up) and straighten, arms hanging down."""
    s = _alternating(rng, t, move=(1.0, 2.0), hold=(0.5, 3.0))
    dof["pelvis_pitch"] = dof["pelvis_pitch"] + rng.uniform(35.0, 60.0) * s
    dof["lumbar_flex"] = dof["lumbar_flex"] + rng.uniform(10.0, 30.0) * s
    dof["thoracic_flex"] = dof["thoracic_flex"] + rng.uniform(5.0, 22.0) * s
    dof["neck_flex"] = dof["neck_flex"] - rng.uniform(0.0, 30.0) * s
    knee = rng.uniform(0.0, 30.0) * s
    _legs(dof, knee / 2.0, dof["l_knee_flex"] + knee)
    trunk = dof["pelvis_pitch"] + dof["lumbar_flex"] + dof["thoracic_flex"]
    for side in ("l", "r"):
        # Flexing the shoulders by (a share of) the trunk's tilt keeps the arms hanging towards the floor.
        dof[f"{side}_shoulder_flex"] = dof[f"{side}_shoulder_flex"] + rng.uniform(0.7, 1.0) * trunk * s


# Offset ranges (degrees) a reach adds to the neutral pose.  "twist" turns the lumbar and thoracic
# spine towards the target, "dip" bends the knees for a low target; arm offsets apply to reaching arms.
_REACH_TRUNK = {"lumbar_flex": (0.0, 25.0), "lumbar_bend": (-10.0, 10.0), "neck_flex": (0.0, 30.0),
                "twist": (-15.0, 15.0), "dip": (0.0, 30.0)}  # fmt: skip
_REACH_ARM = {"shoulder_flex": (40.0, 150.0), "shoulder_abd": (-5.0, 60.0), "shoulder_rot": (-20.0, 40.0),
              "elbow_flex": (0.0, 30.0)}  # fmt: skip


def _reaching(rng: np.random.Generator, t: np.ndarray, dof: dict) -> None:
    """Reach for random targets with one or both arms, turning and bending the trunk towards them."""
    knots = _key_times(rng, t[-1] + 1.0, move=(0.8, 2.0), hold=(0.3, 1.5))
    count = len(knots) // 2
    ranges = dict(_REACH_TRUNK) | {f"{side}_{name}": r for side in ("l", "r") for name, r in _REACH_ARM.items()}
    names = list(ranges)
    low, high = np.array(list(ranges.values())).T
    keys = rng.uniform(low, high, (count, len(names)))
    reaching_arms = rng.integers(0, 3, count)  # 0 left, 1 right, 2 both
    for side, other_arm_only in (("l", 1), ("r", 0)):
        columns = [names.index(f"{side}_{name}") for name in _REACH_ARM]
        keys[np.ix_(reaching_arms == other_arm_only, columns)] = 0.0
    keys[(rng.integers(2) + np.arange(count)) % 2 == 0] = 0.0  # every other key returns to rest
    track = dict(zip(names, _keyframes(t, knots, keys).T))
    for name in names:
        if name in dof:
            dof[name] = dof[name] + track[name]
    dof["lumbar_twist"] = dof["lumbar_twist"] + track["twist"]
    dof["thoracic_twist"] = dof["thoracic_twist"] + track["twist"]
    # The shins tilt forward by half the knee bend, keeping the body over the feet.
    _legs(dof, track["dip"] / 2.0, dof["l_knee_flex"] + track["dip"])


def _waving(rng: np.random.Generator, t: np.ndarray, dof: dict) -> None:
    """Raise one arm (sometimes both), wave with the forearm up, lower it again."""
    s = _alternating(rng, t, move=(0.6, 1.2), hold=(2.0, 5.0))
    sides = [("l", "r")[rng.integers(2)]] if rng.random() < 0.8 else ["l", "r"]
    frequency, phase = rng.uniform(1.0, 2.0), rng.uniform(0.0, 2.0 * np.pi)
    cycle = 2.0 * np.pi * frequency * t + phase
    for side in sides:
        dof[f"{side}_shoulder_abd"] = dof[f"{side}_shoulder_abd"] + rng.uniform(55.0, 110.0) * s
        dof[f"{side}_shoulder_flex"] = dof[f"{side}_shoulder_flex"] + rng.uniform(0.0, 40.0) * s
        # External rotation of the abducted upper arm turns the bent forearm upwards; the hand waves
        # by bending the elbow and rocking that rotation a quarter cycle apart.
        rotation = rng.uniform(55.0, 75.0) + rng.uniform(0.0, 12.0) * np.cos(cycle)
        elbow = rng.uniform(30.0, 60.0) + rng.uniform(10.0, 25.0) * np.sin(cycle)
        dof[f"{side}_shoulder_rot"] = dof[f"{side}_shoulder_rot"] * (1.0 - s) + rotation * s
        dof[f"{side}_elbow_flex"] = dof[f"{side}_elbow_flex"] + elbow * s
    dof["neck_twist"] = dof["neck_twist"] + rng.uniform(-20.0, 20.0) * s


def _gesturing(rng: np.random.Generator, t: np.ndarray, dof: dict) -> None:
    """Talking, pointing and raising gestures: each arm moves between random poses on its own."""
    for side in ("l", "r"):
        knots = _key_times(rng, t[-1] + 1.0, move=(0.4, 1.2), hold=(0.2, 1.5))
        count = len(knots) // 2
        # Offsets from neutral: shoulder flexion, abduction, rotation, elbow flexion.
        keys = rng.uniform([-20.0, -5.0, -40.0, 0.0], [100.0, 80.0, 60.0, 110.0], (count, 4))
        overhead = rng.random(count) < 0.15
        keys[overhead, 0] = rng.uniform(130.0, 155.0, overhead.sum())
        keys[overhead, 3] = rng.uniform(0.0, 30.0, overhead.sum())
        keys[rng.random(count) < 0.2] = 0.0  # back to rest
        track = _keyframes(t, knots, keys)
        beat = rng.uniform(0.0, 10.0) * np.sin(2.0 * np.pi * rng.uniform(1.0, 2.0) * t + rng.uniform(0.0, 2.0 * np.pi))
        for column, name in enumerate(("shoulder_flex", "shoulder_abd", "shoulder_rot", "elbow_flex")):
            dof[f"{side}_{name}"] = dof[f"{side}_{name}"] + track[:, column]
        dof[f"{side}_elbow_flex"] = dof[f"{side}_elbow_flex"] + np.abs(beat)
    dof["thoracic_twist"] = dof["thoracic_twist"] + _wobble(rng, t, 15.0, 0.4)


_IN_PLACE = {
    "sitting": _sitting,
    "crouching": _crouching,
    "reaching": _reaching,
    "waving": _waving,
    "gesturing": _gesturing,
    "bending": _bending,
}


def _neutral(rng: np.random.Generator, t: np.ndarray) -> dict[str, np.ndarray]:
    """A relaxed upright stance with slow sway, per-sequence posture and idle head movements."""
    dof = {
        "pelvis_pitch": rng.uniform(0.0, 6.0) + _wobble(rng, t, 1.5),
        "pelvis_roll": _wobble(rng, t, 1.5),
        "lumbar_flex": rng.uniform(0.0, 5.0) + _wobble(rng, t, 2.0),
        "lumbar_bend": _wobble(rng, t, 2.0),
        "lumbar_twist": _wobble(rng, t, 3.0),
        "thoracic_flex": rng.uniform(0.0, 5.0) + _wobble(rng, t, 2.0),
        "thoracic_bend": _wobble(rng, t, 2.0),
        "thoracic_twist": _wobble(rng, t, 3.0),
        "neck_flex": rng.uniform(-5.0, 10.0) + _wobble(rng, t, 8.0),
        "neck_bend": _wobble(rng, t, 4.0),
        "neck_twist": _wobble(rng, t, 20.0),
    }
    for side in ("l", "r"):
        dof[f"{side}_hip_abd"] = rng.uniform(2.0, 6.0) + np.zeros_like(t)
        dof[f"{side}_hip_rot"] = rng.uniform(-5.0, 10.0) + np.zeros_like(t)
        dof[f"{side}_shoulder_flex"] = rng.uniform(-5.0, 10.0) + _wobble(rng, t, 3.0)
        dof[f"{side}_shoulder_abd"] = rng.uniform(5.0, 12.0) + _wobble(rng, t, 2.0)
        dof[f"{side}_shoulder_rot"] = rng.uniform(-10.0, 20.0) + np.zeros_like(t)
        dof[f"{side}_elbow_flex"] = rng.uniform(5.0, 25.0) + _wobble(rng, t, 3.0)
    _legs(dof, np.zeros_like(t), rng.uniform(2.0, 8.0) + np.zeros_like(t))
    return dof


@dataclasses.dataclass(frozen=True)
class Motion:
    """One sequence: angles f32[T, D] (degrees, `ANGLE_NAMES`), heading f32[T] (degrees about world z),
    poses f32[T, J, 3] (H36M_17, world mm, floor at z = 0)."""

    angles: np.ndarray
    heading: np.ndarray
    poses: np.ndarray


def sample_motion(
    rng: np.random.Generator, family: str, bone_lengths: np.ndarray, num_frames: int, config: SyntheticConfig
) -> Motion:
    """One sequence of `num_frames` frames at `config.fps` of a motion family, inside the capture area.

    Walking families move the pelvis along a path; the others keep the feet near one spot (the
    pelvis moves back when sitting or bending, as a body does) with a slowly drifting heading.  The
    pelvis height comes from the legs: the lower ankle is put at `ANKLE_HEIGHT_MM` above the floor.
    """
    if family not in MOTION_FAMILIES:
        raise ValueError(f"unknown motion family {family!r}; known: {MOTION_FAMILIES}")
    t = np.arange(num_frames) / config.fps
    dof = _neutral(rng, t)
    # Margins keep the whole body (not only the pelvis) inside the square, and the subject mostly
    # central so that the cameras see it whole, as in a capture studio.
    half = config.capture_area / 2.0
    if family in ("walking", "turning"):
        path, heading = _walk(rng, t, dof, half - min(600.0, half / 2.0), turning=family == "turning")
    else:
        _IN_PLACE[family](rng, t, dof)
        heading = rng.uniform(0.0, 360.0) + _wobble(rng, t, rng.uniform(5.0, 40.0), 0.05)
        spot = rng.uniform(-1.0, 1.0, 2) * max(half - 1000.0, 0.0)
        path = spot + np.stack([_wobble(rng, t, 100.0, 0.05), _wobble(rng, t, 100.0, 0.05)], axis=1)
    # The family formulas aim inside the limits; clipping enforces them for extreme random draws.
    limits = angle_limits()
    angles = np.clip(np.stack([dof[name] for name in ANGLE_NAMES], axis=1), limits[:, 0], limits[:, 1])
    relative = forward_kinematics(angles, heading, bone_lengths)
    feet = [_JOINT["LFoot"], _JOINT["RFoot"]]
    root = np.zeros((num_frames, 3))
    root[:, 2] = ANKLE_HEIGHT_MM - relative[:, feet, 2].min(1)
    root[:, :2] = path if family in ("walking", "turning") else path - relative[:, feet, :2].mean(1)
    poses = relative + root[:, None, :]
    return Motion(angles.astype(np.float32), heading.astype(np.float32), poses.astype(np.float32))


@dataclasses.dataclass(frozen=True)
class SubjectMotion:
    """All sequences of one subject, concatenated: N = config.samples_per_subject rows."""

    bone_lengths: np.ndarray  # f64[J] length of the bone ending at each joint (0 for the root), mm
    angles: np.ndarray  # f32[N, D] degrees, columns ANGLE_NAMES
    heading: np.ndarray  # f32[N] degrees about world z
    poses: np.ndarray  # f32[N, J, 3] world mm
    motion: np.ndarray  # str[N] motion family
    sequence: np.ndarray  # i32[N] sequence index within the subject
    frame: np.ndarray  # i32[N] frame index within the sequence


def simulate_subject(config: SyntheticConfig, subject: int) -> SubjectMotion:
    """The body and motion of subject `subject` (0-based), independent of cameras and detector.

    The samples are split into sequences of about `config.sequence_length` frames, cycling through
    the motion families from a random start, with at least one sequence per family when possible.
    """
    bone_lengths = sample_bone_lengths(_rng(config, _STREAM_BODY, subject))
    rng = _rng(config, _STREAM_MOTION, subject)
    total = config.samples_per_subject
    count = min(total, max(len(MOTION_FAMILIES), round(total / config.sequence_length)))
    lengths = [len(chunk) for chunk in np.array_split(np.arange(total), count)]
    first = rng.integers(len(MOTION_FAMILIES))
    families = [MOTION_FAMILIES[(first + k) % len(MOTION_FAMILIES)] for k in range(count)]
    motions = [sample_motion(rng, family, bone_lengths, length, config) for family, length in zip(families, lengths)]
    return SubjectMotion(
        bone_lengths=bone_lengths,
        angles=np.concatenate([m.angles for m in motions]),
        heading=np.concatenate([m.heading for m in motions]),
        poses=np.concatenate([m.poses for m in motions]),
        motion=np.repeat(np.array(families), lengths),
        sequence=np.repeat(np.arange(count, dtype=np.int32), lengths),
        frame=np.concatenate([np.arange(length, dtype=np.int32) for length in lengths]),
    )


# ----------------------------------------------------------------------------------------------
# Cameras


def _look_at(centers: np.ndarray, targets: np.ndarray, roll_degrees: np.ndarray) -> np.ndarray:
    """World-to-camera rotations [C, 3, 3] of cameras at `centers` looking at `targets` (world z up).

    Rows are the camera axes in world coordinates: x right, y down in the image, z forward.
    """
    forward = targets - centers
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right, axis=-1, keepdims=True)
    down = np.cross(forward, right)
    rotation = np.stack([right, down, forward], axis=-2)
    return _rotation(2, roll_degrees) @ rotation  # roll about the optical axis


def _cameras(K: np.ndarray, R: np.ndarray, centers: np.ndarray) -> Cameras:
    """Float32 numpy `Cameras` from intrinsics, rotations and camera centres (t = -R c)."""
    t = -np.einsum("cij,cj->ci", R, centers)
    return Cameras(K=K.astype(np.float32), R=R.astype(np.float32), t=t.astype(np.float32), dist=None)


def make_rig(rng: np.random.Generator, config: SyntheticConfig) -> Cameras:
    """A Human3.6M-like room: `num_views` cameras [C] around the capture area, looking at its centre.

    Cameras sit on a circle (radius in `camera_distance`, evenly spaced azimuths +-10 degrees) at
    heights in `camera_height`, aimed at about 1 m above the room centre; focal lengths vary a few
    percent, principal points lie near the image centre.  Pinhole (dist None), float32 numpy fields.
    """
    C = config.num_views
    azimuth = rng.uniform(0.0, 2.0 * np.pi) + 2.0 * np.pi * np.arange(C) / C + np.radians(rng.uniform(-10, 10, C))
    radius = rng.uniform(*config.camera_distance, C)
    centers = np.stack([radius * np.cos(azimuth), radius * np.sin(azimuth), rng.uniform(*config.camera_height, C)], 1)
    targets = np.stack([rng.normal(0.0, 150.0, C), rng.normal(0.0, 150.0, C), rng.normal(1000.0, 100.0, C)], 1)
    R = _look_at(centers, targets, rng.normal(0.0, 1.0, C))
    focal = config.focal_length * np.clip(1.0 + rng.normal(0.0, 0.02, C), 0.95, 1.05)
    K = np.zeros((C, 3, 3))
    K[:, 0, 0] = focal
    K[:, 1, 1] = focal * (1.0 + rng.normal(0.0, 0.002, C))  # nearly square pixels
    K[:, :2, 2] = np.asarray(config.image_size, np.float64) / 2.0 + rng.normal(0.0, 8.0, (C, 2))
    K[:, 2, 2] = 1.0
    return _cameras(K, R, centers)


def _jitter_rig(rng: np.random.Generator, rig: Cameras) -> Cameras:
    """One subject's calibration of the room: the cameras moved ~2 cm, turned ~0.5 degrees,
    refocused ~0.5%, as repeated calibrations of one studio differ."""
    R, t, K = (np.asarray(field, np.float64) for field in (rig.R, rig.t, rig.K))
    C = len(K)
    centers = -np.einsum("cji,cj->ci", R, t) + rng.normal(0.0, 20.0, (C, 3))
    tilt = _rotation(0, rng.normal(0.0, 0.5, C)) @ _rotation(1, rng.normal(0.0, 0.5, C))
    R = tilt @ _rotation(2, rng.normal(0.0, 0.5, C)) @ R
    K = K.copy()
    K[:, [0, 1], [0, 1]] *= 1.0 + rng.normal(0.0, 0.005, (C, 1))
    K[:, :2, 2] += rng.normal(0.0, 2.0, (C, 2))
    return _cameras(K, R, centers)


def project_points(rig: Cameras, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`jaxpose.camera.project` of world points [N, J, 3] into a numpy rig [C]: (pixels f64[N, C, J, 2],
    depth f64[N, C, J] in mm).  In float64 on the rig's stored (float32) values, so that the stored
    rig reproduces the clean projections to float32 precision."""
    with jax.enable_x64(True):
        cameras = Cameras(**{name: jnp.asarray(getattr(rig, name), jnp.float64) for name in ("K", "R", "t")}, dist=None)
        points_camera = world_to_camera(cameras, jnp.asarray(points, jnp.float64)[:, None])  # [N, C, J, 3]
        pixels = project_from_camera(cameras, points_camera)
        return np.asarray(pixels), np.asarray(points_camera[..., 2])


# ----------------------------------------------------------------------------------------------
# Detector


def detector_sigma(config: SyntheticConfig) -> np.ndarray:
    """f64[J] per-axis noise standard deviation (px) of each H36M_17 joint under `config`."""
    return config.noise_sigma_scale * np.array([DETECTOR_SIGMA_PX[name] for name in H36M_17.joint_names])


# Confidence = exp(-0.5 (error / (width * sigma))^2) + noise: ~0.85 for typical Gaussian errors,
# ~0 for gross outliers of the torso; a floor of half a pixel keeps noise-free configs finite.
_CONFIDENCE_WIDTH = 2.5
_CONFIDENCE_NOISE = 0.03
_MIN_CONFIDENCE = 0.01  # a detected joint keeps confidence > 0; exactly 0 means missing


@dataclasses.dataclass(frozen=True)
class Detections:
    """Simulated detector output with the ground truth of what went wrong."""

    keypoints2d: np.ndarray  # f32[N, C, J, 2] pixels; 0 where missing
    confidence: np.ndarray  # f32[N, C, J] in [0, 1]; 0 exactly where missing
    outlier: np.ndarray  # bool[N, C, J] gross outlier (not missing)
    swapped: np.ndarray  # bool[N, C] the view's left/right joints were exchanged
    missing: np.ndarray  # bool[N, C, J]


def simulate_detector(rng: np.random.Generator, clean2d: np.ndarray, config: SyntheticConfig) -> Detections:
    """Corrupt exact projections f[N, C, J, 2] (H36M_17 joints) as a 2D pose detector would.

    In order: whole-view left/right swaps (`swap_rate` of views), Gaussian noise of per-axis sigma
    `detector_sigma(config)`, gross outliers (`outlier_rate` of joints, displaced by a distance in
    `outlier_distance` in a random direction), missing joints (`missing_rate`; coordinates and
    confidence 0).  The root stays detected in at least two views of every sample, the minimum
    for triangulating it, so every sample remains usable.  Confidence falls with the error against
    the true joint, so swapped and outlying joints score low.
    """
    N, C, J, _ = clean2d.shape
    sigma = detector_sigma(config)
    swapped = rng.random((N, C)) < config.swap_rate
    detected = np.array(clean2d, np.float64)
    detected[swapped] = detected[swapped][:, H36M_17.flip_permutation()]
    detected += rng.standard_normal((N, C, J, 2)) * sigma[:, None]
    outlier = rng.random((N, C, J)) < config.outlier_rate
    count = int(outlier.sum())
    distance = rng.uniform(*config.outlier_distance, count)
    direction = rng.uniform(0.0, 2.0 * np.pi, count)
    detected[outlier] += distance[:, None] * np.stack([np.cos(direction), np.sin(direction)], axis=-1)
    missing = rng.random((N, C, J)) < config.missing_rate
    root_missing = missing[:, :, 0]
    shortfall = np.maximum(2 - (C - root_missing.sum(1)), 0)
    missing[:, :, 0] &= ~(root_missing & (np.cumsum(root_missing, axis=1) <= shortfall[:, None]))
    error = np.linalg.norm(detected - clean2d, axis=-1)
    width = _CONFIDENCE_WIDTH * np.maximum(sigma, 0.5)
    confidence = np.exp(-0.5 * (error / width) ** 2) + rng.normal(0.0, _CONFIDENCE_NOISE, (N, C, J))
    confidence = np.where(missing, 0.0, np.clip(confidence, _MIN_CONFIDENCE, 1.0))
    detected = np.where(missing[..., None], 0.0, detected)
    return Detections(
        keypoints2d=detected.astype(np.float32),
        confidence=confidence.astype(np.float32),
        outlier=outlier & ~missing,
        swapped=swapped,
        missing=missing,
    )


# ----------------------------------------------------------------------------------------------
# The data set


def generate(config: SyntheticConfig = SyntheticConfig()) -> MultiViewDataset:
    """The synthetic multi-view data set: all subjects, one rig per subject, noisy detections.

    Subjects "S1".."Sn": the first `num_train_subjects` have split "train", the rest "test".  Each
    subject's rig is the shared room (`make_rig`) with its own small calibration jitter.  Labels:
    subject, split, motion, sequence (unique over the data set), frame.
    """
    room = make_rig(_rng(config, _STREAM_ROOM), config)
    keypoints, confidence, targets, rigs = [], [], [], []
    labels: dict[str, list[np.ndarray]] = {name: [] for name in ("subject", "split", "motion", "sequence", "frame")}
    sequence_offset = 0
    for subject in range(config.num_subjects):
        motion = simulate_subject(config, subject)
        rig = _jitter_rig(_rng(config, _STREAM_RIG, subject), room)
        clean, depth = project_points(rig, motion.poses)
        if depth.min() <= 0.0:
            raise ValueError(f"subject {subject}: a joint lies behind a camera; enlarge camera_distance")
        detections = simulate_detector(_rng(config, _STREAM_DETECTOR, subject), clean, config)
        count = len(motion.poses)
        keypoints.append(detections.keypoints2d)
        confidence.append(detections.confidence)
        targets.append(motion.poses)
        rigs.append(rig)
        labels["subject"].append(np.full(count, f"S{subject + 1}"))
        labels["split"].append(np.full(count, "train" if subject < config.num_train_subjects else "test"))
        labels["motion"].append(motion.motion)
        labels["sequence"].append(motion.sequence + sequence_offset)
        labels["frame"].append(motion.frame)
        sequence_offset += int(motion.sequence.max()) + 1
    return MultiViewDataset(
        skeleton=H36M_17,
        keypoints2d=np.concatenate(keypoints),
        confidence=np.concatenate(confidence),
        rigs=Cameras(
            K=np.stack([r.K for r in rigs]), R=np.stack([r.R for r in rigs]), t=np.stack([r.t for r in rigs]), dist=None
        ),
        rig_index=np.repeat(np.arange(config.num_subjects, dtype=np.int32), config.samples_per_subject),
        target3d=np.concatenate(targets),
        labels={name: np.concatenate(values) for name, values in labels.items()},
    )
