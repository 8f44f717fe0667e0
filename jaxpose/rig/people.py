"""One person per instant from detections of several people: the one the calibrated views agree on.

Real recordings often show more than one person: a second subject, a passer-by, a reflection, or
a detector's duplicate.  The lifter trains on one person per instant, so for every instant this
module picks, in every view, the detection of the same person, using the geometry alone (no
tracker, no appearance):

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
"""

from __future__ import annotations

import dataclasses
import itertools
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.triangulation import triangulate

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


def _pair_hypotheses(num_views: int, num_people: int) -> np.ndarray:
    """int[H, 4]: (view a, person of a, view b, person of b) for every view pair and detection pair."""
    return np.array(
        [
            (a, p, b, q)
            for a, b in itertools.combinations(range(num_views), 2)
            for p, q in itertools.product(range(num_people), repeat=2)
        ],
        dtype=np.int32,
    )


@jax.jit
def _match_costs(P, keypoints, confidence, hypotheses, threshold_px):
    """For n instants: P [C, 3, 4] (undistorted pixels), keypoints [n, C, K, J, 2], confidence
    [n, C, K, J], hypotheses [H, 4] -> (cost [n, H], match [n, H, C] detection index, matched
    [n, H, C] bool, root [n, H, 3] the proposal's joint 0)."""
    a, p, b, q = (hypotheses[:, i] for i in range(4))
    pair_points = jnp.stack([keypoints[:, a, p], keypoints[:, b, q]], axis=2)  # [n, H, 2, J, 2]
    pair_weights = jnp.stack([confidence[:, a, p], confidence[:, b, q]], axis=2)  # [n, H, 2, J]
    pair_P = jnp.stack([P[a], P[b]], axis=1)  # [H, 2, 3, 4]
    joints_seen = (pair_weights > 0).all(axis=2)  # [n, H, J]: triangulable joints
    points = triangulate(pair_P, pair_points, jnp.where(joints_seen[:, :, None], pair_weights, 0.0), method="normal")
    homogeneous = jnp.concatenate([points, jnp.ones_like(points[..., :1])], -1)  # [n, H, J, 4]
    projected = jnp.einsum("cik,nhjk->nhcji", P, homogeneous)  # [n, H, C, J, 3]
    depth = projected[..., 2:]
    in_front = depth[..., 0] > 0
    pixels = projected[..., :2] / jnp.where(in_front[..., None], depth, 1.0)
    distance = jnp.linalg.norm(pixels[:, :, :, None] - keypoints[:, None], axis=-1)  # [n, H, C, K, J]
    usable = joints_seen[:, :, None, None] & in_front[:, :, :, None] & (confidence[:, None] > 0)
    # The median over the joints both the proposal and the detection have (NaN elsewhere).
    median = jnp.nanmedian(jnp.where(usable, distance, jnp.nan), axis=-1)  # [n, H, C, K]
    median = jnp.where(jnp.isnan(median), jnp.inf, median)
    match = jnp.argmin(median, axis=-1)  # [n, H, C]
    best = jnp.min(median, axis=-1)
    matched = best <= threshold_px
    cost = jnp.where(matched, best, threshold_px).sum(-1)
    # A proposal needs its two detections and at least two joints seen in both.
    valid = (pair_weights.max(-1) > 0).all(-1) & (joints_seen.sum(-1) >= 2)
    return jnp.where(valid, cost, jnp.inf), match, matched, points[..., 0, :]


def _running_median(points: np.ndarray, window: int) -> np.ndarray:
    """f[N, 3] -> the median of each coordinate over `window` instants centred on each (NaN ignored)."""
    half = window // 2
    padded = np.pad(points, ((half, half), (0, 0)), constant_values=np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(padded, window, axis=0)  # [N, 3, window]
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows: no track there
        return np.nanmedian(windows, axis=-1)


def choose_person(
    P: np.ndarray, keypoints: np.ndarray, confidence: np.ndarray, threshold_px: float = DEFAULT_THRESHOLD_PX
) -> PersonChoice:
    """The person the views agree on, per instant (see the module docstring).

    P f32[C, 3, 4] projection matrices of undistorted pixels; keypoints f32[N, C, K, J, 2] undistorted
    pixels of up to K detections per view (padding rows with confidence 0); confidence f32[N, C, K, J].
    """
    N, C, K, J, _ = keypoints.shape
    hypotheses = jnp.asarray(_pair_hypotheses(C, K))
    # Instants per call: the distances [chunk, H, C, K, J] stay near 32 MiB.
    chunk = int(np.clip(2**23 // (len(hypotheses) * C * K * J), 8, 1024))
    P = jnp.asarray(P, jnp.float32)
    detected = (confidence > 0).any(-1)  # [N, C, K]
    H = len(hypotheses)
    cost, match = np.full((N, H), np.inf, np.float32), np.zeros((N, H, C), np.int32)
    matched, root = np.zeros((N, H, C), bool), np.zeros((N, H, 3), np.float32)
    for start in range(0, N, chunk):
        rows = slice(start, min(start + chunk, N))
        n = rows.stop - rows.start
        pad = chunk - n if N > chunk else 0  # pad the last chunk: one compilation
        kp = np.pad(keypoints[rows], ((0, pad), (0, 0), (0, 0), (0, 0), (0, 0)))
        cf = np.pad(confidence[rows], ((0, pad), (0, 0), (0, 0), (0, 0)))
        outputs = jax.device_get(_match_costs(P, jnp.asarray(kp), jnp.asarray(cf), hypotheses, threshold_px))
        cost[rows], match[rows], matched[rows], root[rows] = (array[:n] for array in outputs)
    instants = np.arange(N)
    cheapest = np.argmin(cost, axis=1)
    found = np.isfinite(cost[instants, cheapest])
    track = _running_median(np.where(found[:, None], root[instants, cheapest], np.nan), TRACK_WINDOW)
    from_track = np.nan_to_num(np.linalg.norm(root - track[:, None], axis=-1), nan=np.inf)  # inf: no track
    near = np.isfinite(cost) & (from_track < TRACK_RADIUS_MM)
    winner = np.where(near.any(1), np.argmin(np.where(near, cost, np.inf), axis=1), cheapest)
    chosen = match[instants, winner]  # [N, C]
    keep = matched[instants, winner] & found[:, None]
    instant, view = np.meshgrid(instants, np.arange(C), indexing="ij")
    out_keypoints = keypoints[instant, view, chosen]
    out_confidence = np.where(keep[..., None], confidence[instant, view, chosen], 0.0).astype(np.float32)
    views_with_people = detected.any(-1)
    return PersonChoice(
        keypoints=out_keypoints,
        confidence=out_confidence,
        instants_with_choice=int((detected.sum(-1) > 1).any(-1).sum()),
        views_without_match=int((views_with_people & ~(out_confidence > 0).any(-1)).sum()),
    )
