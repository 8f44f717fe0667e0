"""Several people in view and no rig yet: which detections in which views are the same person, from the
detections alone, so that the rig can be recovered from every person (`jaxpose.calibration.calibrate`).

Without a calibration the correspondence of people across views is unknown, and association through a
rig (`jaxpose.rig.association`) needs one.  The epipolar geometry of a view pair is in the detections,
though: over many instants the true pairings of two views' people are consistent with one fundamental
matrix, a wrong pairing (two people at different places) with none.  So:

1. for every view pair, every instant and every pairing of a detection in one view with one in the
   other, their common joints are correspondences; a robust estimator (OpenCV's MAGSAC++) fits the pair's
   fundamental matrix to all of them pooled: with P people per view about 1/P of the pairings are true,
   the others its outliers (a pair needs `MIN_PAIRINGS` pairings to be estimated);
2. a pairing's cost is the median over its common joints of their symmetric epipolar distance (pixels);
3. per instant, people are taken greedily, the cheapest pairing of two free detections first (cost at most
   `threshold_px`, each the other's cheapest in its view), then each other view's free detection that costs at most `threshold_px` against every
   detection the person has so far (the cheapest).

Each person becomes one row of single-person detections ([R, C, J]: confidence 0 in the views without
them), in instant order: what `calibrate` takes.  Epipolar geometry cannot tell two people apart who
stand on one epipolar line in every view pair; the adjustment's robust weights down-weight such a row.
Detections left out (a false person, a person seen by one view only) are counted.  With one detection
per view the same rule keeps a view only where it agrees with the others.
"""

from __future__ import annotations

import dataclasses
import itertools
import warnings

import cv2
import numpy as np

from jaxpose.calibration.initial import MAX_RANSAC_POINTS, RANSAC_CONFIDENCE, CalibrationError

MIN_PAIRINGS = 20  # candidate pairings (instants x detection pairs) a view pair needs for its fundamental matrix
RANSAC_ITERATIONS = 10_000  # with 3 people per view only 1/3 of the correspondences are inliers


@dataclasses.dataclass(frozen=True)
class MatchedPeople:
    """The people found per instant, each a row of single-person detections."""

    keypoints: np.ndarray
    """f32[R, C, J, 2] each person's detection in each view (distorted pixels, as given)."""
    confidence: np.ndarray
    """f32[R, C, J]: 0 in the views where the person has no detection."""
    instant: np.ndarray
    """i64[R] the instant of each row."""
    views_estimated: int
    """View pairs whose fundamental matrix the detections gave."""
    unmatched: int
    """Detections (with `min_joints` joints) that belong to no person."""


