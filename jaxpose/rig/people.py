"""One person per instant from detections of several people: the one the calibrated views agree on.

Real recordings often show more than one person: a second subject, a passer-by, a reflection, or
a detector's duplicate.  Where the rig loader finds one person in a recording (or none;
`jaxpose.rig.tracked` keeps every person where it finds several), this module picks for every
instant, in every view, the detection of that person, using the geometry alone (no tracker, no
appearance):

1. Every pair of views and every pair of their detections proposes a 3D person: its joints
   triangulated from those two detections.
2. Each proposal is projected into every view, and in each view the detection nearest to it (the
   median over joints of the pixel distance) is its match; a view whose nearest detection is
   further than `threshold_px` has no match (that view sees somebody else, or nobody).
3. Each proposal's cost is the sum over views of its match distance, or `threshold_px` without a
   match: a proposal seen by more views costs less, then the better fit.
4. Two people who are both seen well are both plausible, and a better fit or one more view is
   no reason to switch between them from one instant to the next.  So only proposals whose root
   lies within `TRACK_RADIUS_MM` of the subject's track compete, and the cheapest of them wins; the
   track is the running median (over `TRACK_WINDOW` instants) of the roots of the cheapest
   proposals.  A subject present in most instants owns that median, a passer-by does not.  Where
   no proposal is near the track (or there is none), the cheapest of all wins.

Views without a match keep confidence 0 for that instant.  The same rule runs on instants with a
single detection per view, where it removes a view whose only detection is somebody else (the
main subject occluded, a passer-by detected).

Steps 1-3 run in fixed-size chunks of instants (`proposals`, one compilation whatever the number and
lengths of the recordings, each instant with its own rig's projections); step 4 per recording
(`choose`), on every instant of it (the split and its strides come after: `jaxpose.rig.project.split`).
"""

from __future__ import annotations

import dataclasses
import itertools

import jax
import jax.numpy as jnp
import numpy as np

DEFAULT_THRESHOLD_PX = 40.0
TRACK_WINDOW = 51  # instants: about a second at 50 fps
TRACK_RADIUS_MM = 500.0  # a root this far from the track is somebody else (or the track is lost)


@dataclasses.dataclass(frozen=True)
class PersonChoice:
    """The chosen detection in each view, and how often there was a choice."""

    keypoints: np.ndarray
    """f32[N, C, J, 2] the chosen person's keypoints."""
    confidence: np.ndarray
    """f32[N, C, J], 0 in views where nobody matched."""
    instants_with_choice: int
    """Instants in which some view had more than one detection."""
    views_without_match: int
    """(instant, view) pairs with detections of which none matched the chosen person."""


@dataclasses.dataclass(frozen=True)
class Proposals:
    """Steps 1-3 for n instants and the H = `pair_hypotheses` proposals of each."""

    cost: np.ndarray
    """f32[n, H]: inf for a proposal without its two detections or two joints seen in both."""
    match: np.ndarray
    """int8[n, H, C]: each view's detection nearest to the proposal."""
    matched: np.ndarray
    """bool[n, H, C]: that detection lies within the threshold."""
    root: np.ndarray
    """f32[n, H, 3]: the proposal's joint 0, world mm."""


def pair_hypotheses(num_views: int, num_people: int) -> np.ndarray:
    """int[H, 4]: (view a, person of a, view b, person of b) for every view pair and detection pair."""
    return np.array(
        [
            (a, p, b, q)
            for a, b in itertools.combinations(range(num_views), 2)
            for p, q in itertools.product(range(num_people), repeat=2)
        ],
        dtype=np.int32,
    ).reshape(-1, 4)


def _planes(P, u, v, weight, seen):
    """A view's two DLT planes per joint (`jaxpose.triangulation.dlt_system`: row-normalised, then
    weighted): P [H, 3, 4, 1, n]; u, v, weight [H, J, n] -> two lists of 4 coefficient arrays [H, J, n]."""
    rows = []
    for axis, coordinate in enumerate((u, v)):
        row = [coordinate * P[:, 2, k] - P[:, axis, k] for k in range(4)]
        length = jnp.sqrt(row[0] * row[0] + row[1] * row[1] + row[2] * row[2])
        scale = jnp.maximum(length, 1e-12)
        rows.append([jnp.where(seen, (value / scale) * weight, 0.0) for value in row])
    return rows


