"""A metric, upright world for a recovered rig, from the person it films.

A rig recovered from the person (`jaxpose.calibration.calibrate`) lives in view 0's camera frame,
scaled by a generic limb prior.  Gravity, the floor and the subject's size are in the recording too:

- **Up** is the normal of the floor the feet stand on: in every frame the lower ankle is taken as the
  foot in contact, and a plane is fitted to those positions (robustly: a lifted foot, a jump or a
  bad triangulation is down-weighted).  That plane is only defined when the contacts spread over the
  floor (the subject walks about): when they do not (`MIN_CONTACT_SPREAD_MM`), up is the subject's
  body axis instead, from the ankles' midpoint to the shoulders' midpoint, averaged over the frames
  where the subject stands upright (the standing leg straight, the trunk along that axis).  Gravity is minus up.
- **The floor** lies `ankle_height_mm` below the plane of the ankles in contact.  The ankle joint
  centre (the lateral malleolus) of an adult stands 0.039 of their height above the floor (Winter,
  Biomechanics and Motor Control of Human Movement, segment-length table): 62-76 mm for 1.60-1.95 m.
  The default is `DEFAULT_ANKLE_HEIGHT_MM` (70 mm, a 1.80 m adult); with the subject's height given,
  0.039 of it; any value the user measured overrides both.
- **The scale**, in this order of preference: the subject's height (Pose2Sim's `participant_height`),
  their limb lengths, or the rig's own scale (a rig from `calibrate` carries the limb prior's).
  A height maps to the skeleton through the shoulders: standing, they are 0.818 of the subject's
  height above the floor (Winter's table; every skeleton has shoulders, and unlike the eyes or a head
  top they do not move when the head pitches).  Their height above the ankles when standing straight
  is measured as lengths, not heights, so that walking, sitting or leaning do not lower it: shank +
  thigh + trunk (the hips' to the shoulders' midpoint, over the upright frames), each a median; the
  scale makes it 0.818 of the given height minus the ankle height.  A subject, or a detector's
  shoulder keypoint, off the table by x% gives a scale off by about x% (a keypoint marked 3 cm below
  the acromion: about 2%).
- **The axes**, OpenSim's: +Y up, +X the direction the subject faces over the first frames
  (`start_frames`), +Z to their right (X x Y); the origin on the floor below the subject's mean hip
  position over those frames; millimetres.  `WORLD_FRAME` says it in one line, for files.

`world_frame` returns the similarity X_world = scale R X_rig + t (`WorldFrame`); `points_to_world`
and `cameras_to_world` apply it, `to_world` to a recovered rig, which then names its world.  numpy, float64; pure functions of their inputs.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Literal

import numpy as np

from jaxpose.calibration.scale import body_part, metric_scale
from jaxpose.camera import Cameras
from jaxpose.skeleton import Skeleton

if TYPE_CHECKING:
    from jaxpose.calibration import Calibration

WORLD_FRAME = (
    "upright world from the person: origin on the floor below the subject's mean hip position over the first"
    " frames, +Y up (OpenSim's convention), +X the subject's facing direction then, +Z to their right; millimetres"
)
ANKLE_HEIGHT_FRACTION = 0.039
DEFAULT_ANKLE_HEIGHT_MM = 70.0
# The shoulders' height above the floor when standing, as a fraction of the subject's height (Winter).
SHOULDER_HEIGHT_FRACTION = 0.818
# The ankles in contact must spread at least this much (rig units ~ mm, standard deviation across
# their principal direction) for the floor's tilt to be measured: a subject walking a 1 m circle spreads
# them ~350 mm; one standing still, or walking a straight line, far less.
MIN_CONTACT_SPREAD_MM = 150.0
# Upright: the standing leg's knee within this angle (degrees) of straight, and the trunk and the ankles-to-
# shoulders axis within UPRIGHT_TILT_DEG of up.
STRAIGHT_KNEE_DEG = 20.0
UPRIGHT_TILT_DEG = 15.0
# Fewest frames the estimates are made on.
MIN_FRAMES = 10


@dataclasses.dataclass(frozen=True)
class WorldFrame:
    """The similarity from a rig's frame to the upright metric world: X_world = scale R X_rig + t."""

    scale: float
    """mm per rig unit."""
    R: np.ndarray
    """f64[3, 3] rotation; its rows are the world's X (forward), Y (up) and Z (right) axes in rig coordinates."""
    t: np.ndarray
    """f64[3] mm."""
    up_source: Literal["floor", "body"]
    """Where up came from: the floor the ankles stand on, or the subject's body axis (too little floor covered)."""
    scale_source: Literal["height", "limbs", "rig"]
    ankle_height_mm: float
    body_axis_deg: float
    """Angle between the body-axis estimate of up and the one used (0 when up is the body axis)."""
    contact_spread: float
    """The ankles' spread over the floor across its principal direction (rig units)."""
    contact_frames: int
    """Frames whose lower ankle the floor was fitted to (after down-weighting)."""
    upright_frames: int


