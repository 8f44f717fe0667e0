"""Every person of a recording, as the rig loader prepares them: one row per (instant, person).

The instants' people come from the geometry (`jaxpose.rig.association`, from the proposals the loader has
computed already), are joined into tracks over time (`jaxpose.rig.tracks`), and the tracks a person cannot
have made are left out (`plausible`, counted).  Each person kept is numbered k = 1, 2, ... in the order of
first appearance within the recording; their rows carry, in every view, that person's detection (confidence
0 in the views that do not see them) at the instants where two views or more agree on them.

Where one person or none is found, the recording is prepared as before (`jaxpose.rig.people.choose`: the
person the views agree on at every instant, person 1): a recording of one subject and a passer-by too brief
to make a track gives the same rows as it always did.  So does a recording with at most one detection per
view at every instant (a `detections.npz` of one person, Human3.6M written as a project), without the
association and the tracks (loops over the instants in Python, which a project of Human3.6M's size need not pay): there, two
people can only be seen by disjoint views, and the choice keeps the one more views agree on.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxpose.rig import association, people, tracks
from jaxpose.skeleton import Skeleton

# A track is a person only if the detector believed in it: the median score of its detections' keypoints at
# least this.  Two runs of false detections that agree across two views make a figure the geometry cannot
# tell from a person (Pose2Sim's multi-person demo: a body 4.5 m off seen by cameras 1 and 2 only, whose
# keypoints score 0.38 in the median, where the real person's score 0.60); a person the detector sees
# scores above it (OpenPose on that person 0.59-0.65 per camera, the simulated detector 0.7 and more).
MIN_TRACK_SCORE = 0.45


@dataclasses.dataclass(frozen=True)
class TrackedPeople:
    """The prepared rows of one recording: R rows (instant, person), person by person, instants in order."""

    instant: np.ndarray
    """int64[R] the row's instant (an index into the recording's instants)."""
    person: np.ndarray
    """int32[R] the person, 1, 2, ... in order of first appearance."""
    keypoints: np.ndarray
    """f32[R, C, J, 2] undistorted pixels."""
    confidence: np.ndarray
    """f32[R, C, J]: 0 in the views without the person."""
    people: int
    """People kept (1 where the recording is prepared as one person)."""
    implausible_tracks: int
    """Tracks left out because the detector scored them low (`plausible`)."""
    dropped_instants: int
    """Person-instants left out: in tracks too short (`tracks.TrackSettings.min_instants`) or implausible."""
    instants_with_choice: int
    """Instants in which some view had more than one detection."""
    views_without_match: int
    """(instant, view) pairs with detections of which none belongs to a person kept."""


def plausible(scores: np.ndarray) -> bool:
    """Whether a track whose detections' keypoint scores are `scores` (those above 0) is a person: their
    median at least `MIN_TRACK_SCORE`."""
    return bool(len(scores)) and float(np.median(scores)) >= MIN_TRACK_SCORE


def everyone(
    found: people.Proposals, P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, skeleton: Skeleton,
    threshold_px: float, settings: tracks.TrackSettings = tracks.TrackSettings(),
) -> TrackedPeople:
    """Every person of one recording of n instants (the module docstring): `found` their proposals
    (`people.proposals`), P f32[C, 3, 4] the recording's projection matrices (undistorted pixels, world mm),
    keypoints f32[n, C, K, J, 2] undistorted, confidence f32[n, C, K, J], threshold_px the distance the
    proposals were made with (`RigProjectConfig.person_threshold_px`), which completes each person too."""
    n, C, K, J = confidence.shape
    if K == 1:  # one detection per view at every instant: one person, unless the views disagree (the choice's case)
        return _one_person(found, keypoints, confidence, 0, 0)
    detected = (confidence > 0).any(-1)  # [n, C, K]
    with_choice = int((detected.sum(-1) > 1).any(-1).sum())
    instants_people = association.of_proposals(found, P, keypoints, confidence, threshold_px)
    limbs = np.array(skeleton.bones, np.int64).reshape(-1, 2)
    followed = tracks.follow(instants_people.points, instants_people.present, limbs, settings)
    kept = {}  # a plausible track -> its [r, 2] (instant, slot), instants in order
    for t in range(followed.count):
        row = np.argwhere(followed.identity == t)
        detection = instants_people.detection[row[:, 0], row[:, 1]]  # [r, C]
        scores = confidence[row[:, :1], np.arange(C), np.maximum(detection, 0)][detection >= 0]
        if plausible(scores[scores > 0]):
            kept[t] = row
    dropped = followed.dropped + int(np.isin(followed.identity, [t for t in range(followed.count) if t not in kept]).sum())
    if len(kept) <= 1:
        return _one_person(found, keypoints, confidence, followed.count - len(kept), dropped)
    rows = list(kept.values())
    instant = np.concatenate([row[:, 0] for row in rows])
    slot = np.concatenate([row[:, 1] for row in rows])
    person = np.concatenate([np.full(len(row), k + 1, np.int32) for k, row in enumerate(rows)])
    detection = instants_people.detection[instant, slot]  # [R, C]
    seen = detection >= 0
    safe = np.maximum(detection, 0)
    out_keypoints = keypoints[instant[:, None], np.arange(C), safe]
    out_confidence = np.where(seen[..., None], confidence[instant[:, None], np.arange(C), safe], 0.0).astype(np.float32)
    used = np.zeros((n, C, K), bool)
    at, view = np.nonzero(seen)
    used[instant[at], view, detection[at, view]] = True
    return TrackedPeople(
        instant.astype(np.int64), person, out_keypoints.astype(np.float32), out_confidence, len(kept), followed.count - len(kept),
        dropped, with_choice, int((detected.any(-1) & ~used.any(-1)).sum()),
    )  # fmt: skip


def _one_person(found: people.Proposals, keypoints: np.ndarray, confidence: np.ndarray, implausible: int, dropped: int) -> TrackedPeople:
    """The recording as one person's, at every instant (`people.choose`), as it was prepared before several people."""
    n = len(keypoints)
    choice = people.choose(found, keypoints, confidence)
    return TrackedPeople(
        np.arange(n), np.ones(n, np.int32), choice.keypoints, choice.confidence, 1, implausible, dropped,
        choice.instants_with_choice, choice.views_without_match,
    )  # fmt: skip
