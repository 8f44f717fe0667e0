"""Simulated motion: smooth joint-angle signals, walking paths and the motion families."""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxpose.synthetic.body import ANGLE_NAMES, JOINT_INDEX, angle_limits, forward_kinematics, sample_bone_lengths
from jaxpose.synthetic.config import Stream, SyntheticConfig, stream_rng

MOTION_FAMILIES = ("walking", "turning", "sitting", "crouching", "reaching", "waving", "gesturing", "bending")

# Walkers slow down in tight turns to keep their lateral acceleration below this (mm/s^2): it
# bounds the turning rate and the lean into the turn (atan(1.5 / 9.81) ~ 9 degrees).
_MAX_TURN_ACCELERATION = 1500.0

# The "Foot" joint is the ankle: the lower ankle of a pose sits this high above the floor.
ANKLE_HEIGHT_MM = 80.0


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
    feet = [JOINT_INDEX["LFoot"], JOINT_INDEX["RFoot"]]
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
    bone_lengths = sample_bone_lengths(stream_rng(config, Stream.BODY, subject))
    rng = stream_rng(config, Stream.MOTION, subject)
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