def points_to_world(frame: WorldFrame, points: np.ndarray) -> np.ndarray:
    """Rig points f[..., 3] -> f64[..., 3] world mm."""
    return frame.scale * np.asarray(points, np.float64) @ frame.R.T + frame.t


def cameras_to_world(frame: WorldFrame, cameras: Cameras) -> Cameras:
    """The same cameras [...] in the world: x_cam = R' X_world + t' with R' = R_cam R^T, t' = scale t_cam - R' t
    (camera coordinates, and t, in world mm); K and the lens unchanged.  numpy float64 fields."""
    R = np.asarray(cameras.R, np.float64) @ frame.R.T
    t = frame.scale * np.asarray(cameras.t, np.float64) - np.einsum("...ij,j->...i", R, frame.t)
    return cameras.replace(K=np.asarray(cameras.K, np.float64), R=R, t=t)


def to_world(frame: WorldFrame, calibration: "Calibration") -> "Calibration":
    """A recovered rig (`jaxpose.calibration.Calibration`, in view 0's camera frame) moved into the upright
    world `frame`, which it then names (`Calibration.world`)."""
    if calibration.world is not None:
        raise ValueError("the rig is already in the upright world: moving it again would move it twice")
    return dataclasses.replace(calibration, cameras=cameras_to_world(frame, calibration.cameras), world=frame)