def _epipolar_costs(F: np.ndarray, a: np.ndarray, b: np.ndarray, both: np.ndarray) -> np.ndarray:
    """The median symmetric epipolar distance (px) of every pairing: F [3, 3] (x_b^T F x_a = 0);
    a, b f64[N, K, J, 2] the two views' pixels; both bool[N, K, K, J] joints seen in both ->
    f64[N, K, K] (inf where no joint is)."""
    ha = np.concatenate([a, np.ones_like(a[..., :1])], -1)
    hb = np.concatenate([b, np.ones_like(b[..., :1])], -1)
    lines_b = ha @ F.T  # [N, K, J, 3]: the lines in view b of view a's points
    lines_a = hb @ F  # [N, K, J, 3]
    algebraic = np.einsum("npji,nqji->npqj", ha, lines_a)  # x_b^T F x_a for every pairing [N, K, K, J]
    norm_b = np.linalg.norm(lines_b[..., :2], axis=-1)[:, :, None]  # [N, K(p), 1, J]
    norm_a = np.linalg.norm(lines_a[..., :2], axis=-1)[:, None]  # [N, 1, K(q), J]
    distance = 0.5 * np.abs(algebraic) * (1 / np.maximum(norm_b, 1e-12) + 1 / np.maximum(norm_a, 1e-12))
    distance = np.where(both, distance, np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # pairings without a common joint: all-NaN
        median = np.nanmedian(distance, axis=-1)
    return np.where(np.isnan(median), np.inf, median)


def mutual(cost: np.ndarray, threshold_px: float) -> np.ndarray:
    """bool[K, K]: the pairings of one instant within the threshold whose two detections are each other's
    cheapest (a person missed in one view leaves their detection in the other without a partner, rather than
    paired with the nearest of the others)."""
    best_q = cost == cost.min(1, keepdims=True)
    best_p = cost == cost.min(0, keepdims=True)
    return best_q & best_p & (cost <= threshold_px)


def _fundamental(a: np.ndarray, b: np.ndarray, both: np.ndarray, threshold_px: float, rng: np.random.Generator):
    """The view pair's fundamental matrix from every pairing's common joints (None where fewer than
    `MIN_PAIRINGS` pairings or no estimate)."""
    n, p, q, j = np.nonzero(both)
    if len({(x, y, z) for x, y, z in zip(n, p, q)}) < MIN_PAIRINGS:
        return None
    if len(n) > MAX_RANSAC_POINTS:
        keep = rng.choice(len(n), MAX_RANSAC_POINTS, replace=False)
        n, p, q, j = n[keep], p[keep], q[keep], j[keep]
    cv2.setRNGSeed(int(rng.integers(2**31)))
    F, _ = cv2.findFundamentalMat(
        a[n, p, j].astype(np.float64), b[n, q, j].astype(np.float64), cv2.USAC_MAGSAC, threshold_px, RANSAC_CONFIDENCE,
        RANSAC_ITERATIONS,
    )  # fmt: skip
    return None if F is None or F.shape != (3, 3) else F


def match_people(
    keypoints: np.ndarray,
    confidence: np.ndarray,
    *,
    threshold_px: float,
    min_joints: int,
    min_confidence: float,
    seed: int = 0,
    pixels: np.ndarray | None = None,
) -> MatchedPeople:
    """The people of every instant matched across views without a rig (the module docstring).

    keypoints f32[N, C, K, J, 2] distorted pixels of up to K detections per view in any order (padding with
    confidence 0), confidence f32[N, C, K, J]; `pixels`: the same keypoints undistorted where the lenses are
    known (the epipolar geometry holds for those), else the keypoints are taken as they are.  A detection
    counts with `min_joints` joints of confidence >= `min_confidence`.  Raises `CalibrationError` when no
    view pair's epipolar geometry can be found (too few instants where both views see somebody).
    """
    N, C, K, J = confidence.shape
    xy = np.asarray(keypoints if pixels is None else pixels, np.float64)
    valid = (confidence >= min_confidence) & np.isfinite(xy).all(-1)
    present = valid.sum(-1) >= min_joints  # [N, C, K]
    valid &= present[..., None]
    rng = np.random.default_rng(seed)
    costs = {}
    for a, b in itertools.combinations(range(C), 2):
        both = valid[:, a, :, None] & valid[:, b, None]  # [N, K, K, J]
        both &= both.sum(-1, keepdims=True) >= min_joints
        F = _fundamental(xy[:, a], xy[:, b], both, threshold_px, rng)
        if F is not None:
            costs[a, b] = _epipolar_costs(F, xy[:, a], xy[:, b], both)
            costs[b, a] = costs[a, b].transpose(0, 2, 1)
    if not costs:
        raise CalibrationError(
            f"no two views see people together often enough to relate them without a calibration (each pair needs"
            f" >= {MIN_PAIRINGS} instant-and-detection pairings with >= {min_joints} common joints)"
        )
    rows_keypoints, rows_confidence, instants = [], [], []
    taken = np.zeros((C, K), bool)
    matched = 0
    for n in range(N):
        taken[:] = False
        candidates = [
            (cost, a, p, b, q)
            for (a, b), table in costs.items()
            if a < b
            for p, q in zip(*np.nonzero(mutual(table[n], threshold_px)))
            for cost in (table[n, p, q],)
        ]
        for _, a, p, b, q in sorted(candidates):
            if taken[a, p] or taken[b, q]:
                continue
            members = {a: p, b: q}
            for c in range(C):
                if c in members or not all((m, c) in costs for m in members):
                    continue
                # every free detection of view c against the person's detections so far: the worst of them
                fit = np.max([costs[m, c][n, k] for m, k in members.items()], axis=0)  # [K]
                fit = np.where(taken[c] | ~present[n, c], np.inf, fit)
                best = int(np.argmin(fit))
                if fit[best] <= threshold_px:
                    members[c] = best
            row_xy = np.zeros((C, J, 2), np.float32)
            row_confidence = np.zeros((C, J), np.float32)
            for c, k in members.items():
                taken[c, k] = True
                row_xy[c] = keypoints[n, c, k]
                row_confidence[c] = confidence[n, c, k]
            rows_keypoints.append(row_xy)
            rows_confidence.append(row_confidence)
            instants.append(n)
        matched += int((taken & present[n]).sum())
    return MatchedPeople(
        keypoints=np.asarray(rows_keypoints, np.float32).reshape(-1, C, J, 2),
        confidence=np.asarray(rows_confidence, np.float32).reshape(-1, C, J),
        instant=np.asarray(instants, np.int64),
        views_estimated=len(costs) // 2,
        unmatched=int(present.sum()) - matched,
    )
