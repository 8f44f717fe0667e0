"""Which detections in which views are the same person, at each instant, from the geometry alone.

`jaxpose.rig.people.proposals` gives, for every pair of views and every pair of their detections, a 3D
person triangulated from those two, each view's detection nearest to its projection (the median over
joints of the pixel distance) and whether it lies within `threshold_px`, and its cost: the sum over views
of that distance, or `threshold_px` where a view has no match.  With more than `SEED_VIEWS` views, the
proposals come from each window of `SEED_VIEWS` views consecutive in the rig's order (cyclically), so that
their number grows with the views, not with their square.  The people of an instant are taken from those
proposals greedily, the cheapest first (a proposal of two people that reprojects near some detection in
every view, a "ghost", costs more than a person seen well by one view fewer):

- a proposal counts when its two seed detections are each other's matches (each is the nearest detection
  to the proposal in its own view, within the threshold) and neither belongs to a person already taken;
  with windows, one whose seed belongs to a person, and whose matches agree with that person's detections
  where both have one, adds its other matches to that person (the person's views in other windows);
- its person is every view's matched detection not yet taken, at least two views;
- the person is triangulated from all of its views (`jaxpose.rig.geometry.triangulate_rows`), and then
  completed: in each view where it has no detection, the unused detection nearest to its projection within
  the threshold joins it (with `mirror`, also one whose left and right the detector swapped, exchanged
  back), nearest first; the person is triangulated again.

A person seen by one view only cannot be placed in 3D and is left out; so is a false detection, which
agrees with no other view.  Both are counted (`Association.unmatched`).  Two people close together stay
apart as long as some view separates them by more than the threshold: a proposal made of two different
people reprojects far from both in the third view, and from one of them in its own views.  With more than
`SEED_VIEWS` views, a person seen only by views further apart than that in the rig's order is not found.
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


def _take(found: people.Proposals, hypotheses: np.ndarray, detected: np.ndarray, windowed: bool) -> list[list[np.ndarray]]:
    """The greedy choice of the module docstring: for each instant, the list of its people as int[C]
    detection indices (-1: none).  detected bool[n, C, K]; `windowed`: the proposals are of windows of views."""
    n, H, C = found.match.shape
    a, p, b, q = hypotheses.T
    seeds_agree = (found.match[:, np.arange(H), a] == p) & (found.match[:, np.arange(H), b] == q)
    usable = np.isfinite(found.cost) & seeds_agree & found.matched[:, np.arange(H), a] & found.matched[:, np.arange(H), b]
    chosen = []
    for i in range(n):
        candidates = np.flatnonzero(usable[i])
        order = candidates[np.argsort(found.cost[i, candidates], kind="stable")]
        owner = np.full(detected.shape[1:], -1)  # [C, K] the person each detection belongs to
        persons = []
        for h in order:
            match = found.match[i, h].astype(np.int64)
            owners = {owner[a[h], p[h]], owner[b[h], q[h]]} - {-1}
            if len(owners) == 2 or (owners and not windowed):  # one window: a person has all of its matches
                continue
            views = found.matched[i, h] & (owner[np.arange(C), match] < 0)
            if owners:  # a seed already someone's: the proposal adds the views that person lacks (other windows)
                person = persons[owners.pop()]
                agree = found.matched[i, h] & (person >= 0)
                if (match[agree] != person[agree]).any():
                    continue
                views &= person < 0
                person[views] = match[views]
                owner[np.flatnonzero(views), match[views]] = owner[a[h], p[h]] if owner[a[h], p[h]] >= 0 else owner[b[h], q[h]]
                continue
            if views.sum() < 2:
                continue
            owner[np.flatnonzero(views), match[views]] = len(persons)
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


def _triangulate_rows(P, keypoints, confidence, detection, mirrored, mirror, rows, method="svd") -> np.ndarray:
    """The persons `rows` int[R, 2] (instant, slot) triangulated from all of their views (a mirrored
    detection with its left and right exchanged back): f32[R, J, 3], NaN for joints seen by fewer than two."""
    C = detection.shape[2]
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
    triangulated = triangulate_rows(P, xy, weight, method)
    enough = (weight > 0).sum(1) >= 2  # [R, J]
    return np.where(enough[..., None], triangulated, np.nan).astype(np.float32)


SEED_VIEWS = 4  # views of a proposal window: every pair at most 3 apart (cyclically) seeds proposals
MIN_JOINTS_COMPARED = 3  # joints a detection and a person's projection must share to be compared


def _complete(P, keypoints, confidence, detection, mirror, threshold_px, windowed) -> tuple[np.ndarray, np.ndarray]:
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
    # only to find the views' detections: the normal equations' point, a fraction of the SVD's time
    X = _triangulate_rows(P, keypoints, confidence, detection, mirrored, None, rows, "normal")  # [R, J, 3]
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
    detection = detection.copy()
    if windowed:  # one person proposed by two windows is two persons until here: one, where either fits the other
        row_of = {(instant, slot): i for i, (instant, slot) in enumerate(rows.tolist())}
        for i, (instant, slot) in enumerate(rows):
            if (detection[instant, slot] >= 0).sum() < 2:  # merged into another
                continue
            for other in np.flatnonzero((detection[instant] >= 0).sum(-1) >= 2):
                views = np.flatnonzero(detection[instant, other] >= 0)
                k = detection[instant, other, views]
                if other != slot and lacking[i, views].all() and (cost[i, views, k] <= threshold_px).all():
                    detection[instant, slot, views], mirrored[instant, slot, views] = k, flipped[i, views, k]
                    detection[instant, other] = -1
                    lacking[i, views] = False
                    if (instant, other) in row_of:
                        lacking[row_of[instant, other]] = False
    used = np.zeros(confidence.shape[:3], bool)
    instants, slots, views = np.nonzero(detection >= 0)
    used[instants, views, detection[instants, slots, views]] = True
    cost = np.where(lacking[..., None] & ~used[rows[:, 0]] & (cost <= threshold_px), cost, np.inf)
    r, c, k = np.nonzero(np.isfinite(cost))
    for i in np.argsort(cost[r, c, k], kind="stable"):  # nearest first, each detection and view once
        instant, slot = rows[r[i]]
        if used[instant, c[i], k[i]] or detection[instant, slot, c[i]] >= 0:
            continue
        used[instant, c[i], k[i]] = True
        detection[instant, slot, c[i]] = k[i]
        mirrored[instant, slot, c[i]] = flipped[r[i], c[i], k[i]]
    return detection, mirrored


def _windowed_proposals(P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, threshold_px: float) -> tuple[people.Proposals, np.ndarray]:
    """The proposals of every window of `SEED_VIEWS` consecutive views (one window of all where there are no
    more), their matches over all C views (unmatched outside the window) -> (proposals, hypotheses int[H, 4])."""
    n, C, K = confidence.shape[:3]
    windows = [np.arange(C)] if C <= SEED_VIEWS else [np.arange(a, a + SEED_VIEWS) % C for a in range(C)]
    parts, hypotheses = [], []
    for views in windows:
        found = _proposals_in_chunks(P[views], keypoints[:, views], confidence[:, views], threshold_px)
        pairs = people.pair_hypotheses(len(views), K)
        hypotheses.append(np.stack([views[pairs[:, 0]], pairs[:, 1], views[pairs[:, 2]], pairs[:, 3]], -1))
        match = np.zeros((n, len(pairs), C), np.int8)
        matched = np.zeros((n, len(pairs), C), bool)
        match[..., views], matched[..., views] = found.match, found.matched
        parts.append((found.cost, match, matched, found.root))
    return people.Proposals(*(np.concatenate(column, 1) for column in zip(*parts))), np.concatenate(hypotheses)


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
    P = np.asarray(P, np.float32)
    found, hypotheses = _windowed_proposals(P, keypoints, confidence, threshold_px)
    return _of_proposals(found, hypotheses, P, keypoints, confidence, threshold_px, mirror, windowed=P.shape[0] > SEED_VIEWS)


def of_proposals(
    found: people.Proposals, P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray,
    threshold_px: float = people.DEFAULT_THRESHOLD_PX, mirror: np.ndarray | None = None,
) -> Association:
    """`associate` from the instants' proposals (`people.proposals` of every pair of views, of the same
    keypoints, confidence and `threshold_px`), where the caller has them already (the rig loader:
    `jaxpose.rig.tracked`)."""
    C, K = confidence.shape[1:3]
    return _of_proposals(found, people.pair_hypotheses(C, K), np.asarray(P, np.float32), keypoints, confidence, threshold_px, mirror, windowed=False)


def _of_proposals(found, hypotheses, P, keypoints, confidence, threshold_px, mirror, windowed: bool) -> Association:
    """The people of the instants from their proposals `found` (of the pairs `hypotheses` int[H, 4])."""
    n, C, K, J = confidence.shape
    detected = (confidence > 0).any(-1)
    chosen = _take(found, hypotheses, detected, windowed)
    M = max((len(persons) for persons in chosen), default=0)
    detection = np.full((n, max(M, 1), C), -1, np.int32)
    for i, persons in enumerate(chosen):
        if persons:
            detection[i, : len(persons)] = persons
    detection, mirrored = _complete(P, keypoints, confidence, detection, mirror, threshold_px, windowed)
    points = np.full((*detection.shape[:2], J, 3), np.nan, np.float32)
    rows = np.argwhere((detection >= 0).sum(-1) >= 2)  # [R, 2] (instant, slot)
    if len(rows):
        points[rows[:, 0], rows[:, 1]] = _triangulate_rows(P, keypoints, confidence, detection, mirrored, mirror, rows)
    used = np.zeros((n, C, K), bool)
    instants, slots, views = np.nonzero(detection >= 0)
    used[instants, views, detection[instants, slots, views]] = True
    return Association(detection, points, int((detected & ~used).sum()), mirrored)