def world_frame(
    points: np.ndarray,
    valid: np.ndarray,
    skeleton: Skeleton,
    *,
    height_mm: float | None = None,
    limb_lengths_mm: tuple[float, float, float, float] | None = None,
    ankle_height_mm: float | None = None,
    start_frames: int = 50,
) -> WorldFrame:
    """The upright metric world of one recording (see the module docstring).

    points f[T, J, 3] the subject's joints in the rig's frame (a rig from `calibrate`: mm at the limb
    prior's scale); valid bool[T, J] the well-triangulated ones.  height_mm: the subject's height;
    limb_lengths_mm: their upper arm, forearm, thigh and shank (`jaxpose.calibration.scale.LIMBS`),
    used when no height is given; neither: the rig's scale is kept.  start_frames: how many of the
    first frames that see the hips set the origin and the facing direction.
    """
    points = np.asarray(points, np.float64)
    valid = np.asarray(valid, bool) & np.all(np.isfinite(points), -1)
    if points.ndim != 3 or points.shape[1:] != (skeleton.num_joints, 3) or valid.shape != points.shape[:2]:
        raise ValueError(
            f"world_frame: points must be [T, {skeleton.num_joints}, 3] and valid [T, {skeleton.num_joints}]"
            f" ({skeleton.name}), got {points.shape} and {valid.shape}"
        )
    joints = _body_joints(skeleton)
    ankles, ankles_ok = _midpoint(points, valid, joints["ankle"])
    shoulders, shoulders_ok = _midpoint(points, valid, joints["shoulder"])
    hips, hips_ok = _midpoint(points, valid, joints["hip"])

    # The body axis: a first up, and the upright frames.
    axis_ok = ankles_ok & shoulders_ok
    if axis_ok.sum() < MIN_FRAMES:
        raise ValueError(f"world_frame: only {axis_ok.sum()} frames see both ankles and shoulders; needs {MIN_FRAMES}")
    axis = _unit(shoulders - ankles)
    body_up = _mean_direction(axis[axis_ok])
    upright = _upright(points, valid, joints, axis, axis_ok, hips, hips_ok, shoulders, body_up)
    for _ in range(3):  # sitting or bending frames pull the first mean away from the upright ones
        if upright.sum() < MIN_FRAMES:
            break
        body_up = _mean_direction(axis[upright])
        upright = _upright(points, valid, joints, axis, axis_ok, hips, hips_ok, shoulders, body_up)

    # The floor: a plane through the lower ankle of every frame.
    contacts = _lower_ankles(points, valid, joints["ankle"], body_up)
    if len(contacts) < MIN_FRAMES:
        raise ValueError(f"world_frame: only {len(contacts)} frames see an ankle; needs {MIN_FRAMES}")
    normal, ankle_level, weights, spread = _fit_plane(contacts, body_up)
    # The spread is judged in rig units, i.e. mm at the rig's own scale (a rig from `calibrate` is
    # within ~10% of metric): the floor's tilt needs contacts over a wide enough patch of floor.
    if spread >= MIN_CONTACT_SPREAD_MM:
        up, up_source = normal, "floor"
    else:  # too little floor seen to tilt it: up is the body axis, the ankles' level along it
        up, up_source = body_up, "body"
        ankle_level = float(np.median(contacts @ up))

    # The scale, then the floor below the ankles, in rig units.
    if height_mm is not None:
        if not height_mm > 0:
            raise ValueError(f"world_frame: the subject's height must be positive, got {height_mm} mm")
        ankle = ANKLE_HEIGHT_FRACTION * height_mm if ankle_height_mm is None else ankle_height_mm
        above_ankles = _standing_shoulder_height(points, valid, joints, hips, shoulders, upright & hips_ok & shoulders_ok)
        scale = (SHOULDER_HEIGHT_FRACTION * height_mm - ankle) / above_ankles
        scale_source = "height"
    else:
        ankle = DEFAULT_ANKLE_HEIGHT_MM if ankle_height_mm is None else ankle_height_mm
        if limb_lengths_mm is not None:
            scale, scale_source = metric_scale(points, valid, skeleton, limb_lengths_mm).mm_per_unit, "limbs"
        else:
            scale, scale_source = 1.0, "rig"
    floor_level = ankle_level - ankle / scale

    # The axes and the origin, from the subject's hips over the first frames.
    first = np.flatnonzero(hips_ok)[:start_frames]
    if not len(first):
        raise ValueError("world_frame: no frame sees both hips, which set the origin and the facing direction")
    left = points[first][:, joints["hip"][0]] - points[first][:, joints["hip"][1]]
    forward = _unit(np.cross(left.mean(0), up))
    R = np.stack([forward, up, np.cross(forward, up)])
    centre = hips[first].mean(0)
    origin = centre - (centre @ up - floor_level) * up
    return WorldFrame(
        scale=float(scale),
        R=R,
        t=-scale * R @ origin,
        up_source=up_source,
        scale_source=scale_source,
        ankle_height_mm=float(ankle),
        body_axis_deg=float(np.degrees(np.arccos(np.clip(body_up @ up, -1.0, 1.0)))),
        contact_spread=float(spread),
        contact_frames=int(np.sum(weights > 0.5)),
        upright_frames=int(upright.sum()),
    )


def _body_joints(skeleton: Skeleton) -> dict[str, tuple[int, int]]:
    """Body part -> (left, right) joint indices, for the parts both sides of the skeleton have."""
    parts = {body_part(name): index for index, name in enumerate(skeleton.joint_names)}
    joints = {}
    for part in ("ankle", "foot", "knee", "hip", "shoulder"):
        if ("l", part) in parts and ("r", part) in parts:
            joints.setdefault("ankle" if part == "foot" else part, (parts["l", part], parts["r", part]))
    missing = [part for part in ("ankle", "hip", "shoulder") if part not in joints]
    if missing:
        raise ValueError(f"world_frame: skeleton {skeleton.name!r} has no left and right {missing}")
    return joints


