"""Which detections in which views are the same person, at each instant, from the geometry alone.

`jaxpose.rig.people.proposals` gives, for every pair of views and every pair of their detections, a 3D
person triangulated from those two, each view's detection nearest to its projection (the median over
joints of the pixel distance) and whether it lies within `threshold_px`.  Here the people of an instant
are taken from those proposals greedily, most views first, then the cheapest:

- a proposal counts when its two seed detections are each other's matches (each is the nearest detection
  to the proposal in its own view, within the threshold) and neither belongs to a person already taken;
- its person is every view's matched detection not yet taken, at least two views;
- the person is triangulated again from all of its views (`jaxpose.rig.geometry.triangulate_rows`).

A person seen by one view only cannot be placed in 3D and is left out; so is a false detection, which
agrees with no other view.  Both are counted (`Association.unmatched`).  Two people close together stay
apart as long as some view separates them by more than the threshold: a proposal made of two different
people reprojects far from both in the third view, and from one of them in its own views.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from jaxpose.rig import people
from jaxpose.rig.geometry import triangulate_rows


@dataclasses.dataclass(frozen=True)
class Association:
    """The people of n instants: up to M per instant (padding: detection -1 in every view)."""

    detection: np.ndarray
    """int32[n, M, C]: each person's detection in each view, -1 where the view has none of them."""
    points: np.ndarray
    """f32[n, M, J, 3] world (the calibration's unit), NaN for padding and joints seen by fewer than two views."""
    unmatched: int
    """Detections (with a joint seen) that belong to no person: false detections, people seen by one view."""
    mirrored: np.ndarray
    """bool[n, M, C]: the view's detection joined with its left and right exchanged (`associate`'s mirror)."""

    @property
    def present(self) -> np.ndarray:
        """bool[n, M]: the slot holds a person."""
        return (self.detection >= 0).sum(-1) >= 2


def _take(found: people.Proposals, hypotheses: np.ndarray, detected: np.ndarray) -> list[list[np.ndarray]]:
    """The greedy choice of the module docstring: for each instant, the list of its people as int[C]
    detection indices (-1: none).  detected bool[n, C, K]."""
    n, H, C = found.match.shape
    views_matched = found.matched.sum(-1)
    a, p, b, q = hypotheses.T
    seeds_agree = (found.match[:, np.arange(H), a] == p) & (found.match[:, np.arange(H), b] == q)
    usable = np.isfinite(found.cost) & seeds_agree & found.matched[:, np.arange(H), a] & found.matched[:, np.arange(H), b]
    chosen = []
    for i in range(n):
        candidates = np.flatnonzero(usable[i])
        order = candidates[np.argsort(found.cost[i, candidates], kind="stable")]
        taken = np.zeros(detected.shape[1:], bool)
        persons = []
        for h in order:
            if taken[a[h], p[h]] or taken[b[h], q[h]]:
                continue
            match = found.match[i, h].astype(np.int64)
            views = found.matched[i, h] & ~taken[np.arange(C), match]
            if views.sum() < 2:
                continue
            taken[np.flatnonzero(views), match[views]] = True
            persons.append(np.where(views, match, -1))
        chosen.append(persons)
    return chosen


CHUNK = 256  # instants per compiled call at most: one shape whatever the recording's length
BUDGET = 1 << 22  # proposal-to-detection distances per instant chunk (x 4 bytes, a few such arrays)


