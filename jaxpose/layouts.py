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

from jaxpose.skeleton import BODY_25_LAYOUT, COCO_17, DETECTOR_LAYOUTS, H36M_17, SKELETONS, DetectorLayout, Skeleton

# OpenPose BODY_25 keypoint order.
OPENPOSE_25_JOINT_NAMES = BODY_25_LAYOUT.joint_names

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
    """A source layout compiled to matrices: coordinates = weights @ sources; `sources` lists each recipe's sources."""

    name: str
    num_sources: int
    weights: np.ndarray  # [num_targets, num_sources]
    sources: np.ndarray  # int [num_targets, K]: each target's sources, the first repeated to fill K

    @classmethod
    def compile(
        cls, name: str, source_names: tuple[str, ...], recipe: dict[str, Combination], target: Skeleton = H36M_17
    ) -> "_Adapter":
        """`recipe[joint]` for every joint of `target`, in terms of `source_names`."""
        weights = np.zeros((target.num_joints, len(source_names)), np.float64)
        for joint, combination in recipe.items():
            for source, weight in combination.items():
                weights[target.index(joint), source_names.index(source)] = weight
        used = [np.flatnonzero(row) for row in weights]
        width = max(len(indices) for indices in used)
        sources = np.array([np.pad(indices, (0, width - len(indices)), mode="edge") for indices in used])
        return cls(name, len(source_names), weights, sources)

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
        # A gather of each target's few sources, not a [..., targets, sources] array: long recordings.
        out_confidence = confidence[..., self.sources].min(axis=-1)
        clean = np.where(present[..., None], keypoints, 0.0)
        out = self.weights @ clean  # a broadcast matmul: a twelfth of np.einsum's time on long recordings
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
    "body25",
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