def _midpoint(points: np.ndarray, valid: np.ndarray, pair: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(f64[T, 3] the midpoint of a left/right pair, bool[T] where both are valid)."""
    return 0.5 * (points[:, pair[0]] + points[:, pair[1]]), valid[:, pair[0]] & valid[:, pair[1]]


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-12)


def _angle_deg(vectors: np.ndarray, direction: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(_unit(vectors) @ direction, -1.0, 1.0)))


def _mean_direction(directions: np.ndarray) -> np.ndarray:
    """The mean of unit vectors [N, 3], trimmed twice to those within 30 degrees of it (robust to bad frames)."""
    mean = _unit(directions.mean(0))
    for _ in range(2):
        close = _angle_deg(directions, mean) < 30.0
        if close.any():
            mean = _unit(directions[close].mean(0))
    return mean


def _upright(points, valid, joints, axis, axis_ok, hips, hips_ok, shoulders, up) -> np.ndarray:
    """bool[T]: the standing leg's knee straight (the leg of the lower ankle, where the skeleton has
    knees), trunk and body axis within UPRIGHT_TILT_DEG of up."""
    upright = axis_ok & hips_ok & (_angle_deg(axis, up) < UPRIGHT_TILT_DEG)
    upright &= _angle_deg(shoulders - hips, up) < UPRIGHT_TILT_DEG
    if "knee" in joints:
        straight = []
        for side in (0, 1):
            hip, knee, ankle = (points[:, joints[part][side]] for part in ("hip", "knee", "ankle"))
            bend = 180.0 - np.degrees(np.arccos(np.clip(np.sum(_unit(hip - knee) * _unit(ankle - knee), -1), -1.0, 1.0)))
            seen = valid[:, joints["hip"][side]] & valid[:, joints["knee"][side]] & valid[:, joints["ankle"][side]]
            straight.append(seen & (bend < STRAIGHT_KNEE_DEG))
        left_lower = points[:, joints["ankle"][0]] @ up < points[:, joints["ankle"][1]] @ up
        upright &= np.where(left_lower, straight[0], straight[1])
    return upright


def _standing_shoulder_height(points, valid, joints, hips, shoulders, upright) -> float:
    """The shoulders' height above the ankles when standing straight (rig units): shank + thigh + trunk
    (hips' to shoulders' midpoint), each the median of its lengths, the trunk's over the upright frames
    (a bent spine shortens it).  Lengths, not heights: walking, sitting or leaning do not shorten them."""
    if "knee" not in joints:
        raise ValueError("world_frame: a height needs a skeleton with knees (shank and thigh lengths)")
    if upright.sum() < MIN_FRAMES:
        raise ValueError(
            f"world_frame: the subject stands upright in only {upright.sum()} frames; a height needs"
            f" {MIN_FRAMES} (give limb lengths instead)"
        )
    legs = 0.0
    for upper, lower in (("hip", "knee"), ("knee", "ankle")):
        lengths = [
            np.linalg.norm(points[:, joints[upper][side]] - points[:, joints[lower][side]], axis=-1)[
                valid[:, joints[upper][side]] & valid[:, joints[lower][side]]
            ]
            for side in (0, 1)
        ]
        legs += float(np.median(np.concatenate(lengths)))
    return legs + float(np.median(np.linalg.norm(shoulders - hips, axis=-1)[upright]))


def _lower_ankles(points: np.ndarray, valid: np.ndarray, ankles: tuple[int, int], up: np.ndarray) -> np.ndarray:
    """f64[N, 3] the lower ankle (along up) of every frame that sees one (the foot on the floor)."""
    position = points[:, list(ankles)]  # [T, 2, 3]
    height = np.where(valid[:, list(ankles)], position @ up, np.inf)
    lower = np.argmin(height, axis=1)
    seen = np.isfinite(height.min(1))
    return position[np.arange(len(points)), lower][seen]


def _fit_plane(contacts: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float, np.ndarray, float]:
    """A plane through the contact points, robust to lifted feet: (unit normal along up, its level n.x,
    the points' weights, their spread across the principal direction in the plane).

    Iteratively re-weighted principal components with Tukey's biweight on the distances to the plane
    (scale 1.4826 x their median absolute deviation, at least 1% of the points' spread, so that exact
    data do not divide by zero)."""
    normal = up
    weights = np.ones(len(contacts))
    for _ in range(8):
        centre = np.sum(weights[:, None] * contacts, 0) / np.sum(weights)
        offsets = contacts - centre
        covariance = (weights[:, None] * offsets).T @ offsets / np.sum(weights)
        eigenvalues, eigenvectors = np.linalg.eigh(covariance)
        normal = eigenvectors[:, 0] * np.sign(eigenvectors[:, 0] @ up)
        distance = offsets @ normal
        mad = np.median(np.abs(distance - np.median(distance)))
        sigma = max(1.4826 * mad, 0.01 * np.sqrt(eigenvalues[1]), 1e-9)
        weights = np.clip(1.0 - (distance / (4.685 * sigma)) ** 2, 0.0, None) ** 2
    return normal, float(centre @ normal), weights, float(np.sqrt(eigenvalues[1]))