@jax.jit
def _distances(P, keypoints, confidence, hypotheses):
    """Every proposal's pixel distances to every detection: P f32[n, C, 3, 4] (undistorted pixels),
    keypoints [n, C, K, J, 2], confidence [n, C, K, J], hypotheses int[H, 4] -> (distance f32[n, H, C, K, J],
    NaN where the proposal or the detection lacks the joint or the proposal lies behind the camera;
    root f32[n, H, 3]).

    Written coefficient by coefficient over arrays whose last axis is the instants: the two-view
    least-squares point of `jaxpose.triangulation`'s "normal" method and the projections, where XLA
    on CPU would run the 3x4 products and 3x3 solves of the batched matrix form as many tiny
    matrix products (17 times slower).
    """
    a, p, b, q = (hypotheses[:, i] for i in range(4))
    P = jnp.moveaxis(P, 0, -1)  # [C, 3, 4, n]
    points = jnp.moveaxis(keypoints, 0, -1)  # [C, K, J, 2, n]
    weights = jnp.moveaxis(confidence, 0, -1)  # [C, K, J, n]
    seen = (weights[a, p] > 0) & (weights[b, q] > 0)  # [H, J, n]: triangulable joints
    rows = []
    for view, person in ((a, p), (b, q)):
        rows += _planes(P[view][:, :, :, None], points[view, person, :, 0], points[view, person, :, 1], weights[view, person], seen)
    # The normal equations sum_r n_r n_r^T x = -sum_r n_r d_r, solved through the adjugate.
    g = {(i, j): sum(row[i] * row[j] for row in rows) for i in range(3) for j in range(i, 4)}
    rhs = [-g[i, 3] for i in range(3)]
    cof = {(0, 0): g[1, 1] * g[2, 2] - g[1, 2] * g[1, 2], (0, 1): g[0, 2] * g[1, 2] - g[0, 1] * g[2, 2],
           (0, 2): g[0, 1] * g[1, 2] - g[0, 2] * g[1, 1], (1, 1): g[0, 0] * g[2, 2] - g[0, 2] * g[0, 2],
           (1, 2): g[0, 1] * g[0, 2] - g[0, 0] * g[1, 2], (2, 2): g[0, 0] * g[1, 1] - g[0, 1] * g[0, 1]}  # fmt: skip
    determinant = g[0, 0] * cof[0, 0] + g[0, 1] * cof[0, 1] + g[0, 2] * cof[0, 2]
    determinant = jnp.where(jnp.abs(determinant) < 1e-20, 1e-20, determinant)
    X = [sum(cof[min(i, k), max(i, k)] * rhs[k] for k in range(3)) / determinant for i in range(3)]  # [H, J, n]
    projected = [sum(P[:, i, k, None, None] * X[k][None] for k in range(3)) + P[:, i, 3, None, None] for i in range(3)]
    in_front = projected[2] > 0  # [C, H, J, n]
    depth = jnp.where(in_front, projected[2], 1.0)
    dx = (projected[0] / depth)[:, :, None] - points[:, None, :, :, 0]  # [C, H, K, J, n]
    dy = (projected[1] / depth)[:, :, None] - points[:, None, :, :, 1]
    usable = seen[None, :, None] & in_front[:, :, None] & (weights[:, None] > 0)
    distance = jnp.where(usable, jnp.sqrt(dx * dx + dy * dy), jnp.nan)
    return jnp.transpose(distance, (4, 1, 0, 2, 3)), jnp.moveaxis(jnp.stack([x[:, 0] for x in X], -1), 1, 0)