def halpe26_to_h36m17(keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """HALPE-26 detections -> H36M_17 through their first 17 keypoints, which are COCO-17's."""
    keypoints = np.asarray(keypoints)
    return coco17_to_h36m17(keypoints[..., :17, :], None if scores is None else np.asarray(scores)[..., :17])


FORMATS: dict[str, Converter] = {
    "coco17": coco17_to_h36m17,
    "body25": openpose25_to_h36m17,
    "halpe26": halpe26_to_h36m17,
    "h36m17": h36m17_to_h36m17,
}


def to_h36m17(fmt: str, keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Convert detections in the layout named `fmt` (a key of FORMATS) to H36M_17."""
    try:
        converter = FORMATS[fmt]
    except KeyError:
        raise ValueError(f"unknown keypoint format {fmt!r}; known: {sorted(FORMATS)}") from None
    return converter(keypoints, scores)


# --- Lifting on the detector's own joints (`jaxpose.skeleton.DetectorLayout`) ---------------------------


def _lifting_adapter(name: str, source_names: tuple[str, ...], skeleton: Skeleton, layout: DetectorLayout | None) -> _Adapter:
    recipe = {joint: _point(joint) for joint in skeleton.joint_names}
    if layout is not None and layout.root_from is not None:
        recipe[layout.root] = _mean(*layout.root_from)
    return _Adapter.compile(name, source_names, recipe, skeleton)


# Every detector layout to its lifting skeleton, and every lifting skeleton of `jaxpose.skeleton` to
# itself (e.g. an .npz of Human3.6M's 16 Stacked Hourglass joints), keyed by the layout's name.
_LIFTING: dict[str, _Adapter] = {
    **{
        name: _lifting_adapter(name, layout.joint_names, layout.lifting_skeleton, layout)
        for name, layout in DETECTOR_LAYOUTS.items()
    },
    **{
        name: _lifting_adapter(name, skeleton.joint_names, skeleton, None)
        for name, skeleton in SKELETONS.items()
        if name not in DETECTOR_LAYOUTS
    },
}
LAYOUTS = tuple(sorted(_LIFTING))
"""Every keypoint layout a rig project's detections may be in: detector layouts and jaxpose skeletons."""

# The layout of detector JSON output (OpenPose frames, COCO results) by keypoints per person, where the
# count alone decides it.  25 does not: OpenPose's BODY_25 and BODY_25B both write 25.
_LAYOUT_BY_COUNT = {17: "coco17", 18: "coco18", 26: "halpe26"}


def layout_joint_names(layout: str) -> tuple[str, ...]:
    """The keypoint order of `layout` (a name of `LAYOUTS`)."""
    if layout in DETECTOR_LAYOUTS:
        return DETECTOR_LAYOUTS[layout].joint_names
    return lifting_skeleton(layout).joint_names


def lifting_skeleton(layout: str) -> Skeleton:
    """The skeleton a lifter of detections in `layout` works on: the detector's own joints, root first."""
    if layout in DETECTOR_LAYOUTS:
        return DETECTOR_LAYOUTS[layout].lifting_skeleton
    if layout not in _LIFTING:
        raise ValueError(f"unknown keypoint layout {layout!r}; known: {list(LAYOUTS)}")
    return SKELETONS[layout]


def to_lifting_skeleton(layout: str, keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Detections in `layout` [..., J_layout, 2] (scores [..., J_layout]) -> the `lifting_skeleton`'s
    joints (keypoints f32[..., J, 2], confidence f32[..., J] in [0, 1]).

    A derived root (the hips' midpoint, for layouts without a mid-hip) is only as confident as the
    less confident hip; missing keypoints (score 0, non-finite) get confidence 0 and coordinates 0.
    """
    if layout not in _LIFTING:
        raise ValueError(f"unknown keypoint layout {layout!r}; known: {list(LAYOUTS)}")
    return _LIFTING[layout](keypoints, scores)


def infer_layout(values_per_person: int, where: str, flag: str = "--data.skeleton") -> str:
    """The detector layout of JSON keypoints with `values_per_person` numbers (x, y, score per joint),
    where the count decides it; otherwise a ValueError naming `where`, the candidates and the command's
    `flag` that names the layout."""
    joints, remainder = divmod(values_per_person, 3)
    if remainder == 0 and joints in _LAYOUT_BY_COUNT:
        return _LAYOUT_BY_COUNT[joints]
    if remainder == 0 and joints == 25:
        raise ValueError(
            f"{where}: 75 values per person are OpenPose BODY_25 or BODY_25B (Pose2Sim's default), which the"
            f" count cannot tell apart; pass {flag} body25 or {flag} body25b"
        )
    known = ", ".join(f"{3 * count} ({name})" for count, name in sorted(_LAYOUT_BY_COUNT.items()))
    raise ValueError(
        f"{where}: cannot infer the keypoint layout from {values_per_person} values per person (known: {known},"
        f" 75 (body25 / body25b)); pass {flag} with one of {list(LAYOUTS)}"
    )


MIDHIP_TOLERANCE = 0.1
"""BODY_25's joint 8 (MidHip) lies at the midpoint of its hips (9, 12) to a few pixels; BODY_25B's joint 8
(the right elbow) lies nowhere near the midpoint of its 9 and 12 (left wrist, right hip).  The median, over
poses with the three detected, of that distance divided by the pose's size (its bounding box diagonal)
tells them apart: measured 0.002 on real OpenPose BODY_25 (SPIN's example) and 0.16-0.32 per camera on
Pose2Sim's BODY_25B demo (single poses 0.06-0.44, hence the median over at least `MIDHIP_MIN_POSES`)."""
MIDHIP_MIN_POSES = 3


def check_body25_layout(layout: str, keypoints: np.ndarray, scores: np.ndarray, where: str, flag: str) -> None:
    """Refuse 75-value keypoints named `layout` ("body25" or "body25b") whose joint 8 says otherwise: a
    ValueError naming `where`, the evidence and `flag`.  Other layouts, and input with fewer than
    `MIDHIP_MIN_POSES` poses that detect joints 8, 9 and 12, pass unchecked."""
    if layout not in ("body25", "body25b") or keypoints.shape[-2] != 25:
        return
    points = np.asarray(keypoints, np.float64).reshape(-1, 25, 2)
    seen = (np.asarray(scores).reshape(-1, 25) > 0) & np.isfinite(points).all(-1)
    poses = seen[:, [8, 9, 12]].all(-1) & (seen.sum(-1) >= 4)
    if poses.sum() < MIDHIP_MIN_POSES:  # too little evidence to overrule what the layout was named
        return
    points, seen = points[poses], seen[poses]
    low = np.where(seen[..., None], points, np.inf).min(1)
    high = np.where(seen[..., None], points, -np.inf).max(1)
    size = np.maximum(np.linalg.norm(high - low, axis=-1), 1e-6)
    offset = np.linalg.norm(points[:, 8] - (points[:, 9] + points[:, 12]) / 2, axis=-1) / size
    midhip = float(np.median(offset)) < MIDHIP_TOLERANCE
    if midhip != (layout == "body25"):
        actual = "body25" if midhip else "body25b"
        raise ValueError(
            f"{where}: read as {layout}, but joint 8 is {'' if midhip else 'not '}the midpoint of joints 9 and 12"
            f" (median {np.median(offset):.2f} of the pose's size over {int(poses.sum())} poses): this is {actual.upper()}"
            f" output; pass {flag} {actual}"
        )


def to_skeleton(layout: str, skeleton: Skeleton, keypoints: np.ndarray, scores: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Detections in `layout` as the input of a lifter of `skeleton`: the layout's own lifting skeleton
    (`to_lifting_skeleton`), or H36M_17 through the recipes of this module's docstring (`FORMATS`)."""
    if layout in _LIFTING and lifting_skeleton(layout) == skeleton:
        return to_lifting_skeleton(layout, keypoints, scores)
    if skeleton == H36M_17 and layout in FORMATS:
        return FORMATS[layout](keypoints, scores)
    takes = f"{sorted(FORMATS)}" if skeleton == H36M_17 else f"{[name for name in LAYOUTS if lifting_skeleton(name) == skeleton]}"
    raise ValueError(f"a lifter of skeleton {skeleton.name!r} cannot take keypoints in layout {layout!r}; it takes {takes}")


def layout_of(skeleton: Skeleton) -> str | None:
    """The detector layout whose own joints `skeleton` is (a `<layout>_lifting` skeleton), else None."""
    return next((name for name, layout in DETECTOR_LAYOUTS.items() if layout.lifting_skeleton == skeleton), None)
