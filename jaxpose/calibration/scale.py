"""Metric scale of a recovered rig from the person's limbs.

Two views fix a rig only up to scale.  The person supplies it: the limbs between joint centres
(upper arm, forearm, thigh, shank) vary little between adults, and unlike the torso and head they
mean the same thing for every detector's joint set (a Stacked Hourglass "Spine" is not a mocap
spine; a shoulder is a shoulder).  The rig is scaled so that the median length of each limb over
the calibration frames matches the prior, taking the geometric mean over the four limbs.

The default prior is of an adult of average build: 290 mm upper arm, 260 mm forearm, 450 mm thigh,
440 mm shank.  A child, or a subject whose limbs you measured, needs `--limb-lengths-mm`; the scale
error then follows the prior's error one to one (a subject 5% smaller than the prior gives a rig 5%
too large).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxpose.skeleton import Skeleton

LIMBS = ("upper arm", "forearm", "thigh", "shank")
DEFAULT_LIMB_LENGTHS_MM = (290.0, 260.0, 450.0, 440.0)
# Joint-name stems at each limb's ends (after `body_part`), so that H36M's "LFoot" (its ankle marker),
# HumanEva's "LAnkle" and COCO's "left_ankle" all match.
_LIMB_ENDS = {
    "upper arm": (("shoulder",), ("elbow",)),
    "forearm": (("elbow",), ("wrist",)),
    "thigh": (("hip",), ("knee",)),
    "shank": (("knee",), ("ankle", "foot")),
}


def body_part(joint_name: str) -> tuple[str, str]:
    """('l' | 'r' | '', lower-case body part) of a joint name: "LElbow", "left_elbow" -> ('l', 'elbow')."""
    name = joint_name.lower().replace("_", "")
    for prefix, side in (("left", "l"), ("right", "r"), ("l", "l"), ("r", "r")):
        if name.startswith(prefix):
            return side, name[len(prefix):]
    return "", name


def limb_joints(skeleton: Skeleton) -> dict[str, list[tuple[int, int]]]:
    """Limb -> the (joint, joint) index pairs of the skeleton that form it (left and right)."""
    parts = {body_part(name): index for index, name in enumerate(skeleton.joint_names)}
    limbs = {}
    for limb, (starts, ends) in _LIMB_ENDS.items():
        pairs = []
        for side in ("l", "r"):
            start = next((parts[side, s] for s in starts if (side, s) in parts), None)
            end = next((parts[side, e] for e in ends if (side, e) in parts), None)
            if start is not None and end is not None:
                pairs.append((start, end))
        if pairs:
            limbs[limb] = pairs
    return limbs


@dataclasses.dataclass(frozen=True)
class MetricScale:
    """The factor from rig units to millimetres, and what it was measured on."""

    mm_per_unit: float
    measured_mm: dict[str, float]
    """Each limb's median length after scaling (mm)."""
    prior_mm: dict[str, float]


def metric_scale(
    points: np.ndarray, reliable: np.ndarray, skeleton: Skeleton, limb_lengths_mm=DEFAULT_LIMB_LENGTHS_MM
) -> MetricScale:
    """Scale from joints f[F, J, 3] (rig units), where reliable bool[F, J] marks well-triangulated ones."""
    prior = dict(zip(LIMBS, map(float, limb_lengths_mm)))
    medians = {}
    for limb, pairs in limb_joints(skeleton).items():
        lengths = np.concatenate([
            np.linalg.norm(points[:, a] - points[:, b], axis=-1)[reliable[:, a] & reliable[:, b]] for a, b in pairs
        ])  # fmt: skip
        if len(lengths):
            medians[limb] = float(np.median(lengths))
    if not medians:
        raise ValueError(
            f"skeleton {skeleton.name!r}: no limb ({', '.join(LIMBS)}) is reliably triangulated, so the rig's scale"
            " cannot be set from the body"
        )
    mm_per_unit = float(np.exp(np.mean([np.log(prior[limb] / length) for limb, length in medians.items()])))
    return MetricScale(
        mm_per_unit, {limb: length * mm_per_unit for limb, length in medians.items()}, {limb: prior[limb] for limb in medians}
    )


def prior_scale_error(points_mm: np.ndarray, skeleton: Skeleton, limb_lengths_mm=DEFAULT_LIMB_LENGTHS_MM) -> float:
    """The scale error that the prior makes for a body of known joints f[F, J, 3] (mm): a perfect
    calibration scaled by `metric_scale` is off by this much (prior / true limb length - 1, averaged
    as `metric_scale` averages)."""
    reference = metric_scale(points_mm, np.ones(points_mm.shape[:2], bool), skeleton, limb_lengths_mm)
    return reference.mm_per_unit - 1.0