def chunk_size(views: int, detections: int, joints: int) -> int:
    """Instants per call: `CHUNK`, or fewer (a power of two) where many detections per view make every
    instant's proposals (views^2 detections^2) large."""
    per_instant = len(people.pair_hypotheses(views, detections)) * views * detections * joints
    return int(min(CHUNK, 2 ** max(0, int(np.log2(max(BUDGET // per_instant, 1))))))


def _proposals_in_chunks(P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, threshold_px: float) -> people.Proposals:
    """`people.proposals` over chunks of `chunk_size` instants (the last padded with nobody)."""
    n, C, K, J = confidence.shape
    size = chunk_size(C, K, J)
    parts = []
    for start in range(0, max(n, 1), size):  # one (empty) chunk where n is 0: the arrays keep their shapes
        rows = min(size, n - start)
        pad = ((0, size - rows),) + ((0, 0),) * (keypoints.ndim - 1)
        xy = np.pad(keypoints[start : start + rows], pad)
        weight = np.pad(confidence[start : start + rows], pad[:-1])
        found = people.proposals(np.broadcast_to(P, (size, *P.shape)), xy, weight, threshold_px)
        parts.append([np.asarray(field)[:rows] for field in (found.cost, found.match, found.matched, found.root)])
    return people.Proposals(*(np.concatenate(column) for column in zip(*parts)))


def _triangulate(P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, detection: np.ndarray, mirrored: np.ndarray, mirror: np.ndarray | None) -> np.ndarray:
    """Each person triangulated from all of its views (a mirrored detection with its left and right
    exchanged back): f32[n, M, J, 3], NaN for padding and joints seen by fewer than two views."""
    n, M, C = detection.shape
    J = keypoints.shape[3]
    points = np.full((n, M, J, 3), np.nan, np.float32)
    rows = np.argwhere((detection >= 0).sum(-1) >= 2)  # [R, 2] (instant, slot)
    if not len(rows):
        return points
    index = detection[rows[:, 0], rows[:, 1]]  # [R, C]
    instant = rows[:, 0, None]
    seen = index >= 0
    safe = np.maximum(index, 0)
    xy = keypoints[instant, np.arange(C), safe]  # [R, C, J, 2]
    weight = np.where(seen[..., None], confidence[instant, np.arange(C), safe], 0.0)
    if mirror is not None:
        flip = mirrored[rows[:, 0], rows[:, 1]]  # [R, C]
        xy = np.where(flip[..., None, None], xy[:, :, mirror], xy)
        weight = np.where(flip[..., None], weight[:, :, mirror], weight)
    triangulated = triangulate_rows(P, xy, weight)
    enough = (weight > 0).sum(1) >= 2  # [R, J]
    points[rows[:, 0], rows[:, 1]] = np.where(enough[..., None], triangulated, np.nan)
    return points


MIN_JOINTS_COMPARED = 3  # joints a detection and a person's projection must share to be compared


def _complete(P, keypoints, confidence, detection, points, mirror, threshold_px) -> tuple[np.ndarray, np.ndarray]:
    """Give each person, in each view where it has no detection, the view's unused detection nearest to its
    projection (from all of its views) within `threshold_px`, or that detection with its left and right
    exchanged (`mirror`), nearest first -> (detection, mirrored bool[n, M, C])."""
    n, M, C = detection.shape
    mirrored = np.zeros(detection.shape, bool)
    rows = np.argwhere((detection >= 0).sum(-1) >= 2)
    lacking = detection[rows[:, 0], rows[:, 1]] < 0  # [R, C]
    rows, lacking = rows[lacking.any(1)], lacking[lacking.any(1)]
    if not len(rows):
        return detection, mirrored
    X = points[rows[:, 0], rows[:, 1]]  # [R, J, 3]
    h = np.einsum("cik,rjk->rcji", P, np.concatenate([X, np.ones((*X.shape[:-1], 1), np.float32)], -1))
    projected = np.where(h[..., 2:] > 0, h[..., :2] / np.where(h[..., 2:] > 0, h[..., 2:], 1.0), np.nan)  # [R, C, J, 2]
    candidates = keypoints[rows[:, 0]]  # [R, C, K, J, 2]
    seen = confidence[rows[:, 0]] > 0  # [R, C, K, J]
    costs = []
    for order in [slice(None)] + ([mirror] if mirror is not None else []):
        distance = np.linalg.norm(projected[:, :, None] - candidates[..., order, :], axis=-1)  # [R, C, K, J]
        distance = np.where(seen[..., order], distance, np.nan)
        compared = np.isfinite(distance).sum(-1) >= MIN_JOINTS_COMPARED
        costs.append(np.where(compared, people._median_over_last(distance), np.inf))
    cost = np.min(costs, 0)  # [R, C, K]
    flipped = np.argmin(costs, 0) == 1
    used = np.zeros(confidence.shape[:3], bool)
    instants, slots, views = np.nonzero(detection >= 0)
    used[instants, views, detection[instants, slots, views]] = True
    cost = np.where(lacking[..., None] & ~used[rows[:, 0]] & (cost <= threshold_px), cost, np.inf)
    r, c, k = np.nonzero(np.isfinite(cost))
    detection = detection.copy()
    for i in np.argsort(cost[r, c, k], kind="stable"):  # nearest first, each detection and view once
        instant, slot = rows[r[i]]
        if used[instant, c[i], k[i]] or detection[instant, slot, c[i]] >= 0:
            continue
        used[instant, c[i], k[i]] = True
        detection[instant, slot, c[i]] = k[i]
        mirrored[instant, slot, c[i]] = flipped[r[i], c[i], k[i]]
    return detection, mirrored


def associate(
    P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, threshold_px: float = people.DEFAULT_THRESHOLD_PX,
    mirror: np.ndarray | None = None,
) -> Association:
    """The people of n instants through one rig: P f32[C, 3, 4] projection matrices of undistorted pixels,
    keypoints f32[n, C, K, J, 2] undistorted pixels of up to K detections per view in any order (padding
    with confidence 0), confidence f32[n, C, K, J]; `threshold_px` the largest median joint distance (pixels)
    of a detection to a person's projection for it to be that person (state it with the results); `mirror`
    int[J], the joint each joint is with left and right exchanged (`jaxpose.skeleton`): where given, a
    detection whose left and right the detector swapped joins its person, exchanged back."""
    n, C, K, J = confidence.shape
    P = np.asarray(P, np.float32)
    found = _proposals_in_chunks(P, keypoints, confidence, threshold_px)
    detected = (confidence > 0).any(-1)
    chosen = _take(found, people.pair_hypotheses(C, K), detected)
    M = max((len(persons) for persons in chosen), default=0)
    detection = np.full((n, max(M, 1), C), -1, np.int32)
    for i, persons in enumerate(chosen):
        if persons:
            detection[i, : len(persons)] = persons
    points = _triangulate(P, keypoints, confidence, detection, np.zeros(detection.shape, bool), None)
    detection, mirrored = _complete(P, keypoints, confidence, detection, points, mirror, threshold_px)
    points = _triangulate(P, keypoints, confidence, detection, mirrored, mirror)
    used = np.zeros((n, C, K), bool)
    instants, slots, views = np.nonzero(detection >= 0)
    used[instants, views, detection[instants, slots, views]] = True
    return Association(detection, points, int((detected & ~used).sum()), mirrored)