def _median_over_last(values: np.ndarray) -> np.ndarray:
    """The median over the last axis ignoring NaN (NaN where all are), by one sort: `jnp.nanmedian`'s
    value (the mean of the two middle values) at a fraction of XLA's sorting time on CPU."""
    ordered = np.sort(values, axis=-1)  # NaN last
    count = (~np.isnan(values)).sum(-1, keepdims=True)
    low = np.take_along_axis(ordered, np.maximum(count - 1, 0) // 2, -1)[..., 0]
    high = np.take_along_axis(ordered, np.minimum(count // 2, values.shape[-1] - 1), -1)[..., 0]
    with np.errstate(invalid="ignore"):
        return np.where(count[..., 0] > 0, low * 0.5 + high * 0.5, np.nan).astype(values.dtype)


def proposals(P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, threshold_px: float) -> Proposals:
    """Steps 1-3 for n instants, each with its own projections: P f32[n, C, 3, 4] of undistorted pixels,
    keypoints f32[n, C, K, J, 2] undistorted pixels of up to K detections per view (padding with
    confidence 0), confidence f32[n, C, K, J].  Callers pass fixed-size chunks (`jaxpose.chunks`)."""
    C, K = keypoints.shape[1:3]
    hypotheses = pair_hypotheses(C, K)
    distance, root = jax.device_get(_distances(P, keypoints, confidence, jnp.asarray(hypotheses)))
    median = _median_over_last(distance)  # [n, H, C, K]
    median = np.where(np.isnan(median), np.inf, median)
    match = np.argmin(median, axis=-1)
    best = np.take_along_axis(median, match[..., None], -1)[..., 0]
    matched = best <= threshold_px
    cost = np.where(matched, best, np.float32(threshold_px)).sum(-1, dtype=np.float32)
    # A proposal needs its two detections and at least two joints seen in both.
    a, p, b, q = hypotheses.T
    first, second = confidence[:, a, p] > 0, confidence[:, b, q] > 0  # [n, H, J]
    valid = first.any(-1) & second.any(-1) & ((first & second).sum(-1) >= 2)
    return Proposals(np.where(valid, cost, np.inf).astype(np.float32), match.astype(np.int8), matched, root)


def _running_median(points: np.ndarray, window: int, at: np.ndarray) -> np.ndarray:
    """f32[N, 3] -> at the rows `at`, the median of each coordinate over `window` instants centred on
    each (NaN ignored; NaN where there is none)."""
    half = window // 2
    padded = np.pad(points, ((half, half), (0, 0)), constant_values=np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(padded, window, axis=0)  # [N, 3, window], no copy
    track = np.empty((len(at), points.shape[1]), points.dtype)
    for start in range(0, len(at), 65536):  # bounded memory: each block's windows are sorted as a copy
        rows = at[start : start + 65536]
        track[start : start + len(rows)] = _median_over_last(windows[rows])
    return track


def choose(found: Proposals, keypoints: np.ndarray, confidence: np.ndarray) -> PersonChoice:
    """Step 4 for one recording: the proposals `found` of its n instants (every one, in order: the track
    is a running median over time); keypoints [n, C, K, J, 2] and confidence [n, C, K, J] as `proposals`
    took them."""
    n, C = keypoints.shape[:2]
    rows = np.arange(n)
    cheapest = np.argmin(found.cost, axis=1)
    exists = np.isfinite(found.cost[rows, cheapest])
    roots = np.where(exists[:, None], found.root[rows, cheapest], np.nan).astype(np.float32)
    track = _running_median(roots, TRACK_WINDOW, rows)
    from_track = np.nan_to_num(np.linalg.norm(found.root - track[:, None], axis=-1), nan=np.inf)  # inf: no track
    near = np.isfinite(found.cost) & (from_track < TRACK_RADIUS_MM)
    winner = np.where(near.any(1), np.argmin(np.where(near, found.cost, np.inf), axis=1), cheapest)
    chosen = found.match[rows, winner].astype(np.int64)  # [n, C]
    keep = found.matched[rows, winner] & exists[:, None]
    instant, view = np.meshgrid(rows, np.arange(C), indexing="ij")
    out_keypoints = keypoints[instant, view, chosen]
    out_confidence = np.where(keep[..., None], confidence[instant, view, chosen], 0.0).astype(np.float32)
    detected = (confidence > 0).any(-1)  # [n, C, K]
    return PersonChoice(
        keypoints=out_keypoints,
        confidence=out_confidence,
        instants_with_choice=int((detected.sum(-1) > 1).any(-1).sum()),
        views_without_match=int((detected.any(-1) & ~(out_confidence > 0).any(-1)).sum()),
    )


def choose_person(
    P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, threshold_px: float = DEFAULT_THRESHOLD_PX
) -> PersonChoice:
    """The person the views agree on in every instant of one recording (see the module docstring).

    P f32[C, 3, 4] projection matrices of undistorted pixels; keypoints f32[N, C, K, J, 2] undistorted
    pixels of up to K detections per view (padding rows with confidence 0); confidence f32[N, C, K, J].
    """
    N = len(keypoints)
    P_rows = np.broadcast_to(np.asarray(P, np.float32), (N, *np.shape(P)))
    found = proposals(P_rows, keypoints, confidence, threshold_px)
    return choose(found, keypoints, confidence)
