"""Adapters from 2D detector layouts (COCO-17, OpenPose BODY_25) to the H36M_17 lifting skeleton.

Every H36M_17 joint is a fixed linear combination of source keypoints (a "recipe"), applied to the
coordinates; its confidence is the MIN of the confidences of the sources the recipe uses, so a
constructed joint is only as trustworthy as its weakest source.  numpy in, numpy (float32) out; any
leading batch axes.

Missing keypoints.  A source keypoint is missing when its score is not > 0 (score 0 is the detectors'
"not found") or when its coordinates are not finite.  An output joint with any missing source gets
confidence 0 and coordinates (0, 0), never NaN, so downstream code can rely on the confidence alone.
Confidences are clipped to [0, 1] (docs/conventions.md); `scores=None` means every finite keypoint
has confidence 1.

Correspondences and approximations (H36M_17 joint <- source), with the reasons:
- RHip/LHip, RKnee/LKnee, R/LShoulder, R/LElbow, R/LWrist: the detector's joint of the same name.
  Detector hips are annotated a little higher and wider than Human3.6M's hip-joint centres; that
  offset is systematic, and a lifter trained on these detections absorbs it.
- RFoot/LFoot <- ankles: Human3.6M's "Foot" joint is the ankle.
- Hip (pelvis, the root) <- mean of the two hips, in both formats.  Human3.6M's pelvis is the
  midpoint of its hip joints, and building the root from the very hips the lifter sees keeps them
  symmetric about it.  OpenPose's own MidHip is deliberately not used, for that reason.
- Thorax: COCO <- mean of the shoulders.  OpenPose <- its Neck keypoint, which OpenPose's training
  labels define as that same shoulder midpoint; being detected directly, it survives one occluded
  shoulder (common in side views), and Human3.6M's thorax is not exactly the shoulder midpoint
  anyway (it sits slightly higher, at the base of the neck), so no exact identity is lost.
- Spine <- the point SPINE_FRACTION of the way from pelvis to thorax: Human3.6M's spine joint lies
  about halfway up the torso (its pelvis-spine and spine-thorax bones have similar lengths).
- Neck/Nose <- nose: despite its name, this Human3.6M joint lies at the lower face, near the nose.
- Head (top of head) <- extrapolated along the line from the nose through the midpoint of the eyes:
  `nose + HEAD_EXTRAPOLATION * (eye_midpoint - nose)`.  That line points up the face in a frontal
  view and up-and-back in a profile view, as the real head top does, and the factor turns the nose
  to eye-line distance (~35-40 mm) into the Neck/Nose-to-Head distance of Human3.6M (~110-120 mm).
  The ears are not used: their midpoint is about level with the eyes, so it gives no "up".
  Unreliable for a back view, where nose and eyes are missing; the confidence then goes to 0.
- OpenPose's feet (toes, heels) and COCO/OpenPose ears are not used.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from jaxpose.skeleton import COCO_17, H36M_17

# OpenPose BODY_25 keypoint order.
OPENPOSE_25_JOINT_NAMES = (
    "Nose", "Neck", "RShoulder", "RElbow", "RWrist", "LShoulder", "LElbow", "LWrist", "MidHip",
    "RHip", "RKnee", "RAnkle", "LHip", "LKnee", "LAnkle", "REye", "LEye", "REar", "LEar",
    "LBigToe", "LSmallToe", "LHeel", "RBigToe", "RSmallToe", "RHeel",
)

# Where the spine joint sits on the pelvis -> thorax segment (see module docstring).
SPINE_FRACTION = 0.5
# Head top = nose + HEAD_EXTRAPOLATION * (eye midpoint - nose) (see module docstring).
HEAD_EXTRAPOLATION = 3.0

# A recipe for one output joint: source joint name -> weight (the weights sum to 1).
Combination = dict[str, float]


def _point(name: str) -> Combination:
    return {name: 1.0}


def _mean(*names: str) -> Combination:
    return {name: 1.0 / len(names) for name in names}


def _lerp(a: Combination, b: Combination, fraction: float) -> Combination:
    """(1 - fraction) * a + fraction * b; a fraction outside [0, 1] extrapolates."""
    combined: Combination = {}
    for weight, terms in ((1.0 - fraction, a), (fraction, b)):
        for name, term_weight in terms.items():
            combined[name] = combined.get(name, 0.0) + weight * term_weight
    return combined


# H36M_17 joints copied from a detector joint, keyed by the role names used in `_h36m17_recipe`.
_DIRECT_ROLES = (
    "RHip", "RKnee", "RFoot", "LHip", "LKnee", "LFoot",
    "LShoulder", "LElbow", "LWrist", "RShoulder", "RElbow", "RWrist",
)


def _h36m17_recipe(source: dict[str, str], thorax: Combination) -> dict[str, Combination]:
    """The H36M_17 recipe of a detector whose joint for each role (H36M name, or Nose/LEye/REye) is `source[role]`."""
    recipe = {role: _point(source[role]) for role in _DIRECT_ROLES}
    pelvis = _mean(source["LHip"], source["RHip"])
    nose = _point(source["Nose"])
    recipe.update({
        "Hip": pelvis,
        "Spine": _lerp(pelvis, thorax, SPINE_FRACTION),
        "Thorax": thorax,
        "Neck/Nose": nose,
        "Head": _lerp(nose, _mean(source["LEye"], source["REye"]), HEAD_EXTRAPOLATION),
    })
    return recipe


@dataclasses.dataclass(frozen=True)
class _Adapter:
    """A source layout compiled to matrices: coordinates = weights @ sources; `uses` marks each recipe's sources."""

    name: str
    num_sources: int
    weights: np.ndarray  # [17, num_sources]
    uses: np.ndarray  # bool [17, num_sources]

    @classmethod
    def compile(cls, name: str, source_names: tuple[str, ...], recipe: dict[str, Combination]) -> "_Adapter":
        weights = np.zeros((H36M_17.num_joints, len(source_names)), np.float64)
        for joint, combination in recipe.items():
            for source, weight in combination.items():
                weights[H36M_17.index(joint), source_names.index(source)] = weight
        return cls(name, len(source_names), weights, weights != 0.0)

    def __call__(self, keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        keypoints = np.asarray(keypoints, np.float64)
        if keypoints.ndim < 2 or keypoints.shape[-2:] != (self.num_sources, 2):
            raise ValueError(
                f"{self.name}: expected keypoints of shape [..., {self.num_sources}, 2], got {keypoints.shape}"
            )
        scores = np.ones(keypoints.shape[:-1]) if scores is None else np.asarray(scores, np.float64)
        if scores.shape != keypoints.shape[:-1]:
            raise ValueError(
                f"{self.name}: expected scores of shape {keypoints.shape[:-1]} (the keypoints' shape "
                f"[..., {self.num_sources}] without the coordinate axis), got {scores.shape}"
            )
        # NaN compares False, so a NaN score counts as missing too.
        present = (scores > 0.0) & np.isfinite(keypoints).all(axis=-1)
        confidence = np.where(present, np.clip(scores, 0.0, 1.0), 0.0)
        # Every recipe uses at least one source, so the +inf filler never survives the min.
        out_confidence = np.where(self.uses, confidence[..., None, :], np.inf).min(axis=-1)
        clean = np.where(present[..., None], keypoints, 0.0)
        out = np.einsum("jn,...nc->...jc", self.weights, clean)
        out = np.where(out_confidence[..., None] > 0.0, out, 0.0)
        return out.astype(np.float32), out_confidence.astype(np.float32)


_COCO17 = _Adapter.compile(
    "coco17",
    COCO_17.joint_names,
    _h36m17_recipe(
        {
            "RHip": "right_hip", "RKnee": "right_knee", "RFoot": "right_ankle",
            "LHip": "left_hip", "LKnee": "left_knee", "LFoot": "left_ankle",
            "LShoulder": "left_shoulder", "LElbow": "left_elbow", "LWrist": "left_wrist",
            "RShoulder": "right_shoulder", "RElbow": "right_elbow", "RWrist": "right_wrist",
            "Nose": "nose", "LEye": "left_eye", "REye": "right_eye",
        },
        thorax=_mean("left_shoulder", "right_shoulder"),
    ),
)

_OPENPOSE25 = _Adapter.compile(
    "openpose25",
    OPENPOSE_25_JOINT_NAMES,
    _h36m17_recipe(
        {
            "RHip": "RHip", "RKnee": "RKnee", "RFoot": "RAnkle",
            "LHip": "LHip", "LKnee": "LKnee", "LFoot": "LAnkle",
            "LShoulder": "LShoulder", "LElbow": "LElbow", "LWrist": "LWrist",
            "RShoulder": "RShoulder", "RElbow": "RElbow", "RWrist": "RWrist",
            "Nose": "Nose", "LEye": "LEye", "REye": "REye",
        },
        thorax=_point("Neck"),
    ),
)

_H36M17 = _Adapter.compile("h36m17", H36M_17.joint_names, {name: _point(name) for name in H36M_17.joint_names})


def coco17_to_h36m17(keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """COCO-17 detections (`jaxpose.skeleton.COCO_17` order) -> H36M_17.

    keypoints [..., 17, 2] (pixels), scores [..., 17] (0 = missing; None = all 1) ->
    (keypoints f32[..., 17, 2], confidence f32[..., 17]).  See the module docstring for the mapping.
    """
    return _COCO17(keypoints, scores)


def openpose25_to_h36m17(keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """OpenPose BODY_25 detections (`OPENPOSE_25_JOINT_NAMES` order) -> H36M_17.

    keypoints [..., 25, 2] (pixels), scores [..., 25] (0 = missing; None = all 1) ->
    (keypoints f32[..., 17, 2], confidence f32[..., 17]).  See the module docstring for the mapping.
    """
    return _OPENPOSE25(keypoints, scores)


def h36m17_to_h36m17(keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Identity on H36M_17 detections, with the same validation and missing-joint cleanup as the others."""
    return _H36M17(keypoints, scores)


Converter = Callable[[np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray]]

FORMATS: dict[str, Converter] = {
    "coco17": coco17_to_h36m17,
    "openpose25": openpose25_to_h36m17,
    "h36m17": h36m17_to_h36m17,
}


def to_h36m17(fmt: str, keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Convert detections in the layout named `fmt` (a key of FORMATS) to H36M_17."""
    try:
        converter = FORMATS[fmt]
    except KeyError:
        raise ValueError(f"unknown keypoint format {fmt!r}; known: {sorted(FORMATS)}") from None
    return converter(keypoints, scores)
