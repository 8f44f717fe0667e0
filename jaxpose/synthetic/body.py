"""The simulated body: anatomical joint limits, bone lengths and forward kinematics (H36M_17 joints).

Joint angles are in degrees, columns `ANGLE_NAMES`; left and right limbs use the same anatomical
angle (the right side is mirrored in the kinematics), so `JOINT_LIMITS_DEG` holds one range per
anatomical angle.  The body frame has x forward, y to the subject's left, z up.
"""

from __future__ import annotations

import numpy as np

from jaxpose.skeleton import H36M_17

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

JOINT_INDEX = {name: index for index, name in enumerate(H36M_17.joint_names)}


def sample_bone_lengths(rng: np.random.Generator) -> np.ndarray:
    """f64[J] length of the bone ending at each H36M_17 joint (0 for the root), one subject.

    A global scale (body size, +-9%) times a per-bone factor (+-4%, proportions) shared by the left
    and right bone, so the skeleton is exactly symmetric and within +-14% of `NOMINAL_BONE_MM`.
    """
    scale = rng.uniform(0.91, 1.09)
    lengths = np.zeros(H36M_17.num_joints)
    for name, nominal in NOMINAL_BONE_MM.items():
        if name[0] != "R":  # the right bone copies its left partner's factor below
            lengths[JOINT_INDEX[name]] = nominal * scale * rng.uniform(0.96, 1.04)
    for left, right in H36M_17.left_right_pairs:
        lengths[right] = lengths[left]
    return lengths


def axis_rotation(axis: int, degrees: np.ndarray) -> np.ndarray:
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
    return axis_rotation(1, -flex) @ axis_rotation(0, mirror * abd) @ axis_rotation(2, mirror * rot)


def _trunk_rotation(flex: np.ndarray, bend: np.ndarray, twist: np.ndarray) -> np.ndarray:
    """Joint of a segment pointing along +z (spine, neck): twist, then side bend, then flexion."""
    return axis_rotation(1, flex) @ axis_rotation(0, bend) @ axis_rotation(2, twist)


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
        offset = bone_lengths[JOINT_INDEX[child]] * direction / np.linalg.norm(direction)
        joints[:, JOINT_INDEX[child]] = joints[:, JOINT_INDEX[parent]] + frame @ offset

    pelvis = axis_rotation(2, heading) @ axis_rotation(1, angle["pelvis_pitch"]) @ axis_rotation(0, angle["pelvis_roll"])
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
        shank = thigh @ axis_rotation(1, a["knee_flex"])  # +y rotation swings the shin backward
        upper_arm = thorax @ _limb_rotation(a["shoulder_flex"], a["shoulder_abd"], a["shoulder_rot"], mirror)
        forearm = upper_arm @ axis_rotation(1, -a["elbow_flex"])  # -y rotation swings the forearm forward
        attach(f"{S}Hip", "Hip", pelvis, mirror)
        attach(f"{S}Knee", f"{S}Hip", thigh, mirror)
        attach(f"{S}Foot", f"{S}Knee", shank, mirror)
        attach(f"{S}Shoulder", "Thorax", thorax, mirror)
        attach(f"{S}Elbow", f"{S}Shoulder", upper_arm, mirror)
        attach(f"{S}Wrist", f"{S}Elbow", forearm, mirror)
    return joints
